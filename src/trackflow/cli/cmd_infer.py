"""``trackflow infer``: chain two recordings T_x_y and T_y_z into T_x_z (time-aligned)."""

from __future__ import annotations

from ..evaluation import infer_streams
from ..io import FORMATS, write_stream
from ._common import add_input, load
from .cmd_convert import add_output


def register(subparsers):
    p = subparsers.add_parser(
        "infer",
        help="chain two recordings T_x_y @ T_y_z, time-aligned by pose Kalman filters",
        description="Each recording is Kalman-filtered and queried (smoothed) at the union of "
        "both recordings' timestamps; the aligned poses are composed with covariances.",
    )
    add_input(p, "first")
    p.add_argument("second", help="second recording (T_y_z)")
    p.add_argument("--format2", choices=FORMATS, default=None, help="format of the second")
    p.add_argument(
        "--interpolate",
        action="store_true",
        help="align by interpolating the second recording at the first's times instead",
    )
    add_output(p)
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    a = load(args.first, args.format, args.clean)
    b = load(args.second, args.format2, args.clean)
    method = "interpolate" if args.interpolate else "filter"
    write_stream(args.output, infer_streams(a, b, method=method), format=args.to)
    return 0
