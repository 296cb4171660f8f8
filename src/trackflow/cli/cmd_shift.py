"""``trackflow shift``: add a constant time offset (latency correction) to a recording."""

from __future__ import annotations

from ._common import add_input, add_output, load, save


def register(subparsers):
    p = subparsers.add_parser("shift", help="shift timestamps by a constant offset")
    add_input(p)
    add_output(p)
    p.add_argument(
        "--offset", type=float, required=True, help="seconds to add (may be < 0: --offset -2e9)"
    )
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..evaluation import shift_stream

    save(args, shift_stream(load(args), args.offset))
    return 0
