"""Two agents in one process (real Zenoh sessions on loopback sockets): a sensor leaves and
the query reports "no path" with the reason, a new sensor joins the running plan, and the
command line reports bad agent files through its one error boundary."""

from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (pip install .[distributed])")

from _agents import endpoint, free_port, observer, wait_for

from trackflow.cli.main import main
from trackflow.dataflow import LONG_RUN_KEEP, parse_setup
from trackflow.distributed import Agent, AgentConfig
from trackflow.math import Pose, UncertainPose

MOTION = {"n_dp": 1, "n_do": 1, "noise": [1.0, 1.0]}


def _sensor(name, latency_ms):
    return dict(
        name=name,
        source="W",
        target="X",
        rate_hz=100,
        latency_ms=latency_ms,
        sigma_pos_mm=1.0,
        sigma_ori_deg=0.1,
        motion=MOTION,
    )


def _feed(agent, edge, n=30):
    for _ in range(n):
        t = agent.now_ns()
        agent.feed(edge, t, UncertainPose(Pose([0.1, 0.2, 1.0], [0, 0, 0, 1]), np.eye(6) * 1e-6))
        time.sleep(0.01)


@pytest.mark.slow
def test_no_path_with_reason_then_a_new_sensor_joins():
    realm = f"ip{free_port()}"
    pa, pb, pc = free_port(), free_port(), free_port()
    app = AgentConfig(
        "app",
        parse_setup({"frames": ["W", "X"], "queries": [dict(name="q", source="W", target="X")]}),
        realm=realm,
        zenoh={
            "listen": {"endpoints": [endpoint(pc)]},
            "connect": {"endpoints": [endpoint(pa), endpoint(pb)]},
        },
    )
    slow = AgentConfig(
        "slow",
        parse_setup({"sensors": [_sensor("s_slow", 40)]}),
        realm=realm,
        zenoh={"listen": {"endpoints": [endpoint(pa)]}},
    )
    fast = AgentConfig(
        "fast",
        parse_setup({"sensors": [_sensor("s_fast", 2)]}),
        realm=realm,
        zenoh={"listen": {"endpoints": [endpoint(pb)]}},
    )
    with Agent(app) as c:
        a = Agent(slow).start()
        try:
            wait_for(lambda: c.queries["q"].paths == ["W->X[s_slow]"], 30)
            _feed(a, "s_slow")
            m = wait_for(lambda: c.get("q", a.now_ns() - 20_000_000), 10)
            assert np.allclose(m.pose.position, [0.1, 0.2, 1.0], atol=1e-3)
        finally:
            a.close()
        st = wait_for(lambda: c.queries["q"].state == "no path" and c.queries["q"], 30)
        assert "no path from frame 'W' to frame 'X'" in st.reason
        assert st.events[-1]["reason"] == "sensor s_slow of agent slow left"
        assert c.get("q", c.now_ns()) is None
        # the sensor comes back; then a better sensor joins the running plan
        with Agent(slow):
            wait_for(lambda: c.queries["q"].paths == ["W->X[s_slow]"], 30)
            with Agent(fast) as b:
                st = wait_for(
                    lambda: c.queries["q"].paths == ["W->X[s_fast]"] and c.queries["q"], 30
                )
                assert st.events[-1]["reason"] == "edge s_fast of agent fast appeared"
                _feed(b, "s_fast")
                assert wait_for(lambda: c.get("q", b.now_ns() - 20_000_000), 10) is not None
                assert {"s_slow", "s_fast"} <= {e.name for e in c.union_graph().edges}


