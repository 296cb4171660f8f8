"""``trackflow optical SETUP.yaml``: run the optical tracker as a sensor of a dataflow query."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "optical",
        help="track marker bodies in infrared frames and answer a setup's query",
        description="Run the optical tracker (docs/optical.md) of an optical setup file as the "
        "sensor(s) of its trackflow setup, answer a query and print a summary as JSON.",
    )
    p.add_argument("setup", type=Path, help="optical setup YAML (see examples/optical.yaml)")
    p.add_argument("--query", help="query of the trackflow setup (default: the first)")
    p.add_argument("--out", type=Path, default=None, help="write the results (.tfrec)")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..optical.source import load_optical_setup

    opt = load_optical_setup(args.setup)
    query = opt.setup.query(args.query)
    plan = opt.setup.plan(query)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
    net, sink = plan.build(opt.sources(), record=args.out)
    net.run()
    stats = net.stats()
    tracker = opt.run.tracker
    summary = {
        "query": query.name,
        "results": len(getattr(sink, "events", [])),
        "frames": tracker.stats["frames"],
        "tracker": tracker.stats,
        "pixel_sigma_estimate_px": round(tracker.pixel_sigma_estimate(), 4),
        "sensors": {name: stats[name] for name in opt.bodies},
        "out": None if args.out is None else str(args.out),
    }
    print(json.dumps(summary, indent=1))
    return 0
