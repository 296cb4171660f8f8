"""``trackflow compare REF EST``: absolute and relative pose error with association, alignment."""

from __future__ import annotations

import json
from pathlib import Path

from ._common import add_input
from ._processing import add_processing

#: ``trackflow.evaluation.ALIGNMENTS`` (mirrored so that parsing arguments does not import it).
ALIGNMENTS = ("none", "se3", "sim3", "scale", "origin")
#: ``trackflow.evaluation.POSE_RELATIONS`` (mirrored).
POSE_RELATIONS = (
    "full",
    "trans_part",
    "rot_part",
    "angle_deg",
    "angle_rad",
    "point_distance",
    "point_distance_error_ratio",
)
#: ``trackflow.evaluation.DELTA_UNITS`` (mirrored).
DELTA_UNITS = ("f", "m", "d", "r")


def _relations(text: str) -> tuple[str, ...]:
    import argparse

    names = tuple(v.strip() for v in text.split(",") if v.strip())
    bad = [v for v in names if v not in POSE_RELATIONS]
    if bad or not names:
        raise argparse.ArgumentTypeError(
            f"pose relations must be some of {', '.join(POSE_RELATIONS)}; got {text!r}"
        )
    return names


def register(subparsers):
    p = subparsers.add_parser(
        "compare",
        help="APE/RPE of an estimated trajectory against a reference (evo-compatible figures)",
        description="Associate the samples of REF and EST by time, optionally align EST to "
        "REF (SE(3), Sim(3), scale only or the first pose), and report the absolute (APE) and "
        "relative (RPE) pose errors for the chosen pose relations, with per-axis statistics; "
        "with covariances in EST also the NEES. The options mirror evo_ape / evo_rpe "
        "(docs/cli.md).",
    )
    add_input(p, "reference")
    add_input(p, "estimate", suffix="2", nargs="+")
    p.add_argument("--t-max-diff", type=float, default=0.01, help="association tolerance [s]")
    p.add_argument("--t-offset", type=float, default=0.0, help="added to EST's times [s]")
    p.add_argument(
        "--align",
        choices=ALIGNMENTS,
        default="none",
        help="alignment of EST: Umeyama se3 / sim3 / scale only, or the first pose",
    )
    p.add_argument(
        "-s",
        "--correct-scale",
        action="store_true",
        help="evo's -s: with --align se3 a Sim(3) alignment, alone the scale only",
    )
    p.add_argument(
        "--n-to-align",
        type=int,
        default=None,
        metavar="N",
        help="fit the alignment to the first N associated pairs only",
    )
    p.add_argument(
        "--pose-relation",
        type=_relations,
        default="trans_part,angle_deg",
        metavar="REL[,REL...]",
        help=f"pose relation(s) of APE and RPE, evo's names: {', '.join(POSE_RELATIONS)} "
        "(point_distance_error_ratio: RPE only)",
    )
    p.add_argument(
        "--delta", type=float, default=1, help="RPE step, in --delta-unit (frames: an integer)"
    )
    p.add_argument(
        "--delta-unit",
        choices=DELTA_UNITS,
        default="f",
        help="RPE step unit: f frames, m metres travelled, d degrees, r radians",
    )
    p.add_argument(
        "--all-pairs", action="store_true", help="RPE from every pose, not consecutive segments"
    )
    p.add_argument(
        "--delta-tol",
        type=float,
        default=None,
        help="--all-pairs with m/d/r: relative tolerance of delta (default 0.1)",
    )
    p.add_argument(
        "--pairs-from-reference",
        action="store_true",
        help="choose the RPE pairs on REF instead of the aligned EST",
    )
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument(
        "--save-results", default=None, help="write every error as JSON here (for compare-results)"
    )
    p.add_argument(
        "--plot", default=None, help="write PNGs (errors over time, trajectories) into this folder"
    )
    p.add_argument("--force", action="store_true", help="replace existing results/plots")
    add_processing(p)
    p.set_defaults(func=run)
    return p


def _align(args) -> str:
    """``--align`` with evo's ``-s``: se3 -> sim3, none -> scale."""
    from ..errors import InputError

    if not args.correct_scale:
        return args.align
    if args.align in ("origin", "scale"):
        raise InputError(
            f"-s/--correct-scale goes with --align none, se3 or sim3, not {args.align!r}"
        )
    return {"none": "scale", "se3": "sim3", "sim3": "sim3"}[args.align]


def _label(files) -> str:
    return "+".join("stdin" if f == "-" else Path(f).stem for f in files)


def run(args) -> int:
    from ..errors import InputError
    from ..evaluation import compare_trajectories, merge_streams
    from ..io import atomic_output
    from ._processing import check_text, parse_processing, process, read_all

    align = _align(args)
    if args.delta_tol is not None and not (args.all_pairs and args.delta_unit != "f"):
        raise InputError("--delta-tol applies to --all-pairs with --delta-unit m, d or r")
    if len(args.estimate) > 1 and not args.merge:
        raise InputError(
            f"{len(args.estimate)} estimate files: give --merge to merge them "
            "into one trajectory (by time)"
        )
    proc = parse_processing(args)
    (ref,), checks = read_all(args, [args.reference], proc=proc, name="reference")
    ests, est_checks = read_all(args, args.estimate, "2", proc=proc, name="estimate")
    checks.update(est_checks)
    est = merge_streams(ests) if len(ests) > 1 else ests[0]
    del ests
    ref = process(ref, proc, transform=False)
    est = process(est, proc)
    labels = (_label([args.reference]), _label(args.estimate))
    res = compare_trajectories(
        ref,
        est,
        labels=labels,
        t_max_diff=args.t_max_diff,
        t_offset=args.t_offset,
        align=align,
        n_to_align=args.n_to_align,
        delta=args.delta,
        delta_unit=args.delta_unit,
        delta_tol=0.1 if args.delta_tol is None else args.delta_tol,
        all_pairs=args.all_pairs,
        pairs_from_reference=args.pairs_from_reference,
        pose_relations=args.pose_relation,
    )
    if args.save_results:
        with atomic_output(args.save_results, overwrite=args.force) as tmp:
            tmp.write_text(json.dumps(res.as_dict(arrays=True)) + "\n")
    if args.plot:
        from ..plotting import plot_compare

        out = Path(args.plot)
        out.mkdir(parents=True, exist_ok=True)
        for path in plot_compare(out, res, *labels, overwrite=args.force):
            print(path)
    if args.json:
        d = res.as_dict()
        if checks:
            d["full_check"] = checks
        print(json.dumps(d, indent=2))
    else:
        if checks:
            print(check_text(checks))
        print(res.table())
    return 0
