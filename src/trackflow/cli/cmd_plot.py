"""``trackflow plot``: PNGs of a sequence (measured/filtered/predicted) and error vs horizon."""

from __future__ import annotations

from pathlib import Path

from ..evaluation import Trajectory, evaluate_recording
from ..plotting import plot_error_vs_horizon, plot_sequence
from ._common import add_input, load, parse_horizons


def register(subparsers):
    p = subparsers.add_parser("plot", help="PNG plots: sequence over time, error vs horizon")
    add_input(p)
    p.add_argument("--out", default=".", help="output folder (created)")
    p.add_argument("--horizon", type=float, default=100.0, help="prediction horizon (ms)")
    p.add_argument("--start", type=float, default=None, help="window start (s from first)")
    p.add_argument("--length", type=float, default=3.0, help="window length (s)")
    p.add_argument("--horizons", default="10,20,50,100,200", help="ms, for the error plot")
    p.add_argument("--tune-fraction", type=float, default=0.5, help="as for evaluate")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    recording = Trajectory.from_stream(load(args.file, args.format, args.clean))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    report = evaluate_recording(recording, parse_horizons(args.horizons), args.tune_fraction)
    t_end = recording.t[-1]
    start = t_end * max(args.tune_fraction, 0.0) if args.start is None else args.start
    stem = Path(args.file).stem
    plot_sequence(out / f"{stem}_sequence.png", recording, report.predictor,
                  args.horizon / 1e3, (start, start + args.length))  # fmt: skip
    plot_error_vs_horizon(out / f"{stem}_error_vs_horizon.png", report)
    print(out / f"{stem}_sequence.png")
    print(out / f"{stem}_error_vs_horizon.png")
    return 0
