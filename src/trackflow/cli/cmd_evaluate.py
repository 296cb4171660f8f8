"""``trackflow evaluate``: prediction-error tables (thesis 9.2.1, tables 9.2-9.5)."""

from __future__ import annotations

import json
import sys

from ..evaluation import Trajectory, evaluate_recording
from ._common import add_input, add_learned_orders, load, parse_horizons, parse_orders


def register(subparsers):
    p = subparsers.add_parser(
        "evaluate",
        help="prediction error of the tuned Kalman filter vs linear extrapolation and none",
        description="Tune on the first part of a recording, then score predictions "
        "h ahead of every later sample against the interpolated recording.",
    )
    add_input(p)
    p.add_argument("--horizons", default="10,20,50,100,200", help="milliseconds, comma-separated")
    p.add_argument(
        "--tune-fraction",
        type=float,
        default=0.5,
        help="fraction of the duration to tune on (0 = no tuning, default model); "
        "the rest is scored",
    )
    p.add_argument("--tune-horizons", default="50,100", help="horizons the tuning cost uses (ms)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    add_learned_orders(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    recording = Trajectory.from_stream(load(args.file, args.format, args.clean))
    report = evaluate_recording(
        recording,
        horizons=parse_horizons(args.horizons),
        tune_fraction=args.tune_fraction,
        tune_horizons=parse_horizons(args.tune_horizons),
        ar_orders=parse_orders(args.learned_orders),
        progress=None if args.quiet else sys.stderr,
    )
    if args.json:
        print(json.dumps(report.as_dict(), indent=2))
    else:
        print(report.table())
    return 0
