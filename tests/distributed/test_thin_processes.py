"""Thinned delivery between real agent processes on loopback: one sensor at 240 Hz, consumers
at 30 Hz and 60 Hz asking for thinned streams and one receiving every state; the union is
served, each stream carries one state per tick, the answers match the unthinned consumer's,
garbage demands are counted, and a consumer that dies stops costing the sensor's agent."""

from __future__ import annotations

import collections
import time

import numpy as np
import pytest

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (pip install .[distributed])")

from _agents import (
    AgentProcess,
    endpoint,
    free_port,
    observer,
    status,
    wait_for,
    write_agent,
    write_recording,
)

from trackflow.distributed.thinning import Grid, demand_key
from trackflow.distributed.wire import decode, decode_state

pytestmark = pytest.mark.slow

P30, P60 = int(round(1e9 / 30)), int(round(1e9 / 60))


def _consumer(tmp_path, name, realm, port, sensor_ports, rate, thin, clock_sync="estimate"):
    return write_agent(
        tmp_path / f"{name}.yaml",
        name,
        realm,
        zenoh={
            "listen": {"endpoints": [endpoint(port)]},
            "connect": {"endpoints": [endpoint(p) for p in sensor_ports]},
        },
        extra={"reorder_ms": 60, "thin": thin, "clock_sync": clock_sync},
        frames=["W", "X"],
        queries=[dict(name=f"q_{name}", source="W", target="X", mode="push", rate_hz=rate)],
    )


