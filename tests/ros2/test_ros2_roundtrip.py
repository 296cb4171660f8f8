"""A round trip through ROS 2 topics with real processes on loopback: ``trackflow run`` (a
process of its own) reads a PoseStamped topic and publishes its answers as
PoseWithCovarianceStamped; a second trackflow run reads that topic as its sensor's input. The
second one's measurements are the first one's answers: the same stamps, positions and
rotations, and covariances equal after ROS's convention and back. The first run's recorded
answers, converted to an MCAP bag (/tf and PoseWithCovarianceStamped), are read back whole by
rosbags."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (pip install .[distributed])")
pytest.importorskip("rosbags", reason="rosbags is not installed (pip install .[ros])")

from _ros2live import attachment, key, pose_message

from _rosbag_read import assert_bag_holds, bag_messages
from trackflow.cli.main import main
from trackflow.dataflow import parse_setup
from trackflow.io import read_stream
from trackflow.math import quat_exp
from trackflow.trackers import run_live

pytestmark = pytest.mark.slow

SRC = Path(__file__).resolve().parents[2] / "src"
SENSOR = {"name": "head", "source": "room", "target": "head", "rate_hz": 100,
          "sigma_pos_mm": 0.5, "sigma_ori_deg": 0.2,
          "motion": {"n_dp": 1, "n_do": 1, "noise": [0.0, 3.0, 0.0, 10.0]}}  # fmt: skip


def test_trackflow_to_trackflow_through_ros2(tmp_path, router):
    ep = router.endpoint
    a_setup = {
        "sensors": [dict(SENSOR, input={"ros2": {"topic": "/mocap/head", "connect": ep,
                                                 "node": "trackflow_a"}})],
        "queries": [{"name": "q", "source": "room", "target": "head", "mode": "push",
                     "rate_hz": 50, "ros2": {"topic": "/trackflow/head", "connect": ep,
                                             "node": "trackflow_a"}}],
    }  # fmt: skip
    (tmp_path / "a.yaml").write_text(yaml.safe_dump(a_setup, sort_keys=False))
    b_setup = parse_setup(
        {
            "sensors": [
                dict(
                    SENSOR,
                    name="relay",
                    rate_hz=50,
                    input={
                        "ros2": {
                            "topic": "/trackflow/head",
                            "type": "PoseWithCovarianceStamped",
                            "frame_id": "room",
                            "connect": ep,
                            "node": "trackflow_b",
                        }
                    },
                )
            ],
            "queries": [
                {"name": "r", "source": "room", "target": "head", "mode": "push", "rate_hz": 20}
            ],
        }  # fmt: skip
    )
    stop_b, results = threading.Event(), []
    b = threading.Thread(
        target=lambda: results.append(run_live(b_setup, record=tmp_path / "b.tfrec", stop=stop_b)),
        daemon=True,
    )
    b.start()
    a = None
    try:
        router.wait_token("/MS/%/%/trackflow_b/%trackflow%head/")
        env = {**os.environ, "PYTHONPATH": str(SRC)}
        a = subprocess.Popen(
            [sys.executable, "-m", "trackflow.cli.main", "run", str(tmp_path / "a.yaml"),
             "--record", str(tmp_path / "a.tfrec"), "--json", "--quiet"],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        router.wait_token("/MS/%/%/trackflow_a/%mocap%head/")
        pub = router.publisher(key(0, "/mocap/head", "geometry_msgs/msg/PoseStamped"))
        for i in range(1, 301):
            t = i * 0.01
            p = (0.2 * np.sin(t), 0.1 * np.cos(t), 1.0 + 0.05 * t)
            q = tuple(float(v) for v in quat_exp(np.array([0.0, 0.1 * np.sin(t), 0.3 * t])))
            now = time.time_ns()
            pub.put(pose_message("geometry_msgs/msg/PoseStamped", now, "room", p, q),
                    attachment=attachment(i, now, bytes(16)))  # fmt: skip
            time.sleep(0.01)
        pub.undeclare()
        time.sleep(0.5)
        a.send_signal(signal.SIGTERM)
        out, err = a.communicate(timeout=120)
        assert a.returncode == 0, err[-2000:]
        summary = json.loads(out)
        time.sleep(0.5)
    finally:
        if a is not None and a.poll() is None:
            a.kill()
            a.communicate()
        stop_b.set()
        b.join(60)
    assert summary["sensors"]["head"]["accepted"] == 300
    published = summary["ros2"]["q"]["published"]
    assert published == summary["answers"] > 50
    (res_b,) = results
    assert res_b.statuses["relay"]["rejections"] == {}
    answers, _ = read_stream(tmp_path / "a.tfrec")
    relayed, _ = read_stream(tmp_path / "b.relay.tfrec")
    assert len(relayed.t_ns) == len(answers.t_ns) == published
    np.testing.assert_array_equal(relayed.t_ns, answers.t_ns)
    np.testing.assert_array_equal(relayed.position, answers.position)
    np.testing.assert_allclose(
        relayed.quaternion, answers.quaternion, rtol=0, atol=1e-15
    )  # re-normalised: 1 ulp
    # ROS's convention and back: equal to rounding, relative to each matrix's largest entry
    err = np.abs(relayed.covariance - answers.covariance).max(axis=(1, 2))
    assert np.all(err <= 1e-12 * np.abs(answers.covariance).max(axis=(1, 2)))
    _answers_read_back_from_mcap_bags(answers, tmp_path / "a.tfrec")


def _answers_read_back_from_mcap_bags(answers, record) -> None:
    """The run's recorded answers through ``trackflow convert ... .mcap``: rosbags reads every
    message, on /tf (frames, stamps, pose) and as PoseWithCovarianceStamped (with the
    covariance in ROS's convention)."""
    for msgtype in ("TFMessage", "PoseWithCovarianceStamped"):
        out = record.parent / f"answers_{msgtype}.mcap"
        assert main(["convert", str(record), str(out), "--msgtype", msgtype, "--quiet"]) == 0
        assert_bag_holds(bag_messages(out.with_suffix("")), answers, msgtype)