def test_cli_reports_bad_agent_files(tmp_path, capsys):
    p = tmp_path / "bad.yaml"
    p.write_text("agent: {name: a, colour: red}\n")
    assert main(["agent", str(p)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("trackflow: error:") and "unknown keys" in err and str(p) in err


def test_cli_reports_a_port_in_use(tmp_path, capsys):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = s.getsockname()[1]
        p = tmp_path / "a.yaml"
        endpoints = f"['tcp/127.0.0.1:{port}']"
        p.write_text(f"agent: {{name: a, zenoh: {{listen: {{endpoints: {endpoints}}}}}}}\n")
        assert main(["agent", str(p), "--duration", "1"]) == 1
    err = capsys.readouterr().err
    assert "cannot open the Zenoh session" in err


@pytest.mark.slow
def test_pull_via_get_asks_the_sensor_agent_per_request():
    """``pull_via: get``: no subscription, no replica; each pull is a Zenoh query to the
    sensor agent's get(t), whose answer it returns unchanged (one clock: clock_sync none)."""
    from trackflow.distributed import RemoteGet, remote_get

    realm = f"pv{free_port()}"
    pa, pc = free_port(), free_port()
    app = AgentConfig(
        "app",
        parse_setup({"frames": ["W", "X"], "queries": [dict(name="q", source="W", target="X")]}),
        realm=realm,
        clock_sync="none",
        pull_via="get",
        zenoh={
            "listen": {"endpoints": [endpoint(pc)]},
            "connect": {"endpoints": [endpoint(pa)]},
        },
    )
    sensor = AgentConfig(
        "sensor",
        parse_setup({"sensors": [_sensor("s", 5)]}),
        realm=realm,
        clock_sync="none",
        zenoh={"listen": {"endpoints": [endpoint(pa)]}},
    )
    with Agent(sensor) as a, Agent(app) as c:
        wait_for(lambda: c.queries["q"].paths == ["W->X[s]"], 30)
        _feed(a, "s")
        t = a.now_ns() - 15_000_000
        m = wait_for(lambda: c.get("q", t), 10)
        direct = remote_get(c.session, realm, "get/s", t)
        assert np.array_equal(m.pose.position, direct.pose.position)
        assert np.array_equal(m.pose.covariance, direct.pose.covariance)
        assert isinstance(c.filters["s"], RemoteGet) and not c.remote.subs  # nothing streamed
        assert c.status()["replicas"] == {}


def test_a_fed_state_is_made_at_its_dispatch_time_and_thinned_streams_have_no_late_states():
    """``Agent.feed`` dispatches each measurement at its arrival: the state it makes carries
    that time as its host stamp (never an earlier event's time), so a thinned stream, whose
    ticks the agent completes at the scheduler's time, never gets a state stamped before a
    tick it already completed (a late state: a second message for that tick)."""
    from trackflow.distributed.thinning import Grid, demand_key
    from trackflow.distributed.wire import decode_batch, decode_state

    realm, port = f"fd{free_port()}", free_port()
    cfg = AgentConfig(
        "s",
        parse_setup({"sensors": [_sensor("s1", 2)]}),
        realm=realm,
        zenoh={"listen": {"endpoints": [endpoint(port)]}},
    )
    with Agent(cfg) as a:
        session = observer([endpoint(port)])
        try:
            states, thin = [], []
            session.declare_subscriber(
                f"trackflow/{realm}/states/s",
                lambda s: states.extend(st for _, st in decode_batch(s.payload.to_bytes())),
            )
            session.declare_subscriber(
                f"trackflow/{realm}/thin/s1/obs", lambda s: thin.append(s.payload.to_bytes())
            )
            token = session.liveliness().declare_token(
                demand_key(realm, "s1", "obs", Grid(20_000_000, 0))
            )
            wait_for(lambda: a.status().get("thin_streams", {}).get("s1"), 10)
            # Zenoh drops what is put before the subscription reached the agent (on a loaded
            # machine that can be after the demand token did): feed once it has
            wait_for(lambda: a.states.matched, 10)
            _feed(a, "s1", 40)
            wait_for(lambda: len(states) >= 40 and len(thin) >= 5, 10)
            token.undeclare()
            decoded = [decode_state(b) for b in states]
            assert all(s.host_ns >= s.stamp_ns for s in decoded), [
                (s.stamp_ns, s.host_ns) for s in decoded if s.host_ns < s.stamp_ns
            ]
            streams = a.status()["thin_streams"].get("s1", {})
            assert all(c["late"] == 0 for c in streams.values()), streams
        finally:
            session.close()


def test_a_push_query_keeps_only_its_newest_answers_and_latencies():
    """A push query's answers leave on the network: its sink keeps only the newest
    ``LONG_RUN_KEEP`` answers and latencies (a list per answer grew an agent at 100 Hz by
    0.4 MB a minute, issue 32), while the counts stay whole. (How a bounded sink drops its
    oldest entries is tests/dataflow/test_sinks_keep.py.)"""
    realm, port = f"ka{free_port()}", free_port()
    cfg = AgentConfig(
        "a",
        parse_setup(
            {
                "sensors": [_sensor("s1", 2)],
                "queries": [dict(name="q", source="W", target="X", mode="push", rate_hz=100)],
            }
        ),
        realm=realm,
        zenoh={"listen": {"endpoints": [endpoint(port)]}},
    )
    with Agent(cfg) as a:
        st = wait_for(lambda: a.queries["q"].state == "running" and a.queries["q"], 10)
        _feed(a, "s1", 80)
        wait_for(lambda: st.published >= 60, 10)
        sink = st.sink
        assert sink.stats.events_in >= 60
        stores = (sink.stats.latencies_ns, sink.wall_latencies_ns, sink.events)
        assert [getattr(x, "maxlen", None) for x in stores] == [LONG_RUN_KEEP] * 3
        assert 0 < len(sink.stats.latencies_ns) <= sink.stats.events_in


def _sensor_to(name, target):
    return {**_sensor(name, 2), "target": target}


@pytest.mark.slow
def test_a_departure_re_plans_only_the_queries_whose_plans_used_the_sensor(monkeypatch):
    """Sensors that leave cannot better a plan that does not use them: when only departures
    come, the application plans again only the queries whose paths or fallbacks held one."""
    realm = f"dp{free_port()}"
    px, py, pc = free_port(), free_port(), free_port()
    queries = [dict(name=f"q{t}", source="W", target=t.upper()) for t in "xy"]
    app = AgentConfig(
        "app",
        parse_setup({"frames": ["W", "X", "Y"], "queries": queries}),
        realm=realm,
        zenoh={
            "listen": {"endpoints": [endpoint(pc)]},
            "connect": {"endpoints": [endpoint(px), endpoint(py)]},
        },
    )
    sensors = {
        t: AgentConfig(f"a{t}", parse_setup({"sensors": [_sensor_to(f"s{t}", t.upper())]}),
                       realm=realm, zenoh={"listen": {"endpoints": [endpoint(p)]}})
        for t, p in (("x", px), ("y", py))
    }  # fmt: skip
    with Agent(app) as c, Agent(sensors["x"]):
        ay = Agent(sensors["y"]).start()
        try:
            wait_for(lambda: all(c.queries[q].state == "running" for q in ("qx", "qy")), 30)
            planned, plan = [], c.setup.plan
            monkeypatch.setattr(
                c.setup, "plan", lambda q, **kw: planned.append(q.name) or plan(q, **kw)
            )
            events_x = len(c.queries["qx"].events)
        finally:
            ay.close()
        st = wait_for(lambda: c.queries["qy"].state == "no path" and c.queries["qy"], 30)
        assert st.events[-1]["reason"] == "sensor sy of agent ay left"
        assert planned == ["qy"]  # qx's plan (sx) kept as it was
        assert c.queries["qx"].state == "running" and len(c.queries["qx"].events) == events_x
