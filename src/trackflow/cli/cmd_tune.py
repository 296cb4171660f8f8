"""``trackflow tune``: automatic Kalman filter tuning (thesis 8.1.4); prints the model."""

from __future__ import annotations

import json
import sys

from ..evaluation import Trajectory, tune_model
from ._common import add_input, add_learned_orders, load, parse_horizons, parse_ints, parse_orders


def register(subparsers):
    p = subparsers.add_parser("tune", help="tune the motion model's process noise (Powell)")
    add_input(p)
    p.add_argument("--horizons", default="50,100", help="horizons the cost uses (ms)")
    p.add_argument("--pos-derivatives", default="1,2,3", help="candidate position derivatives")
    p.add_argument("--ori-derivatives", default="1,2", help="candidate orientation derivatives")
    add_learned_orders(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    recording = Trajectory.from_stream(load(args.file, args.format, args.clean))
    res = tune_model(
        recording, parse_horizons(args.horizons), parse_ints(args.pos_derivatives),
        parse_ints(args.ori_derivatives), ar_orders=parse_orders(args.learned_orders),
        progress=None if args.quiet else sys.stderr,
    )  # fmt: skip
    print(json.dumps({"motion_model": res.predictor.as_dict(), **res.as_dict()}, indent=2))
    return 0
