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
event (``start_s``, ``end_s``: kill or SIGSTOP to restart or SIGCONT, ``ready_s``: the victim
back, ``back``, ``streams``: the answer stream the victim can reach). A victim is back at
SIGCONT after a freeze; after a kill, when the restarted agent has logged "ready" or the
restarted simulated tracker has opened its socket, waited for at most 60 s (``back`` false:
never back, and its window ends where the wait ended). The chaos thread is stopped and joined
before the processes are stopped and never restarts one after that.

Gaps are measured on the answers' own times (their stamps), not on their receipt: answers
delivered late in a burst are latency, not loss (receipt gaps are reported apart as
``delivery_stalls``). A gap is more than five periods between consecutive answer times of a
stream, the run's start and end counting as answer times (a stream that stops early or never
starts has a gap). An event explains only gaps of the stream its victim can reach, and only
the part of a gap inside its window, from its start minus 1 s to the victim back plus 10 s of
recovery. Any part of a gap outside every such window is unexplained, machine load or not.

JSON keys (``--json``): ``rss_growth_mb`` (the largest growth of any process's RSS after the
first minutes, a quarter of the run at most five), ``answers_lost`` (the answers missing in
all unexplained parts of gaps: the expected answer times there), ``unexplained_gaps`` (the
gaps with an unexplained part), ``p99_drift_ratio`` (the latency p99 of the last minute over
that of the first minute after the warm-up, the larger of the two streams); a breakdown
that is never subtracted from those: ``answers_lost_load`` and ``load_gaps`` (the part of
``answers_lost`` lying in, and the unexplained gaps whose unexplained part overlaps, a stall
of this machine: a 10 ms sleep of this process overslept by more than 50 ms),
``machine_stalls``, ``max_loadavg`` (and ``loadavg`` per minute); ``delivery_stalls`` (per
stream, ``n`` receipt gaps of more than five periods and the ``longest_s``); and ``minutes``
(the per-minute records), ``events``, ``gaps`` (each with its ``events``, ``unexplained_s``,
``lost``, ``lost_load``). ``--keep DIR`` keeps the processes' logs (and files) in ``DIR``.

Usage: ``python bench/soak.py --minutes 30 [--chaos] [--json] [--seed 1] [--keep DIR]``.
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

from _procs import rss_and_cpu, stop
from adaptive_agents import SENSOR, _agent_file, _endpoint, _port, _proc
from trackflow.distributed.wire import decode
from trackflow.trackers import vrpn

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
TABLE = DATA / "ar_table" / "table_01.txt"
EUROC = DATA / "euroc" / "V1_01_easy_groundtruth_200hz.txt"
ROOM1 = DATA / "tumvi" / "dataset-room1_512_16.txt"
GAP_PERIODS, RECOVERY_S = 5, 10.0
READY_WAIT_S = 60.0  # the longest wait for a restarted victim to be back
STALL_S = 0.05  # an oversleep of the probe's 10 ms sleep beyond this is a machine stall
#: the answer stream each victim can reach (an event explains gaps of that stream only)
REACHES = {"demo natnet tracker": "live demo (VRPN)", "demo dtrack tracker": "live demo (VRPN)",
           "realm natnet tracker": "realm app", "realm dtrack tracker": "realm app",
           "agent nn": "realm app", "agent dt": "realm app"}  # fmt: skip


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
        return rss_and_cpu(self.popen.pid)

    def ready(self) -> bool:
        """Back after a (re)start: an agent has logged ``"ready"``, a simulated tracker has
        opened its socket (after loading and expanding its recording)."""
        if self.name.startswith("agent "):
            try:
                return '"ready"' in self.log.read_text()
            except OSError:
                return False
        try:
            fds = list(Path(f"/proc/{self.popen.pid}/fd").iterdir())
            return any(os.readlink(f).startswith("socket:") for f in fds)
        except OSError:
            return False

    def stop(self) -> None:
        if self.popen is not None:
            stop(self.popen)


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


def _uncovered(a: int, b: int, windows: list[tuple[float, float]]) -> list[tuple[int, int]]:
    """The parts of ``[a, b]`` outside every window."""
    out, t = [], a
    for lo, hi in sorted(windows):
        if hi <= t or lo >= b:
            continue
        if lo > t:
            out.append((t, int(lo)))
        t = max(t, int(hi))
    if t < b:
        out.append((t, b))
    return out


