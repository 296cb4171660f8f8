"""``trackflow scale-cov``: multiply every covariance of a recording by a factor."""

from __future__ import annotations

from ._common import add_input, add_output, load, save


def register(subparsers):
    p = subparsers.add_parser("scale-cov", help="scale the covariances by a factor")
    add_input(p)
    add_output(p)
    p.add_argument("--factor", type=float, required=True, help="covariance multiplier (> 0)")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..evaluation import scale_covariance

    save(args, scale_covariance(load(args), args.factor))
    return 0
