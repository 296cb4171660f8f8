"""Filter placement: the sensor's filter publishes its states, a consumer's replica adopts
them through the wire and answers get(t) as the sensor's filter does; a consumer's plan uses
the replica as the sensor's filter node."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.dataflow import Measurement, Network, PullSink, parse_setup, plan_query
from trackflow.distributed import RemoteFilter, RemoteSource, StatePublisher, decode_state
from trackflow.graph import MotionSpec
from trackflow.math import Pose, UncertainPose, quat_exp

MOTION = MotionSpec(False, 1, 1, (1.0, 1.0))
OFFSET_NS = 30_000_000  # the sensor's known stamp offset


class _Wire:
    """Stands in for a Zenoh publisher: keeps what was put."""

    def __init__(self):
        self.sent: list[bytes] = []

    def put(self, buf: bytes) -> None:
        self.sent.append(buf)


def _sensor_side():
    """Source -> sensor filter -> state publisher, wired as the sensor's agent wires them."""
    from trackflow.dataflow import KalmanFilter

    net = Network()
    src = net.add(RemoteSource("s"))
    kf = net.add(KalmanFilter("kf_s", MOTION, stamp_offset_ns=OFFSET_NS))
    wire = _Wire()
    pub = net.add(StatePublisher("publish_s", kf, wire))
    net.connect(src, kf, mode="push")
    net.connect(kf, pub, mode="push", port=0)
    net.connect(src, pub, mode="push", port=1)
    return src, kf, wire


def _measurement(i: int, rng, jump: bool = False) -> Measurement:
    t_ns = 1_700_000_000_000_000_000 + i * 4_166_667  # Unix-time stamps at 240 Hz
    s = i / 240
    p = np.array([0.2 * np.sin(s), 0.1 * np.cos(s), 1.0]) + rng.normal(0, 5e-4, 3)
    if jump:
        p = p + 3.0
    q = quat_exp([0.0, 0.1 * np.sin(s), 0.3 * np.sin(0.5 * s)])
    return Measurement(t_ns, UncertainPose(Pose(p, q), np.diag([2.5e-7] * 3 + [1e-5] * 3)), t_ns)


def test_replica_through_the_wire_answers_as_the_sensor_filter():
    rng = np.random.default_rng(5)
    src, kf, wire = _sensor_side()
    rep = RemoteFilter("kf_s", MOTION, stamp_offset_ns=OFFSET_NS)
    checked = 0
    for i in range(240):
        src.deliver(_measurement(i, rng, jump=150 <= i < 153))
        while wire.sent:
            assert rep.adopt(decode_state(wire.sent.pop(0)))
        if i % 8 and not 150 <= i < 158:
            continue  # ask every eighth step and around the jump (Python kernels: test-min)
        t = _measurement(i, rng).t_ns - OFFSET_NS
        for tq in (t + 10_000_000, t, t - 2_000_000, t - 300_000_000):
            a, b = kf.pull(tq), rep.pull(tq)
            assert (a is None) == (b is None)
            if a is not None:
                checked += 1
                assert a.t_ns == b.t_ns and a.origin_ns == b.origin_ns
                assert np.array_equal(a.pose.position, b.pose.position)
                assert np.array_equal(a.pose.quaternion, b.pose.quaternion)
                assert np.array_equal(a.pose.covariance, b.pose.covariance)
    assert checked > 100
    assert kf.filter.stats["rejected_gate"] == 3  # the jump was gated and its states sent too
    assert rep.stats.events_in == 240


def test_replica_rejects_other_models_and_old_states_and_maps_clocks():
    rng = np.random.default_rng(6)
    src, kf, wire = _sensor_side()
    for i in range(3):
        src.deliver(_measurement(i, rng))
    states = [decode_state(b) for b in wire.sent]
    other = RemoteFilter("kf_s", MotionSpec(False, 2, 1, 1.0))
    assert not other.adopt(states[0])
    assert other.stats.rejections == {"another motion model": 1}
    rep = RemoteFilter("kf_s", MOTION)
    assert rep.adopt(states[2]) and not rep.adopt(states[1])
    assert rep.stats.rejections == {"older than the newest state": 1}
    with pytest.raises(ValueError, match="adopts filter states"):
        rep.push(_measurement(0, rng))
    # a sender clock 250 ms ahead: the state is 250 ms earlier on the receiver's clock
    ahead = RemoteFilter("kf_s", MOTION)
    ahead.adopt(states[2], offset_ns=-250_000_000)
    assert ahead.last_t == rep.last_t - 250_000_000
    a, b = ahead.pull(ahead.last_t + 5_000_000), rep.pull(rep.last_t + 5_000_000)
    # equal up to the filters' float seconds (Unix time resolves 2.4e-7 s)
    assert np.allclose(a.pose.position, b.pose.position, rtol=0, atol=1e-6)


def test_clock_uncertainty_enters_the_covariance_through_the_velocity():
    """Constant motion at v: sigma_t^2 v v^T is added to the position block (first order)."""
    v = np.array([0.5, -0.2, 0.1])
    src, kf, wire = _sensor_side()
    rep = RemoteFilter("kf_s", MOTION)
    rep_exact = RemoteFilter("kf_s", MOTION)
    sigma = 2e-3
    for i in range(240):
        t_ns = i * 4_166_667
        pose = UncertainPose(Pose(v * t_ns * 1e-9, [0, 0, 0, 1]), np.eye(6) * 1e-8)
        src.deliver(Measurement(t_ns, pose, t_ns))
        s = decode_state(wire.sent.pop())
        rep.adopt(s, sigma_s=sigma)
        rep_exact.adopt(s)
    t = rep.last_t + 5_000_000
    added = rep.pull(t).pose.covariance - rep_exact.pull(t).pose.covariance
    assert np.allclose(added[:3, :3], sigma**2 * np.outer(v, v), rtol=1e-3, atol=1e-12)
    assert np.allclose(added[3:, 3:], 0, atol=1e-12)


def test_a_consumer_plan_uses_the_replica_as_the_sensor_filter():
    setup = parse_setup(
        {
            "sensors": [
                dict(name="s", source="W", target="X", rate_hz=240, motion={"noise": [1, 1]}),
            ],
            "statics": [
                dict(name="xy", source="X", target="Y", position=[0, 0, 0.1], sigma_pos_mm=0.1)
            ],
            "queries": [dict(name="q", source="Y", target="W", mode="pull")],
        }
    )
    net = Network()
    src = net.add(RemoteSource("s"))
    rep = net.add(RemoteFilter("kf_s", setup.graph.edge("s").motion))
    _, sink = plan_query(setup.graph, setup.queries["q"]).build({"s": src}, network=net)
    assert isinstance(sink, PullSink)
    kinds = sorted(c.kind for c in net.components.values())
    assert kinds.count("remote filter") == 1 and "kalman" not in kinds  # no second filter
    assert "inversion" in kinds  # the consumer inverts and chains locally
    rng = np.random.default_rng(7)
    s_src, kf, wire = _sensor_side()
    for i in range(20):
        s_src.deliver(_measurement(i, rng))
    for b in wire.sent:
        rep.adopt(decode_state(b))
    t = rep.last_t
    got = sink.get(t)
    T_W_Y = kf.pull(t).pose.compose(setup.graph.edge("xy").value())
    want = T_W_Y.inverse()
    assert np.allclose(got.pose.position, want.position, atol=1e-12)
    assert np.allclose(got.pose.covariance, want.covariance, rtol=1e-9, atol=1e-15)
