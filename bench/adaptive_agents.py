"""Failover across three agents, measured with real processes (issue 28's figures, the
distributed half of ``bench/adaptive.py``).

The scenario of ``bench/adaptive.py`` spread over a Zenoh realm on loopback: agent ``nn``
holds the NatNet sensor (its ``input:``, the preferred path), agent ``dt`` the DTrack sensor,
agent ``app`` the 100 Hz push query with ``failover: {hold_ms: 500}``; both sensors have
``stale_ms: 100``. The NatNet tracker (``trackflow simulate``) fails three ways: an outage
(``--outage``), a SIGKILL (a new sender 1 s later) and a SIGSTOP for 1 s. The app's switches
come from its status (Zenoh query), its answers from its result key, the truth from the
senders' ``--truth`` files.

Per mode: ``failover_gap_ms``, from the exposure of the newest NatNet state the app had to
its move to DTrack (the age its switch reports in the reason, ``no data for X ms``; for the
outage also from the sender's truth, ``gap_from_truth_ms``), ``switch_back_s`` from the
NatNet tracker's recovery (its first frame after the outage or the restart; SIGCONT) to the
move back (after a freeze: from the first fresh frame after SIGCONT, as in the one-process
benchmark), and the position NEES of the answers on DTrack against the DTrack sender's truth.
JSON with ``--json``: ``{"failover_gap_ms": {"outage", "kill", "freeze"},
"post_switch_nees", "post_switch_nees_p99", "switch_back_s", "hold_s", "modes"}``.

Usage: ``python bench/adaptive_agents.py [--json]`` (needs eclipse-zenoh and
``../shared/data/tumvi``).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from _failover_modes import print_table, run_modes, summary
from _procs import stop
from trackflow.distributed.wire import decode
from trackflow.io import read_stream

ROOT = Path(__file__).resolve().parents[1]
ROOM1 = ROOT.parent / "shared" / "data" / "tumvi" / "dataset-room1_512_16.txt"
STALE_MS, HOLD_MS, RATE_HZ = 100, 500, 100
FAIL_AT_S, FAIL_FOR_S, START_S, DURATION_S, OUTAGE_AT_S = 3.0, 1.0, 5.0, 16.0, 7.0
MOTION = {"n_dp": 1, "n_do": 1, "noise": [0.0, 3.0, 0.0, 10.0]}
SENSOR = {"source": "W", "target": "B", "rate_hz": 120, "sigma_pos_mm": 0.5,
          "sigma_ori_deg": 0.2, "motion": MOTION}  # fmt: skip


def _port(kind=socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _endpoint(port: int) -> str:
    return f"tcp/127.0.0.1:{port}"


def _proc(*args, log: Path | None = None) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    out = subprocess.PIPE if log is None else open(log, "w")  # closed when this process exits
    return subprocess.Popen(
        [sys.executable, "-m", "trackflow.cli.main", *map(str, args)],
        env=env, stdout=out, stderr=subprocess.STDOUT if log else subprocess.PIPE, text=True,
    )  # fmt: skip


def _agent_file(folder: Path, name: str, realm: str, ports: dict, doc: dict) -> Path:
    """An agent's YAML: Zenoh on loopback, listening on its port, connected to those
    before it."""
    before = list(ports)[: list(ports).index(name)]
    zenoh = {"listen": {"endpoints": [_endpoint(ports[name])]},
             "connect": {"endpoints": [_endpoint(ports[o]) for o in before]}}  # fmt: skip
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump({"agent": {"name": name, "realm": realm, "zenoh": zenoh},
                                    "frames": ["W", "B"], **doc}, sort_keys=False))  # fmt: skip
    return path


def _wait(fn, timeout_s: float, what: str, show=None):
    """``fn()`` once it is truthy, polled; a TimeoutError with ``show()`` after
    ``timeout_s``."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        got = fn()
        if got:
            return got
        time.sleep(0.1)
    raise TimeoutError(f"{what}: not within {timeout_s} s; {show() if show else ''}")


def _status(session, realm: str, agent: str) -> dict:
    for reply in session.get(f"trackflow/{realm}/status/{agent}", timeout=3.0):
        if reply.ok is not None:
            return json.loads(reply.ok.payload.to_bytes())
    return {}


def _sender(protocol: str, port: int, truth: Path, start_s: float, duration_s: float, *extra):
    body = ("--body", "rig") if protocol == "natnet" else ("--body-id", 1)
    return _proc(
        "simulate", protocol, ROOM1, "--port", port, *body, "--wait", 200,
        "--start", start_s, "--duration", duration_s, "--truth", truth, *extra,
    )  # fmt: skip


