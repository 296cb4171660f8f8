"""A realm at scale on this machine, measured by CPU per event (issue 31): real agent processes
on loopback, N sensor agents of M sensors each at R Hz and one application agent asking one
push query per sensor agent.

Each sensor agent ``a<i>`` plays M recordings (``room -> b<i>_<m>``, R Hz, a slow circle with
1 mm noise) on the wall clock and publishes its sensors' filter states; the application agent
``app`` asks ``room -> b<i>_0`` of every sensor agent at ``--query-hz``. Every sensor agent
connects to the application agent; Zenoh's gossip connects the rest. After every agent has
logged "ready" and every query runs, the run settles for ``--settle`` seconds, then a window
of ``--seconds`` is measured from the agents' status files (``--status``, written every
second, timed by their modification time) and /proc.

JSON keys (``--json``):

* ``agents``, ``sensors``, ``rate_hz``: the realm (sensor agents, their sensors in all);
* ``answer_rate_ratio``: the slowest query's answers per second over its rate;
* ``cpu_us_per_state``: the CPU time of every agent process in the window over the filter
  states published plus consumed (received by an agent's replica) in it;
* ``rss_mb_per_agent``: the largest RSS of a sensor agent at the window's end;
  ``rss_mb_lone_agent``: the RSS of one such agent running alone, after the same warm-up;
* ``detail``: the application agent's RSS and CPU share, each agent's published and received
  rates, the queries' rates, missed ticks, lost messages, the load average.

Usage: ``python bench/scale.py [--agents 20 --sensors-per-agent 10 --rate-hz 60] [--json]``
(needs eclipse-zenoh: ``pip install -e '.[distributed]'``). A full-size run takes 20 agents'
start-up plus about a minute and loads both cores of this machine.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from _procs import rss_and_cpu, stop
from adaptive_agents import _endpoint, _port, _proc
from trackflow.io import PoseStream, write_stream
from trackflow.math import quat_exp

MOTION = {"n_dp": 1, "n_do": 1, "noise": [0.0, 3.0, 0.0, 10.0]}


def _log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def _recording(path: Path, target: str, rate_hz: float, seconds: float, seed: int) -> str:
    """``room -> target`` at ``rate_hz``: a slow circle, 1 mm and 0.1 degree of noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / rate_hz)
    phase = rng.uniform(0, 2 * np.pi)
    pos = np.stack([0.5 * np.sin(0.3 * t + phase), 0.5 * np.cos(0.3 * t + phase), 1 + 0 * t], 1)
    pos += rng.normal(0, 1e-3, pos.shape)
    rot = np.stack([0 * t, 0 * t, 0.3 * t + phase], 1) + rng.normal(0, 1.7e-3, (len(t), 3))
    cov = np.broadcast_to(np.diag([1e-6] * 3 + [3e-6] * 3), (len(t), 6, 6)).copy()
    stream = PoseStream("room", target, np.round(t * 1e9).astype(np.int64), pos, quat_exp(rot),
                        covariance=cov)  # fmt: skip
    write_stream(path, stream)
    return str(path)


def _agent(folder: Path, name: str, realm: str, port: int, hub: int | None, doc: dict) -> Path:
    zenoh = {"listen": {"endpoints": [_endpoint(port)]}}
    if hub is not None:
        zenoh["connect"] = {"endpoints": [_endpoint(hub)]}
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump({"agent": {"name": name, "realm": realm, "zenoh": zenoh},
                                    **doc}, sort_keys=False))  # fmt: skip
    return path


def _sensor_doc(folder: Path, i: int, m_sensors: int, rate_hz: float, seconds: float) -> dict:
    sensors = [
        {"name": f"s{i}_{m}", "source": "room", "target": f"b{i}_{m}", "rate_hz": rate_hz,
         "latency_ms": 5, "sigma_pos_mm": 1.0, "sigma_ori_deg": 0.1, "motion": MOTION,
         "recording": _recording(folder / f"s{i}_{m}.tfrec", f"b{i}_{m}", rate_hz, seconds,
                                 1000 * i + m)}
        for m in range(m_sensors)
    ]  # fmt: skip
    return {"sensors": sensors}


class Agent:
    """One agent process with its status file."""

    def __init__(self, path: Path, folder: Path, start_ns: int):
        self.name = path.stem
        self.log = folder / f"{self.name}.log"
        self.status_path = folder / f"{self.name}.status.json"
        self.popen = _proc("agent", path, "--start-ns", start_ns, "--status", self.status_path,
                           log=self.log)  # fmt: skip

    def ready(self) -> bool:
        if self.popen.poll() is not None:
            raise RuntimeError(f"agent {self.name} ended:\n{self.log.read_text()[-3000:]}")
        return '"ready"' in self.log.read_text()

    def status(self) -> tuple[float, dict]:
        """(the status file's time [s], its content), read whole (it is replaced whole)."""
        for _ in range(50):
            try:
                t = self.status_path.stat().st_mtime
                return t, json.loads(self.status_path.read_text())
            except (OSError, ValueError):
                time.sleep(0.05)  # (being replaced)
        raise RuntimeError(f"agent {self.name}: no status file")

    def stop(self) -> None:
        stop(self.popen, 20)


