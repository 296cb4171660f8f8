"""``trackflow compile``: compile the numerical kernels ahead of time (``make`` runs it)."""

from __future__ import annotations

import argparse
import sys
import time


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "compile",
        help="compile the numba kernels ahead of time, so that every command's first run is fast",
        description="Run every kernel path of the command line once on a small synthetic "
        "recording, filling the on-disk cache of compiled code (once per installation; "
        "later runs load it in a fraction of a second). Does nothing without numba.",
    )
    p.add_argument("--quiet", action="store_true", help="no progress on standard error")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..evaluation import compile_kernels
    from ..math._backend import numpy_reason

    t0 = time.perf_counter()

    def say(step: str) -> None:
        if not args.quiet:
            print(f"trackflow: compiling: {step} ...", file=sys.stderr, flush=True)

    steps = compile_kernels(say)
    if steps:
        from ..trackers.inputs import warm_up_inputs

        say("live tracker packets (run)")
        warm_up_inputs()
    if not steps:
        print(
            f"trackflow: nothing to compile: {numpy_reason()}, so the kernels run as plain "
            "NumPy (about 100x slower)",
            file=sys.stderr,
        )
    elif not args.quiet:
        print(f"trackflow: kernels compiled in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0
