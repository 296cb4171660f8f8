"""``trackflow plot-traj FILE...``: trajectories of several recordings overlaid (top/side/3D)."""

from __future__ import annotations

from pathlib import Path

from ._processing import add_processing

VIEWS = ("top", "side", "front", "3d")


def register(subparsers):
    p = subparsers.add_parser(
        "plot-traj",
        help="PNG of several trajectories overlaid (top, side and 3D views)",
        description="Overlay recordings in one PNG. With --ref, that recording is drawn too "
        "and is the reference of --sync; it is never merged or transformed (as in evo_traj).",
    )
    p.add_argument("files", nargs="+", help="recordings (formats guessed)")
    p.add_argument("--ref", default=None, help="reference recording (drawn first)")
    p.add_argument("--out", default="trajectories.png", help="output PNG")
    p.add_argument("--views", default="top,side,3d", help=f"comma-separated of {VIEWS}")
    p.add_argument("--clean", action="store_true", help="drop/repair malformed rows")
    p.add_argument("--quiet", action="store_true", help="no read reports on standard error")
    p.add_argument("--force", action="store_true", help="replace an existing PNG")
    add_processing(p, sync=True)
    p.set_defaults(func=run)
    return p


def _name(f: str) -> str:
    return "stdin" if f == "-" else Path(f).stem


def run(args) -> int:
    from ..errors import InputError
    from ..evaluation import merge_streams, sync_streams
    from ..plotting import plot_trajectories, require_matplotlib
    from ._processing import check_text, parse_processing, process, read_all

    require_matplotlib()
    views = tuple(v.strip() for v in args.views.split(",") if v.strip())
    if args.sync and args.ref is None:
        raise InputError("--sync associates the FILES with a reference: give --ref REF")
    if not args.sync and (args.t_max_diff is not None or args.t_offset is not None):
        raise InputError("--t-max-diff and --t-offset apply to --sync")
    proc = parse_processing(args)
    opts = dict(format=None, clean=args.clean, quiet=args.quiet)
    ns = type(args)(**opts, file=None)
    streams, checks = read_all(ns, args.files, proc=proc)
    names = [_name(f) for f in args.files]
    if args.merge:
        streams, names = [merge_streams(streams)], ["+".join(names)]
    streams = [process(s, proc) for s in streams]
    if args.ref is not None:
        (ref,), ref_check = read_all(ns, [args.ref], proc=proc)
        checks = {**ref_check, **checks}
        ref = process(ref, proc, transform=False)
        if args.sync:
            tmax = 0.01 if args.t_max_diff is None else args.t_max_diff
            toff = 0.0 if args.t_offset is None else args.t_offset
            streams = [sync_streams(ref, s, tmax, toff)[1] for s in streams]
        streams, names = [ref, *streams], [_name(args.ref), *names]
    if checks:
        print(check_text(checks))
    plot_trajectories(args.out, streams, names, views, overwrite=args.force)
    print(args.out)
    return 0
