"""A 1,000-frame setup run live (issue 31): the synthetic generator's graph, 50 trackers on
five sensor agents, 20 push queries on an application agent, real processes on loopback.

The graph is :func:`trackflow.graph.random_graph` (1,000 frames, a spanning tree and 80 more
edges; its rates 30-240 Hz, latencies 1-50 ms and noises). Fifty of its edges are trackers:
five sensor agents ``t0 .. t4`` play ten each on the wall clock (a slow wobble around the
edge's pose, at the edge's rate); every other edge is a static relationship of the
application agent ``app``, which asks 20 push queries at 30 Hz between frames whose best
path holds at least one tracker. After every query runs and ``--settle`` seconds, the
queries' rates are measured over ``--seconds``; then the sensor agent whose trackers the
most queries use is killed (SIGKILL) and the application's re-plans are read from its
status.

JSON keys (``--json``):

* ``frames``, ``trackers``, ``queries``: the setup;
* ``answer_rate_ratio``: the slowest query's answers per second over its rate (before the kill);
* ``plan_ms``: the longest planning of a query when the application started (or when its
  trackers appeared), from the re-plan events' ``replan_ms``;
* ``replan_ms``: the longest re-plan after the kill, over the queries that used the killed
  agent's trackers (each with its reason: a fallback path, or "no path");
* ``cpu_cores``: the CPU of all agent processes in the window over its length;
* ``detail``: the queries' rates, their paths' lengths, the re-plans after the kill, the
  states published and received per second, the load average.

Usage: ``python bench/big_setup.py [--seconds 40] [--json]`` (needs eclipse-zenoh). The
whole run takes about 90 s and loads this 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import tempfile
import time
from pathlib import Path

import numpy as np

from _procs import rss_and_cpu
from adaptive_agents import _port
from scale import MOTION, Agent, _agent, _log, _rates, _wait
from trackflow.dataflow import plan_query
from trackflow.graph import Query, random_graph
from trackflow.io import PoseStream, write_stream
from trackflow.math import Pose, quat_exp, quat_multiply

N_FRAMES, N_EXTRA, N_TRACKERS, N_AGENTS, N_QUERIES, QUERY_HZ = 1000, 80, 50, 5, 20, 30.0


def _sigmas(cov: np.ndarray) -> tuple[float, float]:
    """Position [mm] and orientation [deg] sigma of a diagonal 6x6 covariance."""
    return float(np.sqrt(cov[0, 0]) * 1e3), float(np.degrees(np.sqrt(cov[3, 3])))


def _recording(path: Path, edge, pose: Pose, seconds: float) -> str:
    """The tracker ``edge`` at its rate: ``pose`` wobbling by 2 cm and 2 degrees."""
    t = np.arange(0.0, seconds, 1.0 / edge.rate_hz)
    base, q0 = pose.position, pose.quaternion
    pos = base + 0.02 * np.stack([np.sin(0.7 * t), np.cos(0.5 * t), np.sin(0.3 * t)], 1)
    wobble = 0.035 * np.stack([np.sin(0.4 * t), 0 * t, np.cos(0.6 * t)], 1)
    rot = quat_multiply(q0, quat_exp(wobble))
    cov = np.broadcast_to(edge.covariance, (len(t), 6, 6)).copy()
    t_ns = np.round(t * 1e9).astype(np.int64)
    write_stream(path, PoseStream(edge.source, edge.target, t_ns, pos, rot, covariance=cov))
    return str(path)


def make_setup(folder: Path, seconds: float, seed: int) -> tuple[dict, list[dict], dict]:
    """The application's document, the sensor agents' documents and the queries' paths."""
    rng = np.random.default_rng(seed)
    g = random_graph(N_FRAMES, N_FRAMES - 1 + N_EXTRA, rng, static_fraction=0.0)
    edges = list(g.edges)
    trackers = {edges[int(k)].name for k in rng.choice(len(edges), N_TRACKERS, replace=False)}
    # every frame somewhere in a room: the statics of a loop agree with each other
    world = {f"F{k}": Pose(rng.uniform(-5, 5, 3), quat_exp(rng.normal(size=3)))
             for k in range(N_FRAMES)}  # fmt: skip
    statics, sensors = [], []
    for e in edges:
        sp, so = _sigmas(e.covariance)
        pose = world[e.source].inverse() @ world[e.target]
        if e.name in trackers:
            rec = _recording(folder / f"{e.name}.tfrec", e, pose, seconds)
            sensors.append({"name": e.name, "source": e.source, "target": e.target,
                            "rate_hz": round(e.rate_hz, 3),
                            "latency_ms": round(e.latency_s * 1e3, 3), "sigma_pos_mm": sp,
                            "sigma_ori_deg": so, "motion": MOTION, "recording": rec})  # fmt: skip
        else:
            statics.append({"name": e.name, "source": e.source, "target": e.target,
                            "position": pose.position.tolist(),
                            "quaternion": pose.quaternion.tolist(), "sigma_pos_mm": sp,
                            "sigma_ori_deg": so})  # fmt: skip
    # the queries: from a random frame to a tracker's frame, where the best path holds one
    from trackflow.dataflow import parse_setup

    full = parse_setup({"sensors": [{k: v for k, v in s.items() if k != "recording"}
                                    for s in sensors], "statics": statics}).graph  # fmt: skip
    queries, paths, order = [], {}, list(rng.permutation(len(sensors)))
    while len(queries) < N_QUERIES and order:
        s = sensors[order.pop()]
        src = f"F{int(rng.integers(N_FRAMES))}"
        q = Query(src, s["target"], mode="push", rate_hz=QUERY_HZ, name=f"q{len(queries)}")
        try:
            plan = plan_query(full, q)
        except ValueError:
            continue
        if plan.sensors and not plan.relationship_static:
            queries.append({"name": q.name, "source": src, "target": s["target"], "mode": "push",
                            "rate_hz": QUERY_HZ})  # fmt: skip
            paths[q.name] = {"edges": len(plan.paths[0].steps), "trackers": sorted(plan.sensors)}
    app = {"frames": [f"F{k}" for k in range(N_FRAMES)], "statics": statics, "queries": queries}
    per = math.ceil(len(sensors) / N_AGENTS)
    return app, [{"sensors": sensors[k * per : (k + 1) * per]} for k in range(N_AGENTS)], paths


