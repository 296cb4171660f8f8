"""The relative delay of two trackers estimated while the system runs (calibration/
online_offset.py), on the real Quest 2 / UR5e recordings replayed through one network (the
scheduler every runtime uses): after 30 s it agrees with the offline `calibrate clock-offset`
result within 5 ms, with a sigma that covers the difference."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import shared_data_dir
from trackflow.calibration import (
    OnlineClockOffset,
    estimate_clock_offset,
    replay_online_offset,
    rigid_pairs,
)
from trackflow.errors import InputError
from trackflow.graph import MotionSpec, SpatialRelationshipGraph
from trackflow.io import read_stream
from trackflow.math import Pose

DATA = shared_data_dir() / "quest_ur5e" / "quest2"

pytestmark = pytest.mark.skipif(
    not DATA.is_dir(), reason=f"real recordings not found at {DATA} (set TRACKFLOW_DATA)"
)
MOTION = MotionSpec(n_dp=1, n_do=1, noise=(0.0, 5.0, 0.0, 20.0))


def _graph() -> SpatialRelationshipGraph:
    """The robot's tool and the headset on it: one body (a static hand-eye edge)."""
    g = SpatialRelationshipGraph()
    cov = np.diag([1e-6] * 3 + [1e-5] * 3)
    g.add_measured("robot", "base", "tcp", latency_s=0.01, rate_hz=30, motion=MOTION,
                   covariance=cov)  # fmt: skip
    g.add_measured("quest", "qworld", "head", latency_s=0.01, rate_hz=72, motion=MOTION,
                   covariance=cov)  # fmt: skip
    g.add_static("hand_eye", "tcp", "head", Pose.identity())
    return g


def test_rigid_pairs_are_sensors_of_one_body():
    g = _graph()
    assert rigid_pairs(g) == [("quest", "robot")]
    g.add_measured("other", "base", "elsewhere", rate_hz=30)
    assert rigid_pairs(g) == [("quest", "robot")]
    # two sensors of one frame from one world: the same body too
    g.add_measured("robot2", "base2", "tcp", rate_hz=30)
    assert ("robot", "robot2") in rigid_pairs(g) and ("quest", "robot2") in rigid_pairs(g)


def _recordings(run: str):
    """(robot or OptiTrack, headset) of one run."""
    if run == "optitrack":
        folder = DATA.parent / "optitrack_unity_example"
        return read_stream(folder / "opti.csv")[0], read_stream(folder / "unity.csv")[0]
    robot, _ = read_stream(DATA / f"robot_tcp_{run}.tum.txt")
    return robot, read_stream(DATA / f"{run}.txt", clean=True)[0]


@pytest.mark.slow
@pytest.mark.parametrize("run", ["calib", "traj1", "optitrack"])
def test_the_running_estimate_meets_the_offline_one(run):
    """Robot tool (30 Hz) or OptiTrack (120 Hz) against the headset (72 Hz), the first 32 s
    played (the OptiTrack example holds 14 s: all of it)."""
    robot, quest = _recordings(run)
    offline = estimate_clock_offset(quest, robot)  # what `calibrate clock-offset` prints
    got = replay_online_offset(quest, robot, window_s=30.0, play_s=32.0)
    assert "why" not in got, got
    diff_ms = got["offset_ms"] - offline.offset_s * 1e3
    print(f"{run}: online {got} vs offline {offline.offset_s * 1e3:.2f} ms")
    assert abs(diff_ms) < 5.0, (got, offline.offset_s)
    # the sigma covers the difference (3 sigma of the two estimates together)
    both = np.hypot(got["sigma_ms"], offline.sigma_s * 1e3)
    assert abs(diff_ms) < 3 * both + 1e-3, (diff_ms, both)
    assert got["span_s"] >= min(29.0, 0.9 * (quest.t_ns[-1] - quest.t_ns[0]) * 1e-9)


def test_too_little_data_says_why():
    est = OnlineClockOffset("a", "b")
    assert est.estimate()["why"] == "too few measurements yet"
    with pytest.raises(InputError):
        OnlineClockOffset("a", "b", window_s=0)
