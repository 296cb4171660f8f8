"""``trackflow shift``: add a constant time offset (latency correction) to a recording."""

from __future__ import annotations

from ..evaluation import shift_stream
from ..io import write_stream
from ._common import add_input, load
from .cmd_convert import add_output


def register(subparsers):
    p = subparsers.add_parser("shift", help="shift timestamps by a constant offset")
    add_input(p)
    add_output(p)
    p.add_argument("--offset", type=float, required=True, help="seconds to add (may be < 0)")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    out = shift_stream(load(args.file, args.format, args.clean), args.offset)
    write_stream(args.output, out, format=args.to)
    return 0
