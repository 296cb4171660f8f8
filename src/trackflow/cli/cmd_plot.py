"""``trackflow plot``: PNGs of a sequence (measured/filtered/predicted) and error vs horizon."""

from __future__ import annotations

import sys
from pathlib import Path

from ..errors import InputError
from ._common import add_input, load, parse_horizons
from ._progress import FinishingStream


def register(subparsers):
    p = subparsers.add_parser("plot", help="PNG plots: sequence over time, error vs horizon")
    add_input(p)
    p.add_argument("--out", default=".", help="output folder (created)")
    p.add_argument("--horizon", type=float, default=100.0, help="prediction horizon (ms)")
    p.add_argument(
        "--start", type=float, default=None, help="window start (s from first; default: "
        "the start of the scored part)"
    )  # fmt: skip
    p.add_argument("--length", type=float, default=3.0, help="window length (s)")
    p.add_argument("--horizons", default="10,20,50,100,200", help="ms, for the error plot")
    p.add_argument("--tune-fraction", type=float, default=0.5, help="as for evaluate")
    p.add_argument("--force", action="store_true", help="replace existing PNGs")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    import numpy as np

    from ..plotting import plot_error_vs_horizon, plot_sequence, require_matplotlib

    require_matplotlib()
    from ..evaluation import Trajectory, evaluate_recording

    recording = Trajectory.from_stream(load(args, min_samples=10))
    t = recording.t
    start = t[-1] * max(args.tune_fraction, 0.0) if args.start is None else args.start
    if not (np.isfinite(args.length) and args.length > 0):
        raise InputError(f"--length must be > 0 s, got {args.length}")
    inside = np.count_nonzero((t >= start) & (t <= start + args.length))
    if inside < 2:
        raise InputError(
            f"{stream_label(args)}: the window {start:g}..{start + args.length:g} s holds "
            f"{inside} samples; the recording spans 0..{t[-1]:.6g} s (choose --start/--length)"
        )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = "stdin" if args.file == "-" else Path(args.file).stem
    targets = [out / f"{stem}_sequence.png", out / f"{stem}_error_vs_horizon.png"]
    for path in targets:
        if path.exists() and not args.force:
            raise FileExistsError(f"{path}: exists already (pass --force)")
    report = evaluate_recording(
        recording, parse_horizons(args.horizons), args.tune_fraction,
        progress=None if args.quiet else FinishingStream(sys.stderr),
    )  # fmt: skip
    plot_sequence(targets[0], recording, report.predictor, args.horizon / 1e3,
                  (start, start + args.length), title=stem, overwrite=args.force)  # fmt: skip
    plot_error_vs_horizon(targets[1], report, title=stem, overwrite=args.force)
    for path in targets:
        print(path)
    return 0


def stream_label(args) -> str:
    return "<stdin>" if args.file == "-" else args.file
