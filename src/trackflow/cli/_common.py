"""Helpers shared by the PoseTool subcommands: reading recordings and parsing lists."""

from __future__ import annotations

import argparse

import numpy as np

from ..evaluation import LEARNED_ORDERS
from ..io import FORMATS, PoseStream, read_stream

__all__ = ["add_input", "load", "parse_horizons", "parse_ints", "parse_orders"]


def add_input(parser: argparse.ArgumentParser, name: str = "file") -> None:
    """Add a recording argument with ``--format`` and ``--clean``."""
    parser.add_argument(name, help="recording (format guessed from content/extension)")
    parser.add_argument("--format", choices=FORMATS, default=None, help="input format")
    parser.add_argument(
        "--clean",
        action="store_true",
        help="drop/repair malformed rows instead of failing (listed on stderr)",
    )


def load(path, format=None, clean=False) -> PoseStream:
    """Read a recording; with ``clean`` a summary of the changes goes to stderr."""
    import sys

    stream, report = read_stream(path, format=format, clean=clean)
    if clean:
        print(str(report), file=sys.stderr)
    return stream


def parse_horizons(text: str) -> tuple[float, ...]:
    """``"10,20,50"`` (milliseconds) -> horizons in seconds."""
    try:
        ms = [float(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise ValueError(f"horizons must be comma-separated milliseconds, got {text!r}") from exc
    if not ms or any(not np.isfinite(v) or v <= 0 for v in ms):
        raise ValueError(f"horizons must be positive milliseconds, got {text!r}")
    return tuple(v / 1e3 for v in ms)


def parse_ints(text: str) -> tuple[int, ...]:
    """``"1,2,3"`` -> ``(1, 2, 3)``; anything else is a ``ValueError``."""
    try:
        out = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError as exc:
        raise ValueError(f"expected comma-separated integers, got {text!r}") from exc
    if not out:
        raise ValueError(f"expected comma-separated integers, got {text!r}")
    return out


def add_learned_orders(p) -> None:
    """The ``--learned-orders`` option of ``tune`` and ``evaluate`` (see :func:`parse_orders`)."""
    p.add_argument(
        "--learned-orders",
        default=",".join(str(v) for v in LEARNED_ORDERS),
        help="orders of the learned increment models the tuning tries ('none': derivative "
        "models only)",
    )


def parse_orders(text: str) -> tuple[int, ...]:
    """``"3,5,10"`` -> ``(3, 5, 10)``; ``"none"`` -> ``()`` (no learned models)."""
    return () if text.strip().lower() == "none" else parse_ints(text)
