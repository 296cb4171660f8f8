"""``trackflow filter``: run a tuned pose Kalman filter, write filtered poses with covariances.

Without ``--model`` the filter is tuned on the recording itself first (as ``tune`` does), so
the default output's covariances describe the recording; ``--model`` takes a file written by
``tune --output`` (any family, the learned one included). A summary of how the filter fared
(rejected measurements, resets, mean NIS against its 99 % band) goes to standard error.
"""

from __future__ import annotations

import sys

from ..errors import InputError
from ._common import (
    add_input,
    add_learned_orders,
    add_output,
    load,
    parse_horizons,
    parse_orders,
    save,
)
from ._progress import FinishingStream


def register(subparsers):
    p = subparsers.add_parser(
        "filter",
        help="Kalman-filter a recording (tuned on it, or a model file from tune --output)",
        description=__doc__.split("\n\n", 1)[1],
    )
    add_input(p)
    add_output(p)
    p.add_argument("--model", default=None, help="model file from 'trackflow tune --output'")
    p.add_argument("--horizon", type=float, default=0.0, help="predict this many ms ahead")
    p.add_argument("--tune-horizons", default="50,100", help="horizons the tuning uses (ms)")
    add_learned_orders(p)
    p.add_argument(
        "--no-calibrate",
        action="store_true",
        help="keep the model's noise as it is (default: scale it so that the mean NIS on this "
        "recording matches the measurement dimension, making the output sigmas honest)",
    )
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..evaluation import Trajectory, filter_stream, load_model, tune_model

    if not (args.horizon >= 0 and args.horizon < 1e7):
        raise InputError(f"--horizon must be >= 0 ms, got {args.horizon}")
    stream = load(args, min_samples=10)
    if args.model is not None:
        pred = load_model(args.model)
    else:
        pred = tune_model(
            Trajectory.from_stream(stream), parse_horizons(args.tune_horizons),
            # predictions ahead need covariances, which the learned model does not give
            ar_orders=parse_orders(args.learned_orders) if args.horizon == 0 else (),
            progress=None if args.quiet else FinishingStream(sys.stderr),
        ).predictor  # fmt: skip
    res = filter_stream(stream, pred, args.horizon / 1e3, calibrate=not args.no_calibrate)
    save(args, res.stream)
    if not args.quiet:
        mean, lo, hi = res.nis_band()
        inside = "inside" if lo <= mean <= hi else "OUTSIDE"
        print(
            f"filtered {len(stream)} samples ({pred.as_dict()['family']} model): "
            f"{res.rejected} rejected, {res.resets} resets, mean NIS {mean:.3g} "
            f"({inside} the 99 % band {lo:.3g}..{hi:.3g}); noise variance scale "
            + ", ".join(f"{k:.3g}" for k in res.noise_scale),
            file=sys.stderr,
        )
    return 0