def run(settle_s: float, window_s: float, seed: int) -> dict:
    realm, app_port = f"big{_port()}", _port()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        _log("making the 1,000-frame setup and its 50 recordings")
        app_doc, docs, paths = make_setup(folder, 240 + settle_s + window_s, seed)
        files = [_agent(folder, "app", realm, app_port, None, app_doc)]
        files += [_agent(folder, f"t{k}", realm, _port(), app_port, d) for k, d in enumerate(docs)]
        _log(f"starting {len(files)} agents")
        agents = [Agent(f, folder, time.time_ns()) for f in files]
        app = agents[0]
        try:
            _wait(lambda: all(a.ready() for a in agents), 300, "agents not ready")

            def running() -> bool:
                qs = app.status()[1].get("queries", {})
                return len(qs) == len(paths) and all(q["state"] == "running" for q in qs.values())

            _wait(running, 120, "queries not running")
            _log(f"every query running; settling {settle_s:.0f} s")
            time.sleep(settle_s)
            before = [a.status() for a in agents]
            cpu0 = [rss_and_cpu(a.popen.pid)[1] for a in agents]
            t0 = time.monotonic()
            _log(f"measuring {window_s:.0f} s")
            time.sleep(window_s)
            after = [a.status() for a in agents]
            cpu1 = [rss_and_cpu(a.popen.pid)[1] for a in agents]
            dt = time.monotonic() - t0
            # the sensor agent whose trackers the most queries use
            owner = {s["name"]: k for k, d in enumerate(docs) for s in d["sensors"]}
            uses = np.zeros(len(docs), int)
            for p in paths.values():
                for k in {owner[e] for e in p["trackers"]}:
                    uses[k] += 1
            victim = int(np.argmax(uses))
            hit = sorted(q for q, p in paths.items()
                         if any(owner[e] == victim for e in p["trackers"]))  # fmt: skip
            kill_ns = time.time_ns()
            _log(f"killing t{victim} (used by {len(hit)} queries)")
            agents[1 + victim].popen.send_signal(signal.SIGKILL)
            agents[1 + victim].popen.wait(10)

            def replanned() -> dict | None:
                qs = app.status()[1]["queries"]
                ev = {q: [e for e in qs[q]["events"] if e["t_ns"] > kill_ns] for q in hit}
                return ev if all(ev.values()) else None

            _wait(lambda: replanned() is not None, 30, "no re-plan after the kill")
            events = replanned()
            final = app.status()[1]
            load = os.getloadavg()
        finally:
            for a in agents:
                a.stop()
    rates = {q: _rates(before[0], after[0], lambda s, q=q: s["queries"][q]["published"])
             for q in paths}  # fmt: skip
    starts = [e["replan_ms"] for q in final["queries"].values() for e in q["events"]
              if e["t_ns"] < kill_ns]  # fmt: skip
    replans = {q: [{"reason": e["reason"], "state": e["state"], "replan_ms": e["replan_ms"]}
                   for e in ev] for q, ev in events.items()}  # fmt: skip
    return {
        "frames": N_FRAMES,
        "trackers": N_TRACKERS,
        "queries": len(paths),
        "answer_rate_ratio": round(min(rates.values()) / QUERY_HZ, 4),
        "plan_ms": round(max(starts), 3),
        "replan_ms": round(max(e["replan_ms"] for ev in replans.values() for e in ev), 3),
        "cpu_cores": round(sum(c1 - c0 for c0, c1 in zip(cpu0, cpu1)) / dt, 3),
        "detail": {
            "window_s": round(dt, 2),
            "query_rates_hz": {q: round(r, 2) for q, r in rates.items()},
            "paths": paths,
            "killed": f"t{victim}",
            "replans": replans,
            "published_per_s": [
                round(_rates(b, a, lambda s: s["published_states"]), 1)
                for b, a in zip(before[1:], after[1:])
            ],  # fmt: skip
            "app_received_states_per_s": round(
                _rates(before[0], after[0], lambda s: s["received_states"]), 1
            ),
            "app_cpu_share": round((cpu1[0] - cpu0[0]) / dt, 3),
            "load_average": [round(x, 2) for x in load],
        },
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--settle", type=float, default=10.0, help="seconds before the window")
    ap.add_argument("--seconds", type=float, default=40.0, help="the measured window")
    ap.add_argument("--seed", type=int, default=31)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    out = run(a.settle, a.seconds, a.seed)
    if a.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(f"{k}: {v}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