def test_thinned_streams_union_garbage_and_a_dying_consumer(tmp_path):
    realm = f"th{free_port()}"
    ports = {n: free_port() for n in ("s", "c30", "c60", "r30")}
    rec = write_recording(tmp_path / "s1.tfrec", "W", "X", rate_hz=240, duration_s=90, seed=3)
    start_ns = time.time_ns()
    sensor = write_agent(
        tmp_path / "s.yaml",
        "s",
        realm,
        zenoh={"listen": {"endpoints": [endpoint(ports["s"])]}},
        start_ns=start_ns,
        sensors=[
            dict(
                name="s1",
                source="W",
                target="X",
                rate_hz=240,
                latency_ms=3,
                sigma_pos_mm=1.0,
                sigma_ori_deg=0.2,
                motion={"n_dp": 1, "n_do": 1, "noise": [1.0, 1.0]},
                recording=str(rec),
            )
        ],
    )
    # c30 and r30 answer at the same ticks and are compared: they read the host's one clock
    # as it is (clock_sync none). With an estimated offset each, the two estimates differ by
    # up to their round trips (0.01-1 ms under load): a state made that close to a tick is
    # before it for one consumer and after it for the other, at every tick alike (the 240 Hz
    # samples keep one phase to the 30 Hz grid), and each answer is the filter at the tick
    # plus its own estimate. c60 keeps the estimate: its grid follows it (checked below).
    files = {
        "c30": _consumer(tmp_path, "c30", realm, ports["c30"], [ports["s"]], 30, True, "none"),
        "c60": _consumer(tmp_path, "c60", realm, ports["c60"], [ports["s"]], 60, True),
        "r30": _consumer(tmp_path, "r30", realm, ports["r30"], [ports["s"]], 30, False, "none"),
    }
    procs = [AgentProcess(sensor, "--duration", "80", log_dir=tmp_path)]
    procs += [AgentProcess(f, "--duration", "80", log_dir=tmp_path) for f in files.values()]
    session = None
    try:
        for p in procs:
            p.wait_ready()
        session = observer([endpoint(ports[n]) for n in ports])
        results = {n: {} for n in files}
        thin_msgs = {n: [] for n in ("c30", "c60")}
        subs = [
            session.declare_subscriber(
                f"trackflow/{realm}/result/*/q_{n}",
                lambda s, n=n: results[n].__setitem__(
                    (w := decode(s.payload.to_bytes())).exposure_ns, w
                ),
            )
            for n in files
        ]
        subs += [
            session.declare_subscriber(
                f"trackflow/{realm}/thin/s1/{n}",
                lambda s, n=n: thin_msgs[n].append(
                    (s.attachment.to_bytes(), s.payload.to_bytes(), time.monotonic())
                ),
            )
            for n in thin_msgs
        ]

        def serving():
            st = status(session, realm, "s") or {}
            streams = st.get("thin_streams", {}).get("s1", {})
            return st if {"c30", "c60"} <= set(streams) else None

        wait_for(serving, 60)
        wait_for(lambda: all(len(r) > 60 for r in results.values()), 60)
        for n in files:  # start counting now
            results[n].clear()
        for n in thin_msgs:
            thin_msgs[n].clear()
        time.sleep(4.0)

        # each consumer's stream: ticks of its own grid, in order, one state per tick at most:
        # the sensor's agent completes no tick before its player has played every sample
        # arriving by it, so no state is sent late, after its tick, even when the player runs
        # late on a loaded host. The messages are taken before the status: its late counters
        # then cover every one of them.
        got = {n: list(m) for n, m in thin_msgs.items()}
        st = status(session, realm, "s")
        for n, period in (("c30", P30), ("c60", P60)):
            msgs = [(int.from_bytes(a, "little", signed=True), p) for a, p, _ in got[n]]
            grid = st["thin_streams"]["s1"][n]["grids"]
            assert [g[0] for g in grid] == [period]
            ticks = [t for t, _ in msgs]
            assert ticks == sorted(ticks)
            # on the consumer's grid: one phase, or a few while the consumer re-declares it to
            # follow its clock-offset estimate (which moves under load)
            phases = collections.Counter(t % period for t in ticks)
            assert len(phases) <= 3 and grid[0][1] in phases, (n, phases, grid)
            states = [(t, decode_state(p)) for t, p in msgs if p]
            late = st["thin_streams"]["s1"][n]["late"]
            per_tick = collections.Counter(t for t, _ in states)
            assert late == 0 and max(per_tick.values(), default=0) <= 1, (n, late, per_tick)
            n_ticks = (ticks[-1] - ticks[0]) // period + 1
            assert len(per_tick) >= 0.5 * n_ticks, (n, len(per_tick), n_ticks)  # 240 Hz sensor
            seqs = [s.seq for _, s in states]
            assert seqs == sorted(seqs)  # the newest state for each tick, in the filter's order
        # the unthinned consumer gets every state (240 Hz) and answers each tick once its
        # 60 ms jitter buffer has passed; the thinned one answers as soon as its stream
        # completes the tick. An answer made from the same newest measurement (its origin
        # stamp) in both must be the same to the bit (one clock, the same state, the same
        # prediction). A host stalled for longer than the jitter buffer in one consumer and
        # not the other makes them answer a tick from different states: those ticks are
        # counted apart, not compared, so the check does not depend on the host's load.
        common = sorted(set(results["r30"]) & set(results["c30"]))
        assert len(common) > 30, (len(common), {n: len(r) for n, r in results.items()})
        same = [t for t in common if results["r30"][t].origin_ns == results["c30"][t].origin_ns]
        assert len(same) >= 10, (len(same), len(common))
        d = np.array(
            [
                np.linalg.norm(results["r30"][t].pose.position - results["c30"][t].pose.position)
                for t in same
            ]
        )
        assert d.max() <= 1e-9, (int(np.sum(d > 1e-9)), len(same), d.max())

        # garbage demands are counted rejections; the agent keeps serving
        bad = [
            f"trackflow/{realm}/demand/s1/x/abc/0",
            f"trackflow/{realm}/demand/s1/x/10/0",
            f"trackflow/{realm}/demand/s1/x/{P30}/{P30}",
            f"trackflow/{realm}/demand/nosuch/x/{P30}/0",
            f"trackflow/{realm}/demand/s1/x",
        ]
        tokens = [session.liveliness().declare_token(k) for k in bad]
        reasons = (
            "malformed demand",
            "demand period out of range",
            "demand phase out of range",
            "demand for unknown edge",
        )

        def counted():  # two malformed keys, one of each other reason (in any order)
            rej = (status(session, realm, "s") or {}).get("rejections", {})
            want = {r: 2 if r == "malformed demand" else 1 for r in reasons}
            return rej if all(rej.get(r, 0) >= n for r, n in want.items()) else None

        rej = wait_for(counted, 20)
        assert rej["malformed demand"] >= 2, rej
        for t in tokens:
            t.undeclare()

        # anyone may ask: a demand of the test's own session gets its own stream, then ends
        got = []
        sub = session.declare_subscriber(
            f"trackflow/{realm}/thin/s1/obs", lambda s: got.append(s.attachment.to_bytes())
        )
        token = session.liveliness().declare_token(
            demand_key(realm, "s1", "obs", Grid(100_000_000, 0))
        )
        wait_for(lambda: len(got) >= 5, 20)
        ticks = [int.from_bytes(a, "little", signed=True) for a in got]
        assert all(t % 100_000_000 == 0 for t in ticks)
        token.undeclare()
        sub.undeclare()
        wait_for(lambda: "obs" not in serving()["thin_streams"]["s1"], 20)

        # kill -9 a consumer: its token goes, its stream ends; the other keeps its own
        procs[2].kill9()  # c60
        st = wait_for(lambda: _without(session, realm), 30)
        assert "c30" in st["thin_streams"]["s1"]
        for s in subs:
            s.undeclare()
    finally:
        if session is not None:
            session.close()
        for p in procs:
            p.stop()


