"""``trackflow scale-cov``: multiply every covariance of a recording by a factor."""

from __future__ import annotations

from ..evaluation import scale_covariance
from ..io import write_stream
from ._common import add_input, load
from .cmd_convert import add_output


def register(subparsers):
    p = subparsers.add_parser("scale-cov", help="scale the covariances by a factor")
    add_input(p)
    add_output(p)
    p.add_argument("--factor", type=float, required=True, help="covariance multiplier (> 0)")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    out = scale_covariance(load(args.file, args.format, args.clean), args.factor)
    write_stream(args.output, out, format=args.to)
    return 0
