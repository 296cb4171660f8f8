"""``trackflow plan SETUP.yaml``: show the dataflow the planner builds for a query."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import InputError


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "plan",
        help="plan the dataflow of a query in a YAML setup",
        description="Find the path(s) for a query in a setup's spatial relationship graph and "
        "print the dataflow network the planner builds (thesis 7.4).",
    )
    p.add_argument(
        "setup",
        type=Path,
        nargs="+",
        help="YAML setup file, or a realm's agent files (planned on their union graph)",
    )
    p.add_argument("--from", dest="source", help="source frame (default: the setup's query)")
    p.add_argument("--to", dest="target", help="target frame")
    p.add_argument("--query", help="name of a query in the setup (default: the first)")
    p.add_argument("--mode", choices=("pull", "push"), default=None, help="delivery mode")
    p.add_argument("--rate", type=float, default=None, help="push rate [Hz]")
    p.add_argument("--offset-ms", type=float, default=0.0, help="push time offset [ms]")
    p.add_argument("--fuse", action="store_true", help="fuse all independent paths")
    p.add_argument("--static", action="store_true", help="the relationship is static")
    p.add_argument("--evaluation", default=None, help="latency[:lambda] or covariance")
    p.add_argument("--naive", action="store_true", help="no time alignment (latest values)")
    p.add_argument("--explain", action="store_true", help="print why each component is there")
    p.add_argument("--dot", type=Path, default=None, help="write Graphviz dot to this file")
    p.add_argument("--force", action="store_true", help="replace an existing --dot file")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..distributed.realm_setup import realm_setup
    from ..graph import Query

    setup = realm_setup(args.setup)
    if args.source or args.target:
        if not (args.source and args.target):
            raise InputError("give both --from and --to")
        mode = args.mode or ("push" if args.rate else "pull")
        query = Query(
            args.source,
            args.target,
            evaluation=args.evaluation,
            mode=mode,
            rate_hz=args.rate,
            time_offset_s=args.offset_ms * 1e-3,
            fuse=args.fuse,
            static=args.static,
            name=f"{args.source}->{args.target}",
        )
    else:
        query = setup.query(args.query)
    plan = setup.plan(query, align=not args.naive)
    if args.explain:
        print(plan.explain())
    else:
        for path in plan.paths:
            print(f"path: {path}")
        print("dataflow: " + ", ".join(f"{n.id} ({n.label()})" for n in plan.nodes))
    if args.dot is not None:
        from ..io import atomic_output

        with atomic_output(args.dot, overwrite=args.force) as tmp:
            tmp.write_text(plan.to_dot())
        print(f"dot written to {args.dot}")
    return 0
