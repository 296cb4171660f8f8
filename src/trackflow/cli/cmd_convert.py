"""``trackflow convert``: read a recording in one format, write it in another."""

from __future__ import annotations

from ..io import FORMATS, write_stream
from ._common import add_input, load


def add_output(p) -> None:
    p.add_argument("output", help="output file (format from --to or its extension)")
    p.add_argument("--to", choices=FORMATS, default=None, help="output format")


def register(subparsers):
    p = subparsers.add_parser("convert", help="convert a recording between formats")
    add_input(p)
    add_output(p)
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    write_stream(args.output, load(args.file, args.format, args.clean), format=args.to)
    return 0
