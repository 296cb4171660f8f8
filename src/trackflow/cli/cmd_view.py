"""``trackflow view``: the browser view of a live setup or a recording (thesis 8.2)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import add_input


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "view",
        help="3D browser view of a setup (live) or a recording (timeline), with error ellipsoids",
        description="Serve a viser page showing poses with their position and orientation error "
        "glyphs. A YAML setup runs its network (simulated sensors where no recording is given) "
        "and shows every frame, sensor and query with the SRG panel; a recording gets a "
        "timeline. With --snapshot nothing is served for long: one frame is rendered to PNG "
        "through headless Chromium and the command exits.",
    )
    add_input(p, "target", nargs="?")
    p.add_argument(
        "more",
        nargs="*",
        metavar="FILE",
        help="further agent or setup files of one realm: viewed with the first as the one "
        "setup they make together (as `trackflow plan` plans them)",
    )
    p.add_argument("--host", default="127.0.0.1", help="bind address (default loopback only)")
    p.add_argument("--port", type=int, default=8080, help="port (0: any free port)")
    p.add_argument("--snapshot", type=Path, default=None, help="write one frame to this PNG")
    p.add_argument("--at", type=float, default=None, help="time [s] of the snapshot/start")
    p.add_argument("--sigma", type=int, choices=(1, 2, 3), default=1, help="sigma level")
    p.add_argument("--offset-ms", type=float, default=0.0, help="prediction offset [ms]")
    p.add_argument(
        "--magnify",
        type=float,
        default=None,
        help="draw ellipsoids this many times their size (default: 1 live, automatic for a "
        "recording)",
    )
    p.add_argument("--query", default=None, help="setup: the selected query (default first)")
    p.add_argument(
        "--anchor",
        default=None,
        metavar="FRAME",
        help="setup: draw the scene in this frame (default: the room - a frame named world, "
        "room, map or W, else a root of the graph; the page's 'anchor' control changes it)",
    )
    p.add_argument(
        "--posetool",
        action="store_true",
        help="recording: the PoseTool page (hand-tune the Kalman predictor beside the "
        "automatic tuning; --offset-ms sets the starting horizon)",
    )
    realm = p.add_argument_group("realm (a distributed realm, read-only; no target file)")
    realm.add_argument(
        "--realm",
        default=None,
        metavar="NAME",
        help="show the running realm NAME: every agent, its sensors and queries, the union "
        "graph, the queries' paths, re-plans and switches, and the answers (docs/viewer.md)",
    )
    realm.add_argument(
        "--connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="--realm: a Zenoh endpoint of an agent (tcp/127.0.0.1:7447; repeatable)",
    )
    realm.add_argument(
        "--zenoh-config",
        type=Path,
        default=None,
        help="--realm: a complete Zenoh configuration (a secure realm: an observer's from "
        "realm init)",
    )
    p.add_argument(
        "--camera",
        type=_point,
        default=None,
        metavar="X,Y,Z",
        help="recording: place the camera here [m, the recording's source frame] (with "
        "--look-at; the body is then not followed)",
    )
    p.add_argument(
        "--look-at", type=_point, default=None, metavar="X,Y,Z", help="with --camera: its aim"
    )
    p.add_argument("--no-panel", action="store_true", help="snapshot: without the control panel")
    p.add_argument("--width", type=int, default=1280, help="snapshot width [px]")
    p.add_argument("--height", type=int, default=800, help="snapshot height [px]")
    p.set_defaults(func=run)
    return p


def _point(text: str) -> tuple[float, float, float]:
    """``X,Y,Z`` as three floats (argparse reports a bad one with the option's name)."""
    parts = text.split(",")
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"expected X,Y,Z, got {text!r}")
    try:
        return tuple(float(v) for v in parts)  # type: ignore[return-value]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected three numbers X,Y,Z, got {text!r}") from None


def run(args) -> int:
    from ..distributed.realm_setup import is_agent_file
    from ..errors import InputError
    from ..viewer import ViewOptions, is_setup, serve

    if (args.camera is None) != (args.look_at is None):
        raise InputError("--camera and --look-at go together")
    if args.no_panel and args.snapshot is None:
        raise InputError("--no-panel applies to --snapshot (the served page keeps its panel)")
    if args.realm is not None and args.camera is not None:
        raise InputError("--camera applies to a recording's view, not to --realm")
    if args.realm is not None:
        if args.target is not None or args.more:
            raise InputError("--realm views a running realm: give no file")
        from ._realm_view import view_realm

        return view_realm(args)
    if args.target is None:
        raise InputError("give a recording, a setup or agent files, or --realm NAME")
    if args.connect or args.zenoh_config is not None:
        raise InputError("--connect and --zenoh-config go with --realm")

    opts = ViewOptions(
        host=args.host,
        port=0 if args.snapshot is not None else args.port,
        at_s=args.at,
        sigma=args.sigma,
        offset_s=args.offset_ms * 1e-3,
        query=args.query,
        format=args.format,
        clean=args.clean,
        posetool=args.posetool,
        magnify=args.magnify,
        anchor=args.anchor,
        camera=None if args.camera is None else (args.camera, args.look_at),
        no_panel=args.no_panel,
    )
    target = args.target
    files = [args.target, *args.more]
    if args.more or is_agent_file(args.target):
        if not all(is_setup(f) for f in files):
            raise InputError("several files are viewed together only as setups or agent files")
        from ..distributed.realm_setup import realm_setup

        target = realm_setup(files)  # as `trackflow plan` plans them
    out = serve(target, opts, snapshot=args.snapshot, size=(args.width, args.height))
    if out is not None:
        print(f"snapshot written to {out}")
    return 0
