"""``trackflow compare-results A.json B.json ...``: saved comparisons side by side (evo_res)."""

from __future__ import annotations

import json
from pathlib import Path


def register(subparsers):
    p = subparsers.add_parser(
        "compare-results",
        help="several 'compare --save-results' files side by side (table, JSON, plots)",
        description="Load results written by 'trackflow compare --save-results FILE' and show "
        "their statistics side by side: one table per metric that they all have, one row per "
        "result; settings in which they differ are named (as evo_res).",
    )
    p.add_argument("results", nargs="+", help="result files (compare --save-results)")
    p.add_argument(
        "--names", default=None, help="comma-separated row names (default: the file names)"
    )
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument(
        "--plot", default=None, help="write one PNG per metric (errors over time, box plots) here"
    )
    p.add_argument("--force", action="store_true", help="replace existing plots")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..errors import InputError
    from ..evaluation import compare_results, load_result

    names = [Path(f).stem for f in args.results]
    if args.names is not None:
        names = [n.strip() for n in args.names.split(",")]
        if len(names) != len(args.results) or not all(names):
            raise InputError(
                f"--names needs {len(args.results)} non-empty names, got {args.names!r}"
            )
    comparison = compare_results([load_result(f) for f in args.results], names)
    if args.plot:
        from ..plotting import plot_results

        out = Path(args.plot)
        out.mkdir(parents=True, exist_ok=True)
        for path in plot_results(out, comparison, overwrite=args.force):
            print(path)
    print(json.dumps(comparison.as_dict(), indent=2) if args.json else comparison.table())
    return 0
