"""``trackflow evaluate``: prediction-error tables (thesis 9.2.1, tables 9.2-9.5)."""

from __future__ import annotations

import json
import sys

from ._common import (
    add_input,
    add_learned_orders,
    load,
    parse_horizons,
    parse_orders,
)
from ._progress import FinishingStream


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
    p.set_defaults(func=run)
    return p


def describe_model(d: dict) -> str:
    """One line naming the chosen filter: family, derivative counts or learned order."""
    fam = d.get("family") or d.get("kind")
    if fam == "partwise":
        return (
            f"position: {describe_model(d['position'])}; "
            f"orientation: {describe_model(d['orientation'])}"
        )
    if fam in ("twist_ar",) or d.get("kind") == "twist_ar":
        return f"learned increment model of order {d.get('order')}"
    return (
        f"derivative model ({d.get('n_dp')} position, {d.get('n_do')} orientation "
        f"derivatives, {d.get('kind')} noise)"
    )


def run(args) -> int:
    from ..evaluation import Trajectory, evaluate_recording

    recording = Trajectory.from_stream(load(args, min_samples=10))
    report = evaluate_recording(
        recording,
        horizons=parse_horizons(args.horizons),
        tune_fraction=args.tune_fraction,
        tune_horizons=parse_horizons(args.tune_horizons),
        ar_orders=parse_orders(args.learned_orders),
        progress=None if args.quiet else FinishingStream(sys.stderr),
    )
    if args.json:
        print(json.dumps(report.as_dict(), indent=2))
    else:
        print(f"kalman = {describe_model(report.predictor.as_dict())}")
        print(report.table())
    return 0