def _inside(x: np.ndarray, spans: list[tuple[int, int]]) -> np.ndarray:
    """Which of the times ``x`` lie in one of the ``spans`` (closed)."""
    hit = np.zeros(len(x), bool)
    for lo, hi in spans:
        hit |= (x >= lo) & (x <= hi)
    return hit


def _gaps(stream: Stream, events: list[dict], stalls: list, start_ns: int, end_ns: int) -> list:
    """Gaps of more than GAP_PERIODS periods between the answer times of ``stream`` (the
    run's start and end counting as answer times), each with the events that explain part of
    it, its unexplained seconds, the answers missing there (the expected answer times, evenly
    spaced in the gap, that lie in its unexplained parts) and how many of those lie in a
    machine stall (``load``: whether an unexplained part overlaps one)."""
    arr = stream.since(0)
    t = np.unique(np.array([x for _, x in arr if start_ns <= x <= end_ns] or [], np.int64))
    t = np.concatenate([[start_ns], t, [end_ns]])
    period = stream.period_s * 1e9
    windows = [(e["start_ns"] - 1e9, e["ready_ns"] + (RECOVERY_S * 1e9 if e["back"] else 0),
                e["what"]) for e in events if stream.name in e["streams"]]  # fmt: skip
    out = []
    for k in np.flatnonzero(np.diff(t) > GAP_PERIODS * period):
        a, b = int(t[k]), int(t[k + 1])
        why = sorted({w for lo, hi, w in windows if lo <= b and a <= hi})
        rest = _uncovered(a, b, [(lo, hi) for lo, hi, _ in windows])
        n = max(int(round((b - a) / period)), 1)
        due = a + (b - a) * np.arange(1, n) / n  # the answer times missing in the gap
        open_ = _inside(due, rest)
        load = any(p <= y and x <= q for x, y in rest for p, q in stalls)
        out.append({"stream": stream.name, "from_s": round((a - start_ns) * 1e-9, 2),
                    "s": round((b - a) * 1e-9, 3), "events": why,
                    "unexplained_s": round(sum(y - x for x, y in rest) * 1e-9, 3),
                    "open_ns": sum(y - x for x, y in rest),
                    "lost": int(open_.sum()),
                    "lost_load": int((open_ & _inside(due, stalls)).sum()),
                    "load": load})  # fmt: skip
    return out


def _delivery_stalls(stream: Stream, start_ns: int, end_ns: int) -> dict:
    """Receipt gaps (this process or the transport stalled; the answers came late)."""
    r = np.sort(np.array([a for a, _ in stream.since(0) if start_ns <= a <= end_ns] or [0]))
    d = np.diff(r) * 1e-9
    big = d[d > GAP_PERIODS * stream.period_s]
    return {"n": int(len(big)), "longest_s": round(float(big.max()), 3) if len(big) else 0.0}


def _probe(stalls: list, stop: threading.Event) -> None:
    """Machine stalls: a 10 ms sleep of this process overslept by more than STALL_S."""
    while not stop.is_set():
        t0 = time.time_ns()
        time.sleep(0.01)
        t1 = time.time_ns()
        if (t1 - t0) * 1e-9 - 0.01 > STALL_S:
            stalls.append((t0, t1))


