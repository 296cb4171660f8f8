"""``trackflow tune``: automatic Kalman filter tuning (thesis 8.1.4); prints the model."""

from __future__ import annotations

import json
import sys

from ._common import (
    add_input,
    add_learned_orders,
    load,
    parse_horizons,
    parse_ints,
    parse_orders,
)
from ._progress import FinishingStream


def register(subparsers):
    p = subparsers.add_parser("tune", help="tune the motion model's process noise (Powell)")
    add_input(p)
    p.add_argument("--horizons", default="50,100", help="horizons the cost uses (ms)")
    p.add_argument("--pos-derivatives", default="1,2,3", help="candidate position derivatives")
    p.add_argument("--ori-derivatives", default="1,2", help="candidate orientation derivatives")
    add_learned_orders(p)
    p.add_argument(
        "--output", "-o", default=None, help="write the model file for 'trackflow filter --model'"
    )
    p.add_argument("--force", action="store_true", help="replace an existing --output")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..evaluation import Trajectory, save_model, tune_model

    recording = Trajectory.from_stream(load(args, min_samples=10))
    res = tune_model(
        recording, parse_horizons(args.horizons), parse_ints(args.pos_derivatives),
        parse_ints(args.ori_derivatives), ar_orders=parse_orders(args.learned_orders),
        progress=None if args.quiet else FinishingStream(sys.stderr),
    )  # fmt: skip
    if args.output is not None:
        save_model(args.output, res.predictor, tuning=res.as_dict(), overwrite=args.force)
    print(json.dumps({"motion_model": res.predictor.as_dict(), **res.as_dict()}, indent=2))
    return 0
