"""CPU time of one live packet, piece by piece, without sockets or threads.

The work `bench/trackers.py` times end to end, in one thread: a NatNet 4.1 packet of 20
bodies at 240 Hz goes through ``LiveInput.handle`` (decode, clock mapping, 20 checked
samples as arrays, a ``SampleBlock``). They go through ``LiveSources.deliver_block`` (each
source's checks, then the 20 pose Kalman filters' updates in one batched call, as
``trackflow run`` delivers a packet) with an answer: the 20 filtered poses at the packet's
arrival, as arrays (predicted in the same compiled call), delivered before the bookkeeping
(the filters' times and log records, the counts), which follows. Per packet: ``handle_us``
(decoding to samples), ``answer_us`` (samples to answers delivered), ``settle_us`` (the
bookkeeping after), ``packet_us`` (handle + answer: the packet's latency in CPU) and
``total_us`` (all of it). Thread CPU times are less sensitive to other jobs than wall-clock
latencies. The script prints the p10, p50 and p99 per packet over ``--packets`` packets,
after 200 warm-up packets.

Usage: ``python bench/trackers_cpu.py [--json] [--packets N]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from trackflow.dataflow import KalmanFilter, calm_gc, collect_due, parse_input, warm_up
from trackflow.graph import MotionSpec
from trackflow.math import quat_exp
from trackflow.trackers import natnet
from trackflow.trackers.inputs import make_inputs
from trackflow.trackers.runtime import LiveSource, LiveSources

BODIES, RATE, FREQ = 20, 240, 10_000_000


def _packets(n: int, bodies: int = BODIES) -> list[tuple[bytes, int]]:
    """NatNet 4.1 frames of ``bodies`` moving bodies, with host arrival times 3 ms after
    transmit."""
    out = []
    t0 = 1_700_000_000_000_000_000
    for i in range(n):
        t = t0 + i * 1_000_000_000 // RATE
        p = np.array([1.0, 2.0, 0.5]) + 0.01 * np.sin(i * 0.01)
        q = tuple(quat_exp(np.array([0.1, 0.2 + 0.001 * i, 0.3])))
        rbs = tuple(
            natnet.NatNetRigidBody(k, (p[0] + 0.1 * k, p[1], p[2]), q, 2e-4, True)
            for k in range(1, bodies + 1)
        )
        tick = t * FREQ // 1_000_000_000
        frame = natnet.NatNetFrame(i + 1, rbs, t * 1e-9, tick, tick, tick + 20_000)
        out.append((natnet.encode_frame(frame, (4, 1)), t + 3_000_000))
    return out


def network(bodies: int = BODIES):
    """The NatNet 4.1 input of ``bodies`` bodies (its handshake done) and the sources of as
    many pose Kalman filters, one each, compiled: ``(input, {name: LiveSource})``."""
    specs = {
        f"b{k}": (parse_input({"natnet": {"command_port": 1, "body": k}}), np.eye(6) * 1e-6)
        for k in range(1, bodies + 1)
    }
    (inp,) = make_inputs(specs)
    info = natnet.ServerInfo(natnet_version=(4, 1, 0, 0), clock_frequency=FREQ)
    inp.handle(natnet.encode_server_info(info), 0)
    motion = MotionSpec(static=False, n_dp=1, n_do=1, noise=(0.0, 30.0, 0.0, 100.0))
    sources = {name: LiveSource(name) for name in specs}
    filters = {name: KalmanFilter(f"kf_{name}", motion) for name in specs}
    for name in specs:
        sources[name].consumers.append((filters[name], 0))

    class _Net:
        components = filters

    warm_up(_Net)
    return inp, sources


def measure(packets: int, between=None, bodies: int = BODIES) -> dict:
    """Per-packet thread CPU times [us] of packets of ``bodies`` bodies; ``between()``, if
    given, runs before each packet (``experiments/trackers_idle_core.py`` sleeps or spins
    there for the packet period)."""
    inp, sources = network(bodies)
    names = [b.name for b in inp.bodies]
    delivery = LiveSources(sources)
    rows = []
    clock = time.thread_time_ns
    got: list = []

    def answered(answers):  # the packet's 20 answers, delivered
        got.extend((clock(), answers))

    with calm_gc():
        for k, (data, arrival) in enumerate(_packets(packets + 200, bodies)):
            if between is not None:
                between()
            t0 = clock()
            block = inp.handle(data, arrival)
            t1 = clock()
            sensors = [names[bi] for bi in block.index]
            got.clear()
            delivery.deliver_block(sensors, block, arrival, answer=(arrival, answered))
            t3 = clock()  # and the filters' bookkeeping done
            t2, answers = got
            assert answers.ok[-1]
            if k >= 200:
                rows.append((t1 - t0, t2 - t1, t3 - t2, t2 - t0, t3 - t0))
            collect_due()  # as trackflow run does once a packet is answered
    r = np.asarray(rows, dtype=float) * 1e-3
    keys = ("handle_us", "answer_us", "settle_us", "packet_us", "total_us")
    return {
        "p10": {k: round(float(v), 1) for k, v in zip(keys, np.percentile(r, 10, axis=0))},
        "p50": {k: round(float(v), 1) for k, v in zip(keys, np.percentile(r, 50, axis=0))},
        "p99": {k: round(float(v), 1) for k, v in zip(keys, np.percentile(r, 99, axis=0))},
        "bodies": bodies,
        "packets": packets,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--packets", type=int, default=2000)
    args = ap.parse_args(argv)
    out = measure(args.packets)
    if args.json:
        print(json.dumps(out))
    else:
        for q in ("p10", "p50", "p99"):
            print(q, ", ".join(f"{k} {v:.0f}" for k, v in out[q].items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