def _without(session, realm):
    st = status(session, realm, "s") or {}
    streams = st.get("thin_streams", {}).get("s1", {})
    return st if "c60" not in streams and "c30" in streams else None


def test_thinned_consumer_replans_after_kill9(tmp_path):
    """A thinned push query re-plans through the other sensor when the better one's agent
    is killed, and asks the remaining sensor's agent for a thinned stream of it."""
    realm = f"tr{free_port()}"
    ports = {n: free_port() for n in "abc"}
    start_ns = time.time_ns()
    common = dict(
        rate_hz=240,
        sigma_pos_mm=1.0,
        sigma_ori_deg=0.2,
        motion={"n_dp": 1, "n_do": 1, "noise": [1.0, 1.0]},
    )
    rec1 = write_recording(tmp_path / "s1.tfrec", "W", "X", rate_hz=240, duration_s=90, seed=5)
    rec2 = write_recording(tmp_path / "s2.tfrec", "W", "Y", rate_hz=240, duration_s=90, seed=6)
    a = write_agent(
        tmp_path / "a.yaml",
        "a",
        realm,
        zenoh={"listen": {"endpoints": [endpoint(ports["a"])]}},
        start_ns=start_ns,
        sensors=[
            dict(name="s1", source="W", target="X", latency_ms=2, recording=str(rec1), **common)
        ],
    )
    b = write_agent(
        tmp_path / "b.yaml",
        "b",
        realm,
        zenoh={
            "listen": {"endpoints": [endpoint(ports["b"])]},
            "connect": {"endpoints": [endpoint(ports["a"])]},
        },
        start_ns=start_ns,
        sensors=[
            dict(name="s2", source="W", target="Y", latency_ms=20, recording=str(rec2), **common)
        ],
        statics=[dict(name="yx", source="Y", target="X", sigma_pos_mm=0.1, sigma_ori_deg=0.01)],
    )
    c = _consumer(tmp_path, "c", realm, ports["c"], [ports["a"], ports["b"]], 50, True)
    procs = [AgentProcess(f, "--duration", "80", log_dir=tmp_path) for f in (a, b, c)]
    session = None
    try:
        for p in procs:
            p.wait_ready()
        session = observer([endpoint(ports[n]) for n in "bc"])

        def query(sensor, min_published=0):
            st = status(session, realm, "c") or {}
            q = st.get("queries", {}).get("q_c", {})
            ok = q.get("state") == "running" and any(sensor in p for p in q.get("paths", []))
            ok = ok and q.get("path", 0) == 0  # answering from that path, not a fallback
            return st if ok and q.get("published", 0) >= min_published else None

        st = wait_for(lambda: query("s1", 20), 60)
        assert "s1" in st["thin_inputs"]
        procs[0].kill9()
        st = wait_for(lambda: query("s2"), 30)
        before = st["queries"]["q_c"]["published"]
        st = wait_for(lambda: query("s2", before + 20), 30)
        assert "s2" in st["thin_inputs"]
        served = status(session, realm, "b")["thin_streams"]
        assert "c" in served["s2"] and served["s2"]["c"]["sent"] > 0
    finally:
        if session is not None:
            session.close()
        for p in procs:
            p.stop()
