"""``trackflow status --realm NAME [--watch]``: every agent of a realm, read-only, in the
terminal."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "status",
        help="show every agent of a distributed realm (read-only)",
        description="Join a Zenoh realm read-only and print each agent: how its links are "
        "protected, its sensors (live inputs; measured against declared attributes), each "
        "query's state, current path, switches and re-plans, and its rejections "
        "(docs/distributed.md).",
    )
    p.add_argument("--realm", required=True, help="the realm's name (agent: realm:)")
    p.add_argument(
        "--connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="a Zenoh endpoint of an agent (tcp/127.0.0.1:7447; repeatable)",
    )
    p.add_argument(
        "--zenoh-config",
        type=Path,
        default=None,
        help="a complete Zenoh configuration (a secure realm: an observer's from realm init)",
    )
    p.add_argument("--watch", action="store_true", help="print again every second (Ctrl-C)")
    p.add_argument("--json", action="store_true", help="one JSON object per print")
    p.add_argument("--timeout", type=float, default=2.0, help="wait for replies [s]")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..distributed.realm_status import observer_config, realm_status, status_text
    from ..optional import require

    zenoh = require("zenoh", extra="distributed", feature="trackflow status")
    conf = observer_config(zenoh, args.connect, args.zenoh_config)
    with zenoh.open(conf) as session:
        while True:
            st = realm_status(session, args.realm, args.timeout)
            print(json.dumps(st) if args.json else status_text(args.realm, st), flush=True)
            if not args.watch:
                return 0
            time.sleep(1.0)
