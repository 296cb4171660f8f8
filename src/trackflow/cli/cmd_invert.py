"""``trackflow invert``: T_a_b -> T_b_a with covariances propagated."""

from __future__ import annotations

from ._common import add_input, add_output, load, save


def register(subparsers):
    p = subparsers.add_parser("invert", help="invert every pose (T_a_b -> T_b_a)")
    add_input(p)
    add_output(p)
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..evaluation import invert_stream

    save(args, invert_stream(load(args)))
    return 0
