"""``trackflow info``: rate, duration, gaps, jitter and speed statistics of a recording."""

from __future__ import annotations

import json

from ._common import add_input, load


def register(subparsers):
    p = subparsers.add_parser("info", help="rate, duration, gaps, jitter, speed statistics")
    add_input(p)
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..evaluation import stream_info

    info = stream_info(load(args))
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    for key, value in info.items():
        if isinstance(value, dict):
            value = ", ".join(f"{k} {v:.4g}" for k, v in value.items())
        elif isinstance(value, float):
            value = f"{value:.6g}"
        print(f"{key:<24} {value}")
    return 0
