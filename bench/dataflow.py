"""Dataflow throughput and latency on the demo network (one core).

Plays the demo's simulated tracker (60 Hz) and camera (30 Hz) through the projector -> marker
network with a Kalman filter behind each sensor, predicting to the present at 60 Hz, on the
virtual clock as fast as possible (default kernel backend, after one warm-up run).

* ``events_per_s``: dispatched events (sensor samples + sampler ticks) per wall-clock second.
* ``latency_us``: wall time from the scheduler dispatching an event to the result reaching the
  application callback (the processing cost of one delivered output), median and 99th
  percentile.

Usage: ``.venv/bin/python bench/dataflow.py [--json] [--repeat N]``
"""

from __future__ import annotations

import argparse
import json
import logging
import time

import numpy as np

from trackflow import demo
from trackflow.dataflow import plan_query
from trackflow.graph import Query
from trackflow.math import UncertainPose


def build():
    cfg = demo.DemoConfig()
    t, poses = demo.load_demo_motion()
    truth = demo.demo_truth(t, poses, cfg.truth_lowpass_hz)
    fixed = demo.demo_frames(truth, t[0], t[-1])
    calib = UncertainPose(fixed["T_T_C"], np.diag([1e-6] * 6))
    g = demo.demo_graph(cfg, fixed, calib)
    q = Query("P", "M", mode="push", rate_hz=60, time_offset_s=0.0, exclude=("marker",))
    plan = plan_query(g, q)
    return plan, (lambda: demo.demo_sensors(cfg, truth, fixed, t[0], t[-1]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    logging.getLogger("trackflow.filters").setLevel(logging.ERROR)
    plan, make_sensors = build()
    net, sink = plan.build(make_sensors())
    net.run()  # warm-up: compiles the filter kernels once
    rates, lat = [], []
    for _ in range(args.repeat):
        net, sink = plan.build(make_sensors())
        t0 = time.perf_counter()
        net.run()
        dt = time.perf_counter() - t0
        n = sum(s.stats.events_in for s in net.components.values() if s.kind in ("sensor",))
        n += net["sampler"].stats.events_in
        rates.append(n / dt)
        lat.extend(sink.wall_latencies_ns)
    lat_us = np.asarray(lat) * 1e-3
    result = {
        "events_per_s": float(np.median(rates)),
        "latency_us": {
            "p50": float(np.percentile(lat_us, 50)),
            "p99": float(np.percentile(lat_us, 99)),
        },
    }
    if args.json:
        print(json.dumps(result))
    else:
        print(f"events per second: {result['events_per_s']:.0f}")
        print(
            f"dispatch-to-delivery latency: p50 {result['latency_us']['p50']:.1f} us, "
            f"p99 {result['latency_us']['p99']:.1f} us"
        )


if __name__ == "__main__":
    main()
