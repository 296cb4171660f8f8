"""Bad input: clear errors or counted rejections, never a crash or a silent wrong answer."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from _fake_filter import factory
from _scenario import graph, sensors

from trackflow import Pose, UncertainPose
from trackflow.dataflow import (
    Inference,
    Inversion,
    KalmanFilter,
    Network,
    PullSink,
    Recorder,
    RecordingPlayer,
    Sampler,
    StaticPose,
    plan_query,
)
from trackflow.graph import MotionSpec, Query

COV = np.diag([1e-6] * 3 + [1e-4] * 3)


@pytest.fixture(autouse=True)
def _quiet_filter_resets():
    logging.getLogger("trackflow.filters").setLevel(logging.ERROR)


def player(t_ns, positions, name="p", quats=None):
    n = len(t_ns)
    q = np.tile([0, 0, 0, 1.0], (n, 1)) if quats is None else quats
    return RecordingPlayer(name, np.asarray(t_ns, np.int64), positions, q, COV, latency_ns=0)


def recorder_net(p: RecordingPlayer):
    net = Network()
    net.add(p)
    rec = net.add(Recorder("rec"))
    net.connect(p, rec)
    return net, rec


def test_unknown_frames_and_missing_paths_are_errors():
    with pytest.raises(ValueError, match="unknown frame 'Q'"):
        plan_query(graph(), Query("A", "Q"))
    g = graph()
    g.add_frame("island")
    with pytest.raises(ValueError, match="no path from frame 'A' to frame 'island'"):
        plan_query(g, Query("A", "island"))
    plan = plan_query(graph(), Query("A", "M"))
    with pytest.raises(ValueError, match="no recording or sensor given for measured edge 'cam'"):
        plan.build({"art": sensors()["art"]})


def test_cycles_in_the_network_are_refused():
    net = Network()
    a = net.add(Inversion("a"))
    b = net.add(Inversion("b"))
    net.connect(a, b, mode="push")
    with pytest.raises(ValueError, match="would create a cycle"):
        net.connect(b, a, mode="push")
    inf = net.add(Inference("inf"))
    net.connect(a, inf)
    with pytest.raises(ValueError, match="would create a cycle"):
        net.connect(inf, a)
    with pytest.raises(ValueError, match="duplicate component name"):
        net.add(Inversion("a"))
    s = net.add(StaticPose("s", UncertainPose(Pose.identity(), COV)))
    with pytest.raises(ValueError, match="no matching ports"):
        net.connect(s, net.add(Recorder("r")))
    other = Inversion("outsider")
    with pytest.raises(ValueError, match="not part of this network"):
        net.connect(a, other)


def test_nan_poses_and_backwards_timestamps_are_counted_rejections():
    t = np.array([0, 10, 20, 15, 30, 30, 40, 50]) * 1_000_000
    pos = np.zeros((8, 3))
    pos[2] = np.nan
    quats = np.tile([0, 0, 0, 1.0], (8, 1))
    quats[6] = [0, 0, 0, 2.0]  # not a unit quaternion
    p = player(t, pos, quats=quats)
    net, rec = recorder_net(p)
    net.run()
    # 20 ms is NaN (rejected), so 15 ms follows 10 ms and is accepted; the second 30 ms is a
    # repeat; 40 ms carries a non-unit quaternion.
    assert p.stats.rejections == {
        "non-finite pose": 1,
        "timestamp backwards": 1,
        "non-unit quaternion": 1,
    }
    got = [m.t_ns for m in rec.events]
    assert got == sorted(set(got))  # strictly increasing: nothing went backwards
    assert all(np.isfinite(m.pose.position).all() for m in rec.events)
    assert p.stats.events_in == 8
    assert len(got) + p.stats.rejected == 8


def test_backwards_timestamps_after_valid_ones():
    t = np.array([0, 10, 20, 15, 30, 30]) * 1_000_000
    p = player(t, np.zeros((6, 3)))
    net, rec = recorder_net(p)
    net.run()
    assert p.stats.rejections == {"timestamp backwards": 2}
    assert [m.t_ns // 1_000_000 for m in rec.events] == [0, 10, 20, 30]


def test_a_sensor_that_stops_gives_counted_rejections_not_stale_answers():
    q = Query("A", "M", mode="push", rate_hz=60, time_offset_s=0.0)
    plan = plan_query(graph(), q)
    net, rec = plan.build(sensors(end_s=3.0, art_end_s=1.0), filter_factory=factory)
    net.run()
    stats = net.stats()
    assert stats["kf_art"]["rejections"].get("stale", 0) > 50
    t_last = max(m.t_ns for m in rec.events)
    # max_extrapolation (0.5 s) after the tracker's last arrival, then nothing is delivered.
    assert t_last <= int((1.0 + 0.02 + 0.5) * 1e9)
    assert stats["sampler"]["rejections"]["no result"] > 50


def test_filter_rejections_are_counted():
    class Refuses:
        def __init__(self, motion, history_s):
            pass

        def update_pose(self, t, z):
            return False

        def predict(self, t):
            raise AssertionError("never asked")

    net = Network()
    p = net.add(player(np.arange(5) * 10_000_000, np.zeros((5, 3))))
    kf = net.add(KalmanFilter("kf", MotionSpec(), filter_factory=Refuses))
    sink = net.add(PullSink("app"))
    net.connect(p, kf)
    net.connect(kf, sink)
    net.run()
    assert kf.stats.rejections == {"filter rejected update": 5}
    assert sink.get(10_000_000) is None
    assert kf.stats.rejections["no data yet"] == 1
    assert sink.stats.rejections == {"no result": 1}


def test_sampler_and_network_argument_errors():
    with pytest.raises(ValueError, match="rate_hz"):
        Sampler("s", 0.0)
    with pytest.raises(ValueError, match="no sensor or recording"):
        Network().run()
    with pytest.raises(ValueError, match="integer"):
        RecordingPlayer("p", [0.0, 1.0], np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)), COV)