def _wait(cond, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            raise TimeoutError(what)
        time.sleep(0.2)


def _rates(before: tuple[float, dict], after: tuple[float, dict], pick) -> float:
    """Per second between two status snapshots of ``pick(status)``."""
    dt = after[0] - before[0]
    return (pick(after[1]) - pick(before[1])) / dt if dt > 0 else float("nan")


def lone_agent_rss(m_sensors: int, rate_hz: float, settle_s: float) -> float:
    """RSS [MB] of one sensor agent alone after start-up and ``settle_s``."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        doc = _sensor_doc(folder, 0, m_sensors, rate_hz, 120 + settle_s)
        a = Agent(_agent(folder, "a0", f"lone{_port()}", _port(), None, doc), folder,
                  time.time_ns())  # fmt: skip
        try:
            _wait(a.ready, 120, "the lone agent is not ready")
            time.sleep(settle_s)
            return rss_and_cpu(a.popen.pid)[0]
        finally:
            a.stop()


def run(n_agents: int, m_sensors: int, rate_hz: float, query_hz: float, settle_s: float,
        window_s: float) -> dict:  # fmt: skip
    _log(f"a lone agent of {m_sensors} sensors")
    lone = lone_agent_rss(m_sensors, rate_hz, settle_s)
    realm, app_port = f"scale{_port()}", _port()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        seconds = 240 + settle_s + window_s  # start-up of every agent, then the run
        _log(f"writing {n_agents * m_sensors} recordings")
        files = [_agent(folder, f"a{i}", realm, _port(), app_port,
                        _sensor_doc(folder, i, m_sensors, rate_hz, seconds))
                 for i in range(n_agents)]  # fmt: skip
        queries = [{"name": f"q{i}", "source": "room", "target": f"b{i}_0", "mode": "push",
                    "rate_hz": query_hz} for i in range(n_agents)]  # fmt: skip
        frames = ["room"] + [f"b{i}_0" for i in range(n_agents)]
        files.append(_agent(folder, "app", realm, app_port, None,
                            {"frames": frames, "queries": queries}))  # fmt: skip
        start_ns = time.time_ns()
        _log(f"starting {len(files)} agents")
        agents = [Agent(f, folder, start_ns) for f in [files[-1], *files[:-1]]]
        try:
            _wait(lambda: all(a.ready() for a in agents), 300, "agents not ready")
            app = agents[0]

            def running() -> bool:
                qs = app.status()[1].get("queries", {})
                return len(qs) == n_agents and all(q["state"] == "running" for q in qs.values())

            _wait(running, 120, "queries not running")
            _log(f"every agent ready, every query running; settling {settle_s:.0f} s")
            time.sleep(settle_s)
            before = [a.status() for a in agents]
            cpu0 = [rss_and_cpu(a.popen.pid)[1] for a in agents]
            t0 = time.monotonic()
            _log(f"measuring {window_s:.0f} s")
            time.sleep(window_s)
            after = [a.status() for a in agents]
            usage = [rss_and_cpu(a.popen.pid) for a in agents]
            dt = time.monotonic() - t0
            load = os.getloadavg()
        finally:
            for a in agents:
                a.stop()
    published = [_rates(b, a, lambda s: s["published_states"]) for b, a in zip(before, after)]
    received = [_rates(b, a, lambda s: s["received_states"]) for b, a in zip(before, after)]
    messages = [_rates(b, a, lambda s: s["published_messages"]) for b, a in zip(before, after)]
    query_rates = {
        q: _rates(before[0], after[0], lambda s, q=q: s["queries"][q]["published"])
        for q in sorted(after[0][1]["queries"])
    }
    cpu_s = sum(u[1] - c for u, c in zip(usage, cpu0))
    states = (sum(published) + sum(received)) * dt
    return {
        "agents": n_agents,
        "sensors": n_agents * m_sensors,
        "rate_hz": rate_hz,
        "answer_rate_ratio": round(min(query_rates.values()) / query_hz, 4),
        "cpu_us_per_state": round(cpu_s / states * 1e6, 1),
        "rss_mb_per_agent": round(max(u[0] for u in usage[1:]), 1),
        "rss_mb_lone_agent": round(lone, 1),
        "detail": {
            "query_hz": query_hz,
            "window_s": round(dt, 2),
            "cpu_cores_used": round(cpu_s / dt, 3),
            "app_rss_mb": round(usage[0][0], 1),
            "app_cpu_share": round((usage[0][1] - cpu0[0]) / dt, 3),
            "published_per_s": [round(x, 1) for x in published],
            "published_messages_per_s": [round(x, 1) for x in messages],
            "received_per_s": [round(x, 1) for x in received],
            "query_rates_hz": {q: round(r, 2) for q, r in query_rates.items()},
            "missed_ticks": after[0][1]["missed_ticks"],
            "lost_messages": sum(s[1]["lost_messages"] for s in after),
            "load_average": [round(x, 2) for x in load],
        },
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--agents", type=int, default=20)
    ap.add_argument("--sensors-per-agent", type=int, default=10)
    ap.add_argument("--rate-hz", type=float, default=60.0)
    ap.add_argument("--query-hz", type=float, default=30.0)
    ap.add_argument("--settle", type=float, default=15.0, help="seconds before the window")
    ap.add_argument("--seconds", type=float, default=30.0, help="the measured window")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    out = run(a.agents, a.sensors_per_agent, a.rate_hz, a.query_hz, a.settle, a.seconds)
    if a.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(f"{k}: {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
