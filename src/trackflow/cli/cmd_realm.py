"""``trackflow realm init AGENT.yaml ...``: the certificates and Zenoh configurations of a
secure realm (TLS with mutual authentication, access control by identity)."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "realm",
        help="make a secure realm's CA, certificates and Zenoh configurations",
        description="From the realm's agent files: a CA, a certificate per agent (and per "
        "observer), and per agent a Zenoh configuration with mutual TLS and access control "
        "that lets each agent publish only its own sensors' states and results, declare only "
        "its own tokens and answer only its own queryables (docs/distributed.md). Point each "
        "agent's 'zenoh_config:' at its file.",
    )
    sub = p.add_subparsers(dest="action", required=True)
    init = sub.add_parser("init", help="write a new realm's files into a folder")
    init.add_argument("agents", type=Path, nargs="+", help="the realm's agent YAML files")
    init.add_argument("--out", type=Path, required=True, help="folder for the realm's files")
    init.add_argument(
        "--endpoint",
        action="append",
        default=[],
        metavar="NAME=HOST:PORT",
        help="where agent NAME listens (default localhost:7447, 7448, ... in file order)",
    )
    init.add_argument(
        "--observer",
        action="append",
        default=[],
        metavar="NAME",
        help="an identity that may only subscribe and ask (a monitoring tool, the view)",
    )
    init.add_argument("--days", type=int, default=365, help="certificates valid this long")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..distributed import load_agent
    from ..distributed.realm import init_realm, realm_members
    from ..errors import InputError

    endpoints = {}
    for item in args.endpoint:
        name, sep, where = item.partition("=")
        if not sep or ":" not in where:
            raise InputError(f"--endpoint {item!r}: expected NAME=HOST:PORT")
        endpoints[name] = where
    agents = [load_agent(path) for path in args.agents]
    realm, members = realm_members(agents, endpoints)
    files = init_realm(realm, members, args.out, args.observer, args.days)
    print(f"realm {realm!r}: CA {files.ca} (keep ca.key offline)")
    for m in members:
        print(f"  {m.name}: listens on tls/{m.endpoint}; in its agent file: "
              f"zenoh_config: {files.configs[m.name]}")  # fmt: skip
    for o in args.observer:
        print(f"  {o} (observer): {files.configs[o]}")
    return 0
