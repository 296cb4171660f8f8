"""Why a live packet costs more CPU than the same packet in a hot loop: the idle core.

``bench/trackers_cpu.py`` runs the work of one 20-body NatNet packet (decode, samples, 20
filter updates, 20 answers) back to back. In ``bench/trackers.py`` the receiving thread
sleeps for the 4.2 ms between two packets, and the same work then takes much more CPU. This
script separates the two causes:

1. ``cpu``: the per-packet thread CPU time of ``trackers_cpu.measure`` with, before each
   packet, nothing (hot loop), a sleep of the packet period (the thread blocks, the core may
   go idle) or a busy wait of the same length (the core stays busy with this thread).
2. ``e2e``: ``trackers.e2e_latency`` as shipped (the receiving thread blocks in its selector)
   and with the selector of the NatNet input (``trackflow.trackers.natnet_input``)
   replaced by one that polls without blocking (the thread spins: the core never idles, at
   the price of a full core).

Usage: ``PYTHONPATH=src python experiments/trackers_idle_core.py [--seconds S] [--packets N]``
(prints one JSON object). The spinning selector is an experiment, not an option of the
library.
"""

from __future__ import annotations

import argparse
import json
import selectors
import sys
import time
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

import trackers  # noqa: E402  (bench/trackers.py)
import trackers_cpu  # noqa: E402  (bench/trackers_cpu.py)
from trackflow.trackers import natnet_input  # noqa: E402

PERIOD_S = 1.0 / trackers.RATE


def _sleep() -> None:
    time.sleep(PERIOD_S)


def _spin() -> None:
    end = time.perf_counter() + PERIOD_S
    while time.perf_counter() < end:
        pass


class _SpinningSelector(selectors.DefaultSelector):
    """A selector whose ``select`` polls without blocking until ready or timed out."""

    def select(self, timeout=None):
        end = time.monotonic() + (timeout or 0.0)
        while True:
            ready = super().select(0)
            if ready or time.monotonic() > end:
                return ready


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=15.0, help="length of each e2e run")
    ap.add_argument("--packets", type=int, default=800)
    ap.add_argument(
        "--recording",
        type=Path,
        default=ROOT.parent / "shared" / "data" / "tumvi" / "dataset-room1_512_16.txt",
    )
    args = ap.parse_args(argv)
    if not args.recording.exists():  # a worktree beside the main checkout
        args.recording = Path("/work/shared/data/tumvi/dataset-room1_512_16.txt")
    out: dict = {"cpu_p50_us": {}, "e2e_us": {}}
    for name, between in (("hot", None), ("sleep", _sleep), ("spin", _spin)):
        out["cpu_p50_us"][name] = trackers_cpu.measure(args.packets, between)["p50"]
    keys = ("p50", "p99", "wake_p50", "wake_p99", "handle_p50", "service_p50")
    lat = trackers.e2e_latency(args.seconds, args.recording)
    out["e2e_us"]["blocking"] = {k: round(lat[k]) for k in keys}
    shipped = natnet_input.selectors
    natnet_input.selectors = types.SimpleNamespace(
        DefaultSelector=_SpinningSelector, EVENT_READ=selectors.EVENT_READ
    )
    try:
        lat = trackers.e2e_latency(args.seconds, args.recording)
    finally:
        natnet_input.selectors = shipped
    out["e2e_us"]["spinning"] = {k: round(lat[k]) for k in keys}
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