def measure(mode: str, folder: Path) -> dict:
    """One run of ``mode`` (module docstring)."""
    import zenoh

    realm = f"adapt{_port()}"
    ports = {n: _port(socket.SOCK_STREAM) for n in ("nn", "dt", "app")}
    nn, dt = _port(), _port()
    files = {
        "nn": _agent_file(folder, "nn", realm, ports, {"sensors": [{
            "name": "natnet", **SENSOR, "latency_ms": 5,
            "input": {"natnet": {"command_port": nn, "body": "rig"}, "stale_ms": STALE_MS}}]}),
        "dt": _agent_file(folder, "dt", realm, ports, {"sensors": [{
            "name": "dtrack", **SENSOR, "latency_ms": 20,
            "input": {"dtrack": {"port": dt, "body": 1}, "stale_ms": STALE_MS}}]}),
        "app": _agent_file(folder, "app", realm, ports, {"queries": [{
            "name": "q", "source": "W", "target": "B", "mode": "push", "rate_hz": RATE_HZ,
            "failover": {"hold_ms": HOLD_MS}}]}),
    }  # fmt: skip
    agents = {n: _proc("agent", f, "--duration", 120, log=folder / f"{n}.log")
              for n, f in files.items()}  # fmt: skip
    senders: list[subprocess.Popen] = []
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([_endpoint(p) for p in ports.values()]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = None
    answers: list = []
    try:
        for n in agents:
            _wait(lambda n=n: '"ready"' in (folder / f"{n}.log").read_text(), 180, f"agent {n}")
        session = zenoh.open(conf)
        sub = session.declare_subscriber(
            f"trackflow/{realm}/result/*/q", lambda s: answers.append(decode(s.payload.to_bytes()))
        )
        extra = (
            ("--outage", f"{OUTAGE_AT_S}:{OUTAGE_AT_S + FAIL_FOR_S}") if mode == "outage" else ()
        )
        started_ns = time.time_ns()  # the NatNet sender's first frame is later
        natnet = _sender("natnet", nn, folder / "nn_truth.tfrec", START_S, DURATION_S, *extra)
        senders += [natnet, _sender("dtrack", dt, folder / "dt_truth.tfrec", START_S, DURATION_S)]

        def on(path: int):
            q = _status(session, realm, "app").get("queries", {}).get("q", {})
            return q if q.get("state") == "running" and q.get("path") == path else None

        def app() -> dict:
            return _status(session, realm, "app").get("queries", {}).get("q", {})

        _wait(lambda: on(0) and len(answers) > 50, 60, "answers from NatNet", app)
        streaming = time.monotonic()
        # the switches of the start (a tracker that delivers first) are not the failure's
        base_ns = time.time_ns()
        recovered_ns = None
        # the failure begins after failed_ns and ends after healed_ns (a kill or a freeze:
        # here; an outage: from the sender's truth afterwards)
        if mode == "outage":
            failed_ns = healed_ns = started_ns  # (exact ones from the truth below)
        else:
            time.sleep(FAIL_AT_S)
            failed_ns = time.time_ns()
            if mode == "kill":
                natnet.kill()
                natnet.communicate()
                time.sleep(FAIL_FOR_S)
                resumed = time.monotonic() - streaming
                healed_ns = time.time_ns()
                senders.append(_sender("natnet", nn, folder / "nn2_truth.tfrec",
                                       START_S + resumed, DURATION_S - resumed))  # fmt: skip
            else:
                natnet.send_signal(signal.SIGSTOP)
                time.sleep(FAIL_FOR_S)
                recovered_ns = healed_ns = time.time_ns()
                natnet.send_signal(signal.SIGCONT)

        # back on NatNet after a move away for the failure (while the trackers still
        # stream): a move before the failure (a loaded host's stall of the NatNet agent
        # longer than stale_ms) and its return are not the failure's
        def returned():
            q = on(0)
            moved = [e for e in (q or {}).get("switches", []) if e["t_ns"] > failed_ns]
            away = [e for e in moved if e["to"] == 1]
            ok = away and moved[-1]["to"] == 0 and moved[-1]["t_ns"] > healed_ns
            return q if ok else None

        if mode == "outage":
            # when the outage comes is known only from the sender's truth (its process starts
            # streaming a variable time after it is started): the whole run, then the status,
            # which keeps every switch
            natnet.communicate(timeout=120)
            q = app()
        else:
            q = _wait(returned, 30, "the return to NatNet", app)
        for p in senders:
            if p.returncode is None:
                p.communicate(timeout=120)
        sub.undeclare()
        rejections = _status(session, realm, "app").get("rejections", {})
    finally:
        if session is not None:
            session.close()
        for p in (*senders, *agents.values()):
            stop(p)
    events = [e for e in q["switches"] if e["t_ns"] > base_ns]
    if mode == "outage":  # the newest frame before the outage, and the first after it
        truth, _ = read_stream(folder / "nn_truth.tfrec")
        k = int(np.argmax(np.diff(truth.t_ns)))
        failed_ns = int(truth.t_ns[k])
        recovered_ns = int(truth.t_ns[k + 1]) + 5_000_000  # sent 5 ms after its exposure
    away = next((e for e in events if e["to"] == 1 and e["t_ns"] > failed_ns), None)
    back = away and next((e for e in events if e["to"] == 0 and e["t_ns"] > away["t_ns"]), None)
    if back is None:
        gaps = [] if mode != "outage" else [
            (round((int(a) - failed_ns) * 1e-6, 1), round(int(b - a) * 1e-6, 1))
            for a, b in zip(truth.t_ns[:-1], truth.t_ns[1:]) if b - a > 50_000_000]  # fmt: skip
        raise RuntimeError(
            f"{mode}: no move away and back after the failure began; failed_ns {failed_ns}, "
            f"base_ns {base_ns}, events {events}, gaps over 50 ms (from the failure, ms) {gaps}"
        )
    age = re.match(r"sensor natnet: no data for (\d+) ms", away["reason"])
    if age is None:
        raise RuntimeError(f"{mode}: moved for another reason: {events}")
    out = {"failover_gap_ms": float(age.group(1)), "reason": away["reason"]}
    # moves away before the failure: a stall of an agent longer than stale_ms on a loaded
    # host is a real gap of the data the app sees, so the app moves; counted, not hidden
    out["moves_before_failure"] = [e for e in events if e["to"] == 1 and e["t_ns"] <= failed_ns]
    if mode == "outage":
        out["gap_from_truth_ms"] = round((away["t_ns"] - failed_ns) * 1e-6, 1)
    elif mode == "kill":
        again, _ = read_stream(folder / "nn2_truth.tfrec")
        recovered_ns = int(again.t_ns[0]) + 5_000_000
    else:  # the first fresh frame after SIGCONT (the continued sender first flushes old ones)
        truth, _ = read_stream(folder / "nn_truth.tfrec")
        out["sigcont_to_fresh_ms"] = round(
            (int(truth.t_ns[np.searchsorted(truth.t_ns, recovered_ns)]) + 5_000_000
             - recovered_ns) * 1e-6, 1)  # fmt: skip
        recovered_ns += int(out["sigcont_to_fresh_ms"] * 1e6)
    out["switch_back_s"] = round((back["t_ns"] - recovered_ns) * 1e-9, 3)
    out["back_reason"] = back["reason"]
    dt_truth, _ = read_stream(folder / "dt_truth.tfrec")
    t = np.array([a.exposure_ns for a in answers], dtype=np.int64)
    on_dt = (t >= away["t_ns"]) & (t < back["t_ns"]) & (t > dt_truth.t_ns[0])
    on_dt &= t < dt_truth.t_ns[-1]
    pos = np.array([a.pose.position for a in answers])[on_dt]
    cov = np.array([a.pose.covariance for a in answers])[on_dt][:, :3, :3]
    ref = np.stack([np.interp(t[on_dt], dt_truth.t_ns, dt_truth.position[:, i])
                    for i in range(3)], axis=1)  # fmt: skip
    err = pos - ref
    out["nees"] = np.einsum("ni,ni->n", err, np.linalg.solve(cov, err[..., None])[..., 0])
    out["answers_on_dtrack"] = int(on_dt.sum())
    out["switches"] = events
    out["backlog_dropped"] = rejections.get("older than the backlog window", 0)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if not ROOM1.exists():
        print(f"needs {ROOM1}", file=sys.stderr)
        return 2
    modes = run_modes(measure, " (three agents)")
    out = {**summary(modes, STALE_MS + 2 * 1000 / 120), "hold_s": HOLD_MS / 1000}
    if args.json:
        print(json.dumps(out))
    else:
        print_table(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
