"""Agents in separate processes on loopback: discovery, push and pull queries, kill -9 and
re-planning, rejoining, garbage on the key space, late joiners, router-less and routed."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (pip install .[distributed])")

from _agents import (
    SRC,
    AgentProcess,
    endpoint,
    free_port,
    observer,
    sensor_and_app,
    status,
    wait_for,
    write_agent,
    write_recording,
)

from trackflow.distributed import remote_get
from trackflow.distributed.wire import decode, encode
from trackflow.math import Pose, UncertainPose

pytestmark = pytest.mark.slow

PERIOD_NS = 20_000_000  # the 50 Hz push query


def _files(tmp_path, realm, zenoh_of, start_ns):
    """Agent files: a (sensor s1: W->X, fast), b (sensor s2: W->Y, slow, static yx: Y->X),
    c (push query W->X), d (late joiner, pull query W->X)."""
    rec1 = write_recording(tmp_path / "s1.tfrec", "W", "X", rate_hz=100, duration_s=60, seed=1)
    rec2 = write_recording(tmp_path / "s2.tfrec", "W", "Y", rate_hz=100, duration_s=60, seed=2)
    common = dict(
        sigma_pos_mm=1.0, sigma_ori_deg=0.2, motion={"n_dp": 1, "n_do": 1, "noise": [1.0, 1.0]}
    )
    files = {
        "a": write_agent(
            tmp_path / "a.yaml",
            "a",
            realm,
            zenoh=zenoh_of("a"),
            start_ns=start_ns,
            sensors=[
                dict(
                    name="s1",
                    source="W",
                    target="X",
                    rate_hz=100,
                    latency_ms=5,
                    recording=str(rec1),
                    **common,
                )
            ],
        ),
        "b": write_agent(
            tmp_path / "b.yaml",
            "b",
            realm,
            zenoh=zenoh_of("b"),
            start_ns=start_ns,
            sensors=[
                dict(
                    name="s2",
                    source="W",
                    target="Y",
                    rate_hz=100,
                    latency_ms=20,
                    recording=str(rec2),
                    **common,
                )
            ],
            statics=[dict(name="yx", source="Y", target="X", sigma_pos_mm=0.1, sigma_ori_deg=0.01)],
        ),
        "c": write_agent(
            tmp_path / "c.yaml",
            "c",
            realm,
            zenoh=zenoh_of("c"),
            frames=["W", "X"],
            queries=[dict(name="q", source="W", target="X", mode="push", rate_hz=50)],
        ),
        "d": write_agent(
            tmp_path / "d.yaml",
            "d",
            realm,
            zenoh=zenoh_of("d"),
            frames=["W", "X"],
            queries=[dict(name="qd", source="W", target="X", mode="pull")],
        ),
    }
    return files


def _query(st: dict | None, name: str) -> dict:
    return (st or {}).get("queries", {}).get(name, {})


def _running_on(session, realm, agent, query, sensor, min_published=0):
    def check():
        q = _query(status(session, realm, agent), query)
        ok = q.get("state") == "running" and any(sensor in p for p in q.get("paths", []))
        ok = ok and q.get("path", 0) == 0  # answering from that path, not a fallback
        return q if ok and q.get("published", 0) >= min_published else None

    return check


@pytest.fixture
def procs(tmp_path):
    started: list[AgentProcess] = []

    def start(path, *args):
        p = AgentProcess(path, "--duration", "90", *args, log_dir=tmp_path)
        started.append(p)
        return p

    yield start
    for p in started:
        p.stop()


def test_peers_replan_after_kill9_rejoin_garbage_and_late_joiner(tmp_path, procs):
    realm = f"t{free_port()}"
    ports = {n: free_port() for n in "abcd"}
    others = {"a": [], "b": ["a"], "c": ["a", "b"], "d": ["a", "b", "c"]}

    def zenoh_of(n):
        return {
            "listen": {"endpoints": [endpoint(ports[n])]},
            "connect": {"endpoints": [endpoint(ports[o]) for o in others[n]]},
        }

    start_ns = (time.time_ns() // PERIOD_NS) * PERIOD_NS
    files = _files(tmp_path, realm, zenoh_of, start_ns)
    a, b, c = procs(files["a"]), procs(files["b"]), procs(files["c"])
    for p in (a, b, c):
        p.wait_ready()
    session = observer([endpoint(ports[n]) for n in "abc"])
    try:
        results = []
        sub = session.declare_subscriber(
            f"trackflow/{realm}/result/*/q", lambda s: results.append(decode(s.payload.to_bytes()))
        )
        wait_for(_running_on(session, realm, "c", "q", "s1", min_published=20), 60)
        wait_for(lambda: len(results) >= 10, 20)
        r = results[-1]
        assert r.pose.covariance.shape == (6, 6) and np.all(np.isfinite(r.pose.position))
        # c runs no filter of its own: it adopts the states of s1's filter, which runs on a
        replica = status(session, realm, "c")["replicas"]["s1"]
        assert replica["states"] > 20 and "another motion model" not in replica["rejections"]

        # garbage, unknown versions and poses where batches of filter states belong (a's) are
        # counted, nothing else happens
        pose = encode(
            UncertainPose(Pose.identity(), np.eye(6) * 1e-6), seq=1, exposure_ns=0, host_ns=0
        )
        for _ in range(5):
            session.put(f"trackflow/{realm}/states/a", b"garbage")
            session.put(f"trackflow/{realm}/states/a", pose[:2] + struct.pack("<B", 9) + pose[3:])
            session.put(f"trackflow/{realm}/states/a", pose)

        def counted():
            rej = (status(session, realm, "c") or {}).get("rejections", {})
            kinds = ("bad magic", "unknown version", "wrong kind")
            return rej if all(rej.get(k, 0) >= 5 for k in kinds) else None

        wait_for(counted, 20)

        # kill -9 the agent of the better path: the query re-plans through s2 and keeps going
        a.kill9()
        q = wait_for(_running_on(session, realm, "c", "q", "s2"), 30)
        assert any("s1 of agent a left" in e["reason"] for e in q["events"])
        before = q["published"]
        wait_for(_running_on(session, realm, "c", "q", "s2", min_published=before + 20), 30)

        # the restarted agent rejoins and the better path comes back
        procs(files["a"]).wait_ready()
        q = wait_for(_running_on(session, realm, "c", "q", "s1"), 30)
        assert any("s1 of agent a appeared" in e["reason"] for e in q["events"])

        # a late joiner learns the static edge and answers pull queries over Zenoh
        procs(files["d"]).wait_ready()

        def joined():  # it has learnt the static edge and its query runs (in either order)
            s = status(session, realm, "d")
            return s and "yx" in s["statics"] and _query(s, "qd").get("state") == "running"

        wait_for(joined, 30)

        def pulled():
            try:
                return remote_get(session, realm, "query/qd", time.time_ns() - 50_000_000)
            except ValueError:
                return None

        sample = wait_for(pulled, 30)
        assert abs(sample.pose.position[2] - 1.0) < 0.05  # the recordings hold z = 1 m
        edge = remote_get(session, realm, "get/s2", time.time_ns() - 50_000_000)
        assert abs(edge.pose.position[2] - 1.0) < 0.05
        # placement: d answers from its replica of s1's filter (running on a) what a's filter
        # answers itself at the same instant. d maps a's stamps with its estimate of a's
        # clock offset (0.01-1 ms off the truth, more under load), so d's answer at t is a's
        # filter at t + offset: a is asked at that time (moving at up to 0.4 m/s, the
        # offset alone would part the answers by 0.4 mm per ms)
        wait_for(_running_on(session, realm, "d", "qd", "s1"), 30)

        def same_states():
            # both answers must come from the same newest state, whose origin d maps by its
            # offset estimate (so a's origin minus d's is that estimate, < 1 ms), predicted
            # forward from it: at a time before that state a answers from its history and d
            # back from the state (a loaded run parted them by 0.8 mm so). A state that
            # reaches a or d between the requests changes an answer: asked again
            try:
                t = time.time_ns() - 50_000_000
                newest = remote_get(session, realm, "query/qd", t).origin_ns
                t = max(t, newest + 1_000_000)
                at_d = remote_get(session, realm, "query/qd", t)
                offset = remote_get(session, realm, "get/s1", t).origin_ns - at_d.origin_ns
                if abs(offset) >= 1_000_000 or at_d.exposure_ns < at_d.origin_ns:
                    return None
                at_a = remote_get(session, realm, "get/s1", t + offset)
                again = remote_get(session, realm, "query/qd", t)
            except ValueError:  # refused (too far ahead of the newest state): asked again
                return None
            same = at_a.origin_ns - offset == at_d.origin_ns == again.origin_ns
            return (at_d, at_a) if same else None

        at_d, at_a = wait_for(same_states, 30)
        # equal up to the rounding of times in float seconds (0.24 us at Unix times)
        assert np.linalg.norm(at_d.pose.position - at_a.pose.position) < 1e-6
        with pytest.raises(ValueError, match="missing or not an integer"):
            for reply in session.get(f"trackflow/{realm}/query/qd?t=soon", timeout=3.0):
                if reply.err is not None:
                    raise ValueError(reply.err.payload.to_bytes().decode())
        sub.undeclare()
    finally:
        session.close()


def test_router_setup_with_clients(tmp_path, procs):
    realm = f"r{free_port()}"
    router_port = free_port()

    def zenoh_of(n):
        return {"mode": "client", "connect": {"endpoints": [endpoint(router_port)]}}

    start_ns = (time.time_ns() // PERIOD_NS) * PERIOD_NS
    files = _files(tmp_path, realm, zenoh_of, start_ns)
    router = write_agent(tmp_path / "router.yaml", "router", realm, zenoh={})
    procs(router, "--mode", "router", "--listen", endpoint(router_port)).wait_ready()
    a, b, c = procs(files["a"]), procs(files["b"]), procs(files["c"])
    for p in (a, b, c):
        p.wait_ready()
    session = observer([endpoint(router_port)])
    try:
        wait_for(_running_on(session, realm, "c", "q", "s1", min_published=20), 60)
        a.kill9()
        q = wait_for(_running_on(session, realm, "c", "q", "s2"), 30)
        wait_for(_running_on(session, realm, "c", "q", "s2", min_published=q["published"] + 10), 30)
    finally:
        session.close()


def test_status_file_is_current_while_the_agent_runs(tmp_path, procs):
    """``--status FILE`` is rewritten while the agent runs (a monitor can read it at any time,
    whole), not only at exit."""
    rec = write_recording(tmp_path / "s1.tfrec", "W", "X", rate_hz=100, duration_s=60, seed=9)
    path = write_agent(
        tmp_path / "s.yaml", "lone", f"st{free_port()}", zenoh={}, start_ns=time.time_ns(),
        sensors=[dict(name="s1", source="W", target="X", rate_hz=100, sigma_pos_mm=1.0,
                      sigma_ori_deg=0.2, motion={"n_dp": 1, "n_do": 1, "noise": [1.0, 1.0]},
                      recording=str(rec))],
    )  # fmt: skip
    status_file = tmp_path / "status.json"
    p = procs(path, "--status", str(status_file))
    p.wait_ready()
    first = wait_for(lambda: status_file.exists() and json.loads(status_file.read_text()), 30)
    assert p.proc.poll() is None  # written while running
    assert first["agent"] == "lone" and first["security"] == "loopback"
    later = wait_for(
        lambda: (
            (s := json.loads(status_file.read_text()))["published_states"]
            > first["published_states"]
            and s
        ),
        30,
    )
    assert later["agent"] == "lone" and p.proc.poll() is None


def test_status_command_shows_every_agent_of_a_realm(tmp_path, procs):
    """``trackflow status --realm`` joins read-only and shows both agents: the sensor's
    host advertising its sensor, the application's query running on it."""
    realm = f"stat{free_port()}"
    sensor, app, (es, ec) = sensor_and_app(tmp_path, realm)
    for p in (procs(sensor), procs(app)):
        p.wait_ready()
    cmd = [sys.executable, "-m", "trackflow.cli.main", "status", "--realm", realm,
           "--connect", es, "--connect", ec]  # fmt: skip
    env = dict(os.environ, PYTHONPATH=str(SRC))

    def running():
        out = subprocess.run([*cmd, "--json"], capture_output=True, text=True, timeout=60,
                             env=env)  # fmt: skip
        st = json.loads(out.stdout)
        q = st.get("host_c", {}).get("queries", {}).get("q", {})
        return st if q.get("state") == "running" and q.get("published", 0) > 0 else None

    st = wait_for(running, 60, interval_s=1.0)
    assert sorted(st) == ["host_c", "host_s"]
    assert st["host_c"]["live_edges"] == {"s1": "host_s"}
    text = subprocess.run(cmd, capture_output=True, text=True, timeout=60, env=env).stdout
    assert text.startswith(f"realm {realm}: 2 agent(s)")
    assert "host_s (links: loopback)" in text and "q: running, path W->X[s1]" in text
