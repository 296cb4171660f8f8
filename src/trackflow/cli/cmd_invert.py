"""``trackflow invert``: T_a_b -> T_b_a with covariances propagated."""

from __future__ import annotations

from ..evaluation import invert_stream
from ..io import write_stream
from ._common import add_input, load
from .cmd_convert import add_output


def register(subparsers):
    p = subparsers.add_parser("invert", help="invert every pose (T_a_b -> T_b_a)")
    add_input(p)
    add_output(p)
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    write_stream(args.output, invert_stream(load(args.file, args.format, args.clean)), args.to)
    return 0
