"""Recorder -> .tfrec file -> RecordingPlayer: a record/replay round trip through a network."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from _scenario import graph, sensors

from trackflow import Pose, UncertainPose
from trackflow.dataflow import Measurement, Recorder, RecordingPlayer, plan_query
from trackflow.graph import Query
from trackflow.io import read_native

QUERY = Query("A", "M", mode="push", rate_hz=60, time_offset_s=0.0)


@pytest.fixture(autouse=True)
def _quiet_filter_resets():
    logging.getLogger("trackflow.filters").setLevel(logging.ERROR)


def _equal_arrays(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_record_then_replay_gives_the_same_outputs(tmp_path):
    plan = plan_query(graph(), QUERY)
    live = sensors(seed=5, end_s=2.0)
    net, app = plan.build(live, record=tmp_path / "out.tfrec")
    # raw recorders tapping each sensor's push output
    for name, sensor in live.items():
        rec = net.add(
            Recorder(f"raw_{name}", path=tmp_path / f"{name}.tfrec", source="x", target=name)
        )
        net.connect(sensor, rec, mode="push")
    net.run()
    first = app.arrays()
    assert len(first["t_ns"]) > 100

    # The written output file holds exactly the delivered events.
    out, report = read_native(tmp_path / "out.tfrec")
    assert (out.source, out.target) == ("A", "M")
    np.testing.assert_array_equal(out.t_ns, first["t_ns"])
    np.testing.assert_array_equal(out.position, first["position"])
    np.testing.assert_array_equal(out.quaternion, first["quaternion"])
    np.testing.assert_array_equal(out.covariance, first["covariance"])

    # Replay the raw recordings through a fresh network: identical outputs, bit for bit.
    players = {}
    for name, sensor in live.items():
        stream, _ = read_native(tmp_path / f"{name}.tfrec")
        assert len(stream) == len(sensor.t_ns)
        players[name] = RecordingPlayer.from_stream(name, stream, latency_ns=sensor.latency_ns)
    net2, app2 = plan.build(players, record=tmp_path / "replay.tfrec")
    net2.run()
    _equal_arrays(first, app2.arrays())
    replay, _ = read_native(tmp_path / "replay.tfrec")
    assert replay == out
    assert net2.stats()["app"] == net.stats()["app"] | {
        "latency_ms": net2.stats()["app"]["latency_ms"]
    }


def test_recorder_counts_times_it_cannot_write(tmp_path):
    """A result whose time is not after the previous one is delivered and kept in memory but
    counted instead of breaking the file's strict order."""
    rec = Recorder("r", path=tmp_path / "r.tfrec", source="A", target="B")
    rec.reset()  # what a network does when a run starts
    m = Measurement(10, UncertainPose(Pose([1, 2, 3], [0, 0, 0, 1]), np.eye(6) * 1e-4), 5)
    for t in (10, 20, 20, 15, 30):
        rec.push(Measurement(t, m.pose, m.origin_ns))
    rec.finish()
    stream, _ = read_native(tmp_path / "r.tfrec")
    assert stream.t_ns.tolist() == [10, 20, 30]
    assert len(rec.events) == 5
    assert rec.stats.rejections == {"not recorded: time not increasing": 2}
    # after the run, further results are appended, never silently dropped
    rec.push(Measurement(40, m.pose, m.origin_ns))
    rec.finish()
    assert read_native(tmp_path / "r.tfrec")[0].t_ns.tolist() == [10, 20, 30, 40]


def test_recorder_needs_frames_for_a_file(tmp_path):
    with pytest.raises(ValueError, match="source and target"):
        Recorder("r", path=tmp_path / "x.tfrec")


def test_queries_sharing_a_network_share_the_sensor_filters():
    """Two queries built into one network run one filter per sensor and give exactly what
    each gives in a network of its own."""
    g = graph()
    q_now = Query("A", "M", mode="push", rate_hz=60, time_offset_s=0.0, name="now")
    q_past = Query("A", "M", mode="push", rate_hz=60, time_offset_s=-0.1, name="past")
    alone = {}
    for q in (q_now, q_past):
        net, app = plan_query(g, q).build(sensors(seed=4, end_s=1.5))
        net.run()
        alone[q.name] = app.arrays()
    live = sensors(seed=4, end_s=1.5)
    net, app_now = plan_query(g, q_now).build(live, network=None, prefix="now_")
    net, app_past = plan_query(g, q_past).build(live, network=net, prefix="past_")
    filters = sorted(n for n, c in net.components.items() if c.kind == "kalman")
    assert filters == ["kf_art", "kf_cam"]
    assert net["kf_art"].role == "predictor+interpolator"
    net.run()
    _equal_arrays(alone["now"], app_now.arrays())
    _equal_arrays(alone["past"], app_past.arrays())
    # every sensor sample reached its filter once
    assert net["kf_art"].stats.events_in == net["art"].stats.events_out


_KILLED_RUN = """
import os, sys
sys.path.insert(0, {tests!r})
from _scenario import graph, sensors
from trackflow.dataflow import plan_query
from trackflow.graph import Query
n = 0
def die(m):
    global n
    n += 1
    if n == 50:
        os._exit(3)  # a crash: no finally, no close, no flush
q = Query("A", "M", mode="push", rate_hz=60, time_offset_s=0.0)
net, app = plan_query(graph(), q).build(sensors(seed=5, end_s=2.0), callback=die, record={path!r})
net.run()
"""


def test_a_killed_run_leaves_a_readable_recording(tmp_path):
    """The recorder writes each result as it arrives: a process killed in the middle of a run
    leaves every result delivered before the kill, identical to a complete run's first ones."""
    import subprocess
    import sys
    from pathlib import Path

    path = tmp_path / "killed.tfrec"
    code = _KILLED_RUN.format(tests=str(Path(__file__).parent), path=str(path))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=120)
    assert proc.returncode == 3, proc.stderr.decode()
    stream, _ = read_native(path)
    assert len(stream) == 49  # the 50th result was being delivered when the process died
    net, app = plan_query(graph(), QUERY).build(sensors(seed=5, end_s=2.0))
    net.run()
    full = app.arrays()
    np.testing.assert_array_equal(stream.t_ns, full["t_ns"][:49])
    np.testing.assert_array_equal(stream.position, full["position"][:49])
    np.testing.assert_array_equal(stream.covariance, full["covariance"][:49])
