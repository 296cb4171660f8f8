"""Long runs: the live demo and a three-agent realm for minutes or hours, optionally with chaos.

Two systems run side by side on loopback for ``--minutes``:

* **the live demo**: ``trackflow simulate natnet`` (ar_table table_01) and ``simulate dtrack``
  (EuRoC V1_01) replayed back and forth (``--plays``) into ``trackflow run
  examples/live_demo.yaml``, whose answers this process reads as a VRPN client (every answer,
  with its time);
* **a three-agent realm**: agents ``nn`` (a NatNet sensor with its ``input:``), ``dt`` (a
  DTrack sensor) and ``app`` (a 100 Hz push query with failover between them), fed by two
  more simulated trackers replaying TUM-VI room1; this process subscribes to the app's
  results.

Every minute it records each process's resident memory (RSS) and CPU, the answers of each
stream and their latency percentiles (receipt minus the answer's time). With ``--chaos``, at
random times (every 30-90 s) it kills (SIGKILL, restarted 3-8 s later) or freezes (SIGSTOP
for 1-4 s) one of the four simulated trackers or the agents ``nn`` and ``dt``, and logs each
event. A gap in an answer stream (more than five periods without an answer) is explained
when an event's window (its start to its end plus 10 s of recovery) overlaps it.

JSON keys (``--json``): ``rss_growth_mb`` (the largest growth of any process's RSS after the
first minutes, a quarter of the run at most five), ``answers_lost`` (answers missing in the
unexplained gaps), ``unexplained_gaps``, ``p99_drift_ratio`` (the latency p99 of the last
minute over that of the first minute after the warm-up, the larger of the two streams), and
``minutes`` (the per-minute records), ``events``, ``gaps``.

Usage: ``python bench/soak.py --minutes 30 [--chaos] [--json] [--seed 1]``.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from adaptive_agents import SENSOR, _agent_file, _endpoint, _port, _proc
from trackflow.distributed.wire import decode
from trackflow.trackers import vrpn

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
TABLE = DATA / "ar_table" / "table_01.txt"
EUROC = DATA / "euroc" / "V1_01_easy_groundtruth_200hz.txt"
ROOM1 = DATA / "tumvi" / "dataset-room1_512_16.txt"
GAP_PERIODS, RECOVERY_S = 5, 10.0


@dataclass
class Managed:
    """A process this soak starts, and may kill, freeze and restart."""

    name: str
    args: tuple
    log: Path
    popen: subprocess.Popen | None = None
    restarts: int = 0

    def start(self) -> None:
        self.popen = _proc(*self.args, log=self.log)

    def sample(self) -> tuple[float, float] | None:
        """RSS [MB] and CPU time [s] so far, from /proc (None if gone)."""
        try:
            status = Path(f"/proc/{self.popen.pid}/status").read_text()
            stat = Path(f"/proc/{self.popen.pid}/stat").read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            return None
        rss = next(int(ln.split()[1]) for ln in status.splitlines() if ln.startswith("VmRSS"))
        ticks = os.sysconf("SC_CLK_TCK")
        return rss / 1024, (int(stat[11]) + int(stat[12])) / ticks

    def stop(self) -> None:
        if self.popen is not None and self.popen.poll() is None:
            self.popen.send_signal(signal.SIGCONT)
            self.popen.terminate()
            try:
                self.popen.wait(10)
            except subprocess.TimeoutExpired:
                self.popen.kill()
                self.popen.wait(10)


@dataclass
class Stream:
    """Answers of one query as they arrive: (receipt, answer time) [ns]."""

    name: str
    period_s: float
    arrivals: list = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def add(self, t_ns: int) -> None:
        with self.lock:
            self.arrivals.append((time.time_ns(), t_ns))

    def since(self, k: int) -> list:
        with self.lock:
            return self.arrivals[k:]


def _read_vrpn(port: int, stream: Stream, stop: threading.Event) -> None:
    """Every VRPN report of ``Tracker0`` into ``stream`` (reconnecting while the server is
    not there)."""
    while not stop.is_set():
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=2) as c:
                c.sendall(vrpn.make_cookie())
                dec = vrpn.StreamDecoder()
                c.settimeout(1.0)
                while not stop.is_set():
                    try:
                        data = c.recv(65536)
                    except TimeoutError:
                        continue
                    if not data:
                        break
                    for r in dec.feed(data):
                        stream.add(r.sec * 1_000_000_000 + r.usec * 1000)
        except OSError:
            stop.wait(0.5)


def _gaps(stream: Stream, events: list[dict], start_ns: int, end_ns: int) -> list[dict]:
    """Gaps of more than GAP_PERIODS periods in ``stream`` between ``start_ns`` and
    ``end_ns``, each with the event that explains it (or None)."""
    recv = np.array([a for a, _ in stream.since(0) if start_ns <= a <= end_ns], np.int64)
    if len(recv) < 2:
        return [{"stream": stream.name, "from_s": 0.0, "s": (end_ns - start_ns) * 1e-9,
                 "event": None}]  # fmt: skip
    recv.sort()
    limit = GAP_PERIODS * stream.period_s * 1e9
    out = []
    for k in np.flatnonzero(np.diff(recv) > limit):
        a, b = int(recv[k]), int(recv[k + 1])
        why = next(
            (e["what"] for e in events
             if e["start_ns"] - 1e9 <= b and a <= e["end_ns"] + RECOVERY_S * 1e9),
            None,
        )  # fmt: skip
        out.append({"stream": stream.name, "from_s": round((a - start_ns) * 1e-9, 2),
                    "s": round((b - a) * 1e-9, 3), "event": why})  # fmt: skip
    return out


def _chaos(rng: random.Random, victims: list[Managed], events: list, stop: threading.Event):
    """Kill or freeze a random victim every 30-90 s (module docstring)."""
    while not stop.wait(rng.uniform(30, 90)):
        v = rng.choice(victims)
        start = time.time_ns()
        if rng.random() < 0.5:
            v.popen.kill()
            v.popen.wait(10)
            stop.wait(rng.uniform(3, 8))
            v.restarts += 1
            v.start()
            what = f"kill -9 and restart {v.name}"
        else:
            v.popen.send_signal(signal.SIGSTOP)
            stop.wait(rng.uniform(1, 4))
            v.popen.send_signal(signal.SIGCONT)
            what = f"freeze {v.name}"
        events.append({"what": what, "start_ns": start, "end_ns": time.time_ns()})
        print(f"chaos: {what}", file=sys.stderr, flush=True)


def _setups(folder: Path, total_s: float) -> tuple[list[Managed], dict, int, str, list[int]]:
    """The processes (not started), the answer streams' ports and the realm's name."""
    plays = int(total_s // 60) + 2  # every recording is longer than 60 s
    nn_demo, dt_demo, vr = _port(), _port(), _port(socket.SOCK_STREAM)
    demo = (ROOT / "examples" / "live_demo.yaml").read_text()
    (folder / "demo.yaml").write_text(
        demo.replace("command_port: 41510", f"command_port: {nn_demo}").replace(
            "port: 45000", f"port: {dt_demo}"
        )
    )
    realm = f"soak{_port()}"
    ports = {n: _port(socket.SOCK_STREAM) for n in ("nn", "dt", "app")}
    nn, dt = _port(), _port()
    stale = {"stale_ms": 200}
    files = {
        "nn": _agent_file(folder, "nn", realm, ports, {"sensors": [{
            "name": "natnet", **SENSOR, "input": {"natnet": {"command_port": nn, "body": "rig"},
                                                  **stale}}]}),
        "dt": _agent_file(folder, "dt", realm, ports, {"sensors": [{
            "name": "dtrack", **SENSOR, "latency_ms": 20,
            "input": {"dtrack": {"port": dt, "body": 1}, **stale}}]}),
        "app": _agent_file(folder, "app", realm, ports, {"queries": [{
            "name": "q", "source": "W", "target": "B", "mode": "push", "rate_hz": 100,
            "failover": {"hold_ms": 1000}}]}),
    }  # fmt: skip
    sim = ("--wait", total_s, "--plays", plays)
    procs = [
        Managed("demo natnet tracker", ("simulate", "natnet", TABLE, "--port", nn_demo,
                                        "--body", "head", *sim), folder / "s1.log"),
        Managed("demo dtrack tracker", ("simulate", "dtrack", EUROC, "--port", dt_demo, *sim),
                folder / "s2.log"),
        Managed("trackflow run", ("run", folder / "demo.yaml", "--vrpn-port", vr, "--duration",
                                  total_s + 30), folder / "run.log"),
        Managed("realm natnet tracker", ("simulate", "natnet", ROOM1, "--port", nn, "--body",
                                         "rig", *sim), folder / "s3.log"),
        Managed("realm dtrack tracker", ("simulate", "dtrack", ROOM1, "--port", dt, *sim),
                folder / "s4.log"),
    ]  # fmt: skip
    procs += [Managed(f"agent {n}", ("agent", f, "--duration", total_s + 30), folder / f"{n}.log")
              for n, f in files.items()]  # fmt: skip
    return procs, ports, vr, realm, [nn, dt]


def soak(minutes: float, chaos: bool, seed: int, folder: Path) -> dict:
    import zenoh

    total_s = minutes * 60
    procs, ports, vr, realm, _ = _setups(folder, total_s)
    by_name = {p.name: p for p in procs}
    demo = Stream("live demo (VRPN)", 1 / 60)
    app = Stream("realm app", 1 / 100)
    stop = threading.Event()
    events: list[dict] = []
    session = None
    for p in procs:
        p.start()
    try:
        for n in ("nn", "dt", "app"):
            end = time.monotonic() + 180
            while '"ready"' not in (folder / f"{n}.log").read_text():
                if time.monotonic() > end:
                    raise TimeoutError(f"agent {n} not ready: {(folder / f'{n}.log').read_text()}")
                time.sleep(0.2)
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("connect/endpoints", json.dumps([_endpoint(p) for p in ports.values()]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        session = zenoh.open(conf)
        key = f"trackflow/{realm}/result/app/q"
        session.declare_subscriber(key, lambda s: app.add(decode(s.payload.to_bytes()).exposure_ns))
        threading.Thread(target=_read_vrpn, args=(vr, demo, stop), daemon=True).start()
        time.sleep(5.0)  # everything connected
        start = time.time_ns()
        if chaos:
            victims = [by_name[n] for n in ("demo natnet tracker", "demo dtrack tracker",
                                            "realm natnet tracker", "realm dtrack tracker",
                                            "agent nn", "agent dt")]  # fmt: skip
            threading.Thread(target=_chaos, args=(random.Random(seed), victims, events, stop),
                             daemon=True).start()  # fmt: skip
        minutes_out = []
        last = {p.name: p.sample() for p in procs}
        marks = {s.name: len(s.arrivals) for s in (demo, app)}
        for m in range(int(np.ceil(minutes))):
            span = min(60.0, total_s - 60 * m)
            stop.wait(span)
            now = {p.name: p.sample() for p in procs}
            row = {"minute": m + 1, "rss_mb": {}, "cpu_share": {}, "answers": {},
                   "latency_ms": {}}  # fmt: skip
            for name, s in now.items():
                if s is not None:
                    row["rss_mb"][name] = round(s[0], 1)
                    if last.get(name) is not None and s[1] >= last[name][1]:
                        row["cpu_share"][name] = round((s[1] - last[name][1]) / span, 4)
            for st in (demo, app):
                new = st.since(marks[st.name])
                marks[st.name] += len(new)
                row["answers"][st.name] = len(new)
                lat = np.array([(a - t) * 1e-6 for a, t in new])
                if len(lat):
                    row["latency_ms"][st.name] = {
                        "p50": round(float(np.percentile(lat, 50)), 3),
                        "p99": round(float(np.percentile(lat, 99)), 3),
                    }
            minutes_out.append(row)
            last = now
            print(f"minute {m + 1}: {json.dumps(row)}", file=sys.stderr, flush=True)
        end = time.time_ns()
    finally:
        stop.set()
        if session is not None:
            session.close()
        for p in procs:
            p.stop()
    return _summary(minutes_out, events, [demo, app], start, end, procs)


def _summary(rows, events, streams, start, end, procs) -> dict:
    warm = min(5, max(1, len(rows) // 4))
    growth = 0.0
    for p in procs:
        if p.restarts:  # a restarted process starts again: judged from its last start
            continue
        rss = [r["rss_mb"].get(p.name) for r in rows[warm - 1 :]]
        rss = [x for x in rss if x is not None]
        if rss:
            growth = max(growth, max(rss) - rss[0])
    gaps = [g for st in streams for g in _gaps(st, events, start, end)]
    lost = sum(
        max(int(round(g["s"] / st.period_s)) - 1, 0)
        for st in streams for g in gaps if g["stream"] == st.name and g["event"] is None
    )  # fmt: skip
    drift = 0.0
    for st in streams:
        p99 = [r["latency_ms"].get(st.name, {}).get("p99") for r in rows[warm:]]
        p99 = [x for x in p99 if x is not None]
        if len(p99) >= 2 and p99[0] > 0:
            drift = max(drift, p99[-1] / p99[0])
    return {
        "rss_growth_mb": round(growth, 1),
        "answers_lost": lost,
        "unexplained_gaps": sum(g["event"] is None for g in gaps),
        "p99_drift_ratio": round(drift, 3),
        "warm_up_minutes": warm,
        "events": [
            {
                **{k: v for k, v in e.items() if k == "what"},
                "at_s": round((e["start_ns"] - start) * 1e-9, 1),
            }
            for e in events
        ],  # fmt: skip
        "gaps": gaps,
        "minutes": rows,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--chaos", action="store_true")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    missing = [p for p in (TABLE, EUROC, ROOM1) if not p.exists()]
    if missing:
        print(f"skipped: needs {missing}", file=sys.stderr)
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        out = soak(args.minutes, args.chaos, args.seed, Path(tmp))
    if args.json:
        print(json.dumps(out))
    else:
        rows = out.pop("minutes")
        print(json.dumps(out, indent=1))
        for r in rows:
            print(json.dumps(r))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
