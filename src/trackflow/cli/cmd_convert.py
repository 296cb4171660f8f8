"""``trackflow convert``: read a recording in one format, write it in another."""

from __future__ import annotations

from ._common import add_input, add_output, load, save


def register(subparsers):
    p = subparsers.add_parser("convert", help="convert a recording between formats")
    add_input(p)
    add_output(p)
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    save(args, load(args))
    return 0
