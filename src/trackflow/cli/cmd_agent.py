"""``trackflow agent SETUP.yaml``: run one agent of a distributed setup on Zenoh."""

from __future__ import annotations

import argparse
import json
import sys
import threading
from pathlib import Path


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "agent",
        help="run a distributed-tracking agent (Zenoh) for a YAML setup fragment",
        description="Join a Zenoh session, advertise this setup's sensors and static edges, "
        "discover the other agents' fragments and answer this setup's queries over the union "
        "graph (docs/distributed.md). Default network: loopback only, no multicast scouting.",
    )
    p.add_argument("setup", type=Path, help="agent YAML (a setup plus an 'agent:' section)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    p.add_argument("--mode", choices=("peer", "client", "router"), help="Zenoh mode")
    p.add_argument("--listen", action="append", default=None, help="Zenoh listen endpoint")
    p.add_argument("--connect", action="append", default=None, help="Zenoh connect endpoint")
    p.add_argument("--start-ns", type=int, default=None, help="agent time of recording time 0")
    p.add_argument(
        "--status",
        type=Path,
        default=None,
        help="keep the status JSON here: rewritten every second while running, final at exit",
    )
    p.add_argument(
        "--insecure",
        action="store_true",
        help="accept links off this machine without TLS and access control (said in status)",
    )
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..dataflow import stop_signals
    from ..distributed import load_agent, run_agent

    cfg = load_agent(args.setup)
    if any(spec.protocol == "optical" for spec in cfg.setup.inputs.values()):
        from .. import optical  # noqa: F401  (registers the 'optical' feed; layer 5 wires it)
    if args.mode:
        cfg.zenoh["mode"] = args.mode
    if args.listen is not None:
        cfg.zenoh["listen"] = {"endpoints": args.listen}
    if args.connect is not None:
        cfg.zenoh["connect"] = {"endpoints": args.connect}
    if args.start_ns is not None:
        cfg.start_ns = args.start_ns
    if args.insecure:
        cfg.insecure = True

    def ready(agent) -> None:
        print(json.dumps({"ready": agent.name, "realm": agent.realm}), flush=True)

    def write(status: dict) -> None:  # replaced whole: a reader never sees half a file
        tmp = args.status.with_name(args.status.name + ".tmp")
        tmp.write_text(json.dumps(status, indent=2))
        tmp.replace(args.status)

    stop = threading.Event()
    with stop_signals(lambda *_: stop.set()):  # SIGTERM/SIGHUP end the agent as Ctrl-C does
        status = run_agent(cfg, args.duration, on_ready=ready, stop=stop,
                           on_status=write if args.status is not None else None)  # fmt: skip
    if args.status is not None:
        write(status)
    else:
        print(json.dumps(status, indent=2))
    sys.stdout.flush()
    return 0