def _chaos(rng: random.Random, victims: list[Managed], events: list, stop: threading.Event):
    """Kill or freeze a random victim every 30-90 s (module docstring)."""
    while not stop.wait(rng.uniform(30, 90)):
        v = rng.choice(victims)
        start = time.time_ns()
        if rng.random() < 0.5:
            v.popen.kill()
            v.popen.wait(10)
            what = f"kill -9 and restart {v.name}"
            if stop.wait(rng.uniform(3, 8)):  # shutdown began: never restarted
                end = time.time_ns()
                events.append({"what": f"kill -9 {v.name} (not restarted: shutdown)",
                               "start_ns": start, "end_ns": end, "ready_ns": end,
                               "back": False, "streams": [REACHES[v.name]]})  # fmt: skip
                break
            v.restarts += 1
            v.start()
            end = time.time_ns()
            limit = time.monotonic() + READY_WAIT_S
            while not v.ready() and time.monotonic() < limit and not stop.wait(0.1):
                pass
            back = v.ready()
            if not back:
                waited = time.monotonic() - limit + READY_WAIT_S
                cut = ", wait cut short by the shutdown" if stop.is_set() else ""
                what += f" (not back after {waited:.0f} s{cut})"
        else:
            v.popen.send_signal(signal.SIGSTOP)
            stop.wait(rng.uniform(1, 4))
            v.popen.send_signal(signal.SIGCONT)
            what = f"freeze {v.name}"
            end, back = time.time_ns(), True
        events.append({"what": what, "start_ns": start, "end_ns": end, "ready_ns": time.time_ns(),
                       "back": back, "streams": [REACHES[v.name]]})  # fmt: skip
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
    stalls: list = []
    chaos_thread = None
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
        threading.Thread(target=_probe, args=(stalls, stop), daemon=True).start()
        if chaos:
            victims = [by_name[n] for n in ("demo natnet tracker", "demo dtrack tracker",
                                            "realm natnet tracker", "realm dtrack tracker",
                                            "agent nn", "agent dt")]  # fmt: skip
            chaos_thread = threading.Thread(
                target=_chaos, args=(random.Random(seed), victims, events, stop), daemon=True
            )
            chaos_thread.start()
        minutes_out = []
        last = {p.name: p.sample() for p in procs}
        marks = {s.name: len(s.arrivals) for s in (demo, app)}
        for m in range(int(np.ceil(minutes))):
            span = min(60.0, total_s - 60 * m)
            stop.wait(span)
            now = {p.name: p.sample() for p in procs}
            row = {"minute": m + 1, "rss_mb": {}, "cpu_share": {}, "answers": {},
                   "latency_ms": {}, "loadavg": round(os.getloadavg()[0], 2)}  # fmt: skip
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
        if chaos_thread is not None:
            chaos_thread.join(READY_WAIT_S)  # it never restarts a process after this
            if chaos_thread.is_alive():
                print("chaos thread still running at shutdown", file=sys.stderr, flush=True)
        if session is not None:
            session.close()
        for p in procs:
            p.stop()
    return _summary(minutes_out, events, [demo, app], start, end, procs, stalls)


def _summary(rows, events, streams, start, end, procs, stalls=()) -> dict:
    warm = min(5, max(1, len(rows) // 4))
    growth = 0.0
    for p in procs:
        if p.restarts:  # a restarted process starts again: judged from its last start
            continue
        rss = [r["rss_mb"].get(p.name) for r in rows[warm - 1 :]]
        rss = [x for x in rss if x is not None]
        if rss:
            growth = max(growth, max(rss) - rss[0])
    gaps = [g for st in streams for g in _gaps(st, events, list(stalls), start, end)]
    open_ = [g for g in gaps if g.pop("open_ns") > 0]  # gaps with an unexplained part
    drift = 0.0
    for st in streams:
        p99 = [r["latency_ms"].get(st.name, {}).get("p99") for r in rows[warm:]]
        p99 = [x for x in p99 if x is not None]
        if len(p99) >= 2 and p99[0] > 0:
            drift = max(drift, p99[-1] / p99[0])
    return {
        "rss_growth_mb": round(growth, 1),
        "answers_lost": sum(g["lost"] for g in gaps),
        "unexplained_gaps": len(open_),
        "p99_drift_ratio": round(drift, 3),
        # a breakdown, never subtracted from the two above: their part in machine stalls
        "answers_lost_load": sum(g["lost_load"] for g in gaps),
        "load_gaps": sum(g["load"] for g in open_),
        "delivery_stalls": {st.name: _delivery_stalls(st, start, end) for st in streams},
        "machine_stalls": {
            "n": len(stalls),
            "s": round(sum(b - a for a, b in stalls) * 1e-9, 2),
        },  # fmt: skip
        "max_loadavg": max((r["loadavg"] for r in rows), default=0.0),
        "warm_up_minutes": warm,
        "events": [
            {
                "what": e["what"],
                "streams": e["streams"],
                "start_s": round((e["start_ns"] - start) * 1e-9, 1),
                "end_s": round((e["end_ns"] - start) * 1e-9, 1),
                "ready_s": round((e["ready_ns"] - start) * 1e-9, 1),
                "back": e["back"],
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
    ap.add_argument("--keep", type=Path, help="keep the processes' logs in this folder")
    args = ap.parse_args(argv)
    missing = [p for p in (TABLE, EUROC, ROOM1) if not p.exists()]
    if missing:
        print(f"skipped: needs {missing}", file=sys.stderr)
        return 0
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
        out = soak(args.minutes, args.chaos, args.seed, args.keep)
    else:
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
