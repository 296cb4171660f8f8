"""``trackflow compare REF EST``: absolute and relative pose error with association, alignment."""

from __future__ import annotations

import json
from pathlib import Path

from ._common import add_input, load

ALIGNMENTS = ("none", "se3", "sim3", "origin")


def register(subparsers):
    p = subparsers.add_parser(
        "compare",
        help="APE/RPE of an estimated trajectory against a reference (evo-compatible figures)",
        description="Associate the samples of REF and EST by time, optionally align EST to "
        "REF (SE(3), Sim(3) or the first pose), and report the absolute (APE) and relative "
        "(RPE) pose errors with per-axis statistics; with covariances in EST also the NEES.",
    )
    add_input(p, "reference")
    add_input(p, "estimate", suffix="2")
    p.add_argument("--t-max-diff", type=float, default=0.01, help="association tolerance [s]")
    p.add_argument("--t-offset", type=float, default=0.0, help="added to EST's times [s]")
    p.add_argument("--align", choices=ALIGNMENTS, default="none", help="alignment of EST")
    p.add_argument("--delta", type=int, default=1, help="RPE step in associated pairs")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--save-results", default=None, help="write every error as JSON here")
    p.add_argument("--plot", default=None, help="write PNGs (errors over time, trajectories) "
                   "into this folder")  # fmt: skip
    p.add_argument("--force", action="store_true", help="replace existing results/plots")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..evaluation import compare_trajectories
    from ..io import atomic_output

    ref = load(args, "reference", min_samples=2)
    est = load(args, "estimate", suffix="2", min_samples=2)
    res = compare_trajectories(
        ref, est, t_max_diff=args.t_max_diff, t_offset=args.t_offset, align=args.align,
        delta=args.delta,
    )  # fmt: skip
    if args.save_results:
        with atomic_output(args.save_results, overwrite=args.force) as tmp:
            tmp.write_text(json.dumps(res.as_dict(arrays=True)) + "\n")
    if args.plot:
        from ..plotting import plot_compare

        out = Path(args.plot)
        out.mkdir(parents=True, exist_ok=True)
        for path in plot_compare(out, res, Path(args.reference).stem,
                                 Path(args.estimate).stem, overwrite=args.force):  # fmt: skip
            print(path)
    print(json.dumps(res.as_dict(), indent=2) if args.json else res.table())
    return 0
