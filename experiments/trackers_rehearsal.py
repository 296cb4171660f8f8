"""Why rehearsing a packet's path on twins makes the live packet cheaper.

One 20-body NatNet 4.1 packet (decode, 20 filter updates, 20 answers: the work of
``bench/trackers_cpu.py``) is timed from ``handle`` to the answers' delivery, one packet per
frame period (240 Hz), in one thread, without sockets:

* ``hot``: packets back to back (the hot loop);
* ``after_sleep``: the thread sleeps a frame period before each packet (as a receiving
  thread waits for the next datagram);
* ``second_after_sleep``: two packets after each sleep of two periods, the second timed: the
  same work right after the first, on a core that did not idle in between;
* ``rehearsed``: as ``after_sleep``, with a :class:`trackflow.trackers.rehearsal.Rehearsal`
  of the previous packet (twins: another input, sources and filters) over 0.4 ms before the
  packet, as ``rehearse_us: 400`` times it.

The thread's wall-clock time per packet, p50 and p99 over ``--packets`` after 200 warm-up
packets. On the shared virtual machine of 2026-11-25 03:51 UTC (800 packets): hot p50 214 us,
after a sleep 810 us, the packet right after it 336 us, rehearsed 360 us (p99 427, 1152, 515,
524 us): the cost after a sleep follows the code (twins, other objects, take most of it
away), not the data.

Usage: ``PYTHONPATH=src python experiments/trackers_rehearsal.py [--packets N]`` (prints one
JSON object).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

import trackers_cpu  # noqa: E402  (the packets and the 20 filters of bench/trackers_cpu.py)
from trackflow.dataflow import calm_gc  # noqa: E402
from trackflow.trackers.rehearsal import Rehearsal  # noqa: E402
from trackflow.trackers.runtime import LiveSources  # noqa: E402

PERIOD_S = 1 / trackers_cpu.RATE


def _pipeline():
    """The live path of bench/trackers_cpu.py: ``one(data, arrival, deliver)`` and the
    rehearsal of its input."""
    inp, sources = trackers_cpu.network()
    names = [b.name for b in inp.bodies]
    delivery = LiveSources(sources)

    def one(data, arrival, deliver):
        block = inp.handle(data, arrival)
        sensors = [names[i] for i in block.index]
        delivery.deliver_block(sensors, block, arrival, answer=(arrival, deliver))

    return one, Rehearsal(inp, sources, answer=True)


def measure(mode: str, packets: int) -> dict:
    one, rehearsal = _pipeline()
    frames = trackers_cpu._packets(2 * packets + 400)
    clock = time.perf_counter_ns
    took: list[int] = []
    got: list[int] = []
    deliver = lambda answers: got.append(clock())  # noqa: E731
    step = 2 if mode == "second_after_sleep" else 1
    with calm_gc():
        for k in range(0, step * (packets + 200), step):
            if mode == "after_sleep":
                time.sleep(PERIOD_S)
            elif mode == "second_after_sleep":
                time.sleep(2 * PERIOD_S)
                one(*frames[k], deliver)
                k += 1
            elif mode == "rehearsed":  # a rehearsal takes up to ~0.5 ms here
                due = time.perf_counter() + PERIOD_S
                time.sleep(PERIOD_S - 0.4e-3 - 0.5e-3)
                if k:
                    rehearsal(*frames[k - 1])
                time.sleep(max(0.0, due - time.perf_counter()))
            got.clear()
            t0 = clock()
            one(*frames[k], deliver)
            took.append(got[0] - t0)
    us = np.asarray(took[200:], dtype=float) * 1e-3
    return {q: round(float(np.percentile(us, v)), 1) for q, v in (("p50", 50), ("p99", 99))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--packets", type=int, default=1000)
    args = ap.parse_args(argv)
    modes = ("hot", "after_sleep", "second_after_sleep", "rehearsed")
    print(json.dumps({m: measure(m, args.packets) for m in modes}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
