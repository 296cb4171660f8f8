"""``trackflow plot-traj FILE...``: trajectories of several recordings overlaid (top/side/3D)."""

from __future__ import annotations

from pathlib import Path

VIEWS = ("top", "side", "front", "3d")


def register(subparsers):
    p = subparsers.add_parser(
        "plot-traj", help="PNG of several trajectories overlaid (top, side and 3D views)"
    )
    p.add_argument("files", nargs="+", help="recordings (formats guessed)")
    p.add_argument("--out", default="trajectories.png", help="output PNG")
    p.add_argument("--views", default="top,side,3d", help=f"comma-separated of {VIEWS}")
    p.add_argument("--clean", action="store_true", help="drop/repair malformed rows")
    p.add_argument("--quiet", action="store_true", help="no read reports on standard error")
    p.add_argument("--force", action="store_true", help="replace an existing PNG")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    import argparse

    from ..plotting import plot_trajectories, require_matplotlib
    from ._common import load

    require_matplotlib()
    views = tuple(v.strip() for v in args.views.split(",") if v.strip())
    streams = []
    for f in args.files:
        one = argparse.Namespace(file=f, format=None, clean=args.clean, quiet=args.quiet)
        streams.append(load(one))
    names = ["stdin" if f == "-" else Path(f).stem for f in args.files]
    plot_trajectories(args.out, streams, names, views, overwrite=args.force)
    print(args.out)
    return 0
