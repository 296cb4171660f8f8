"""A small synthetic tracker + camera world for dataflow tests (known ground truth)."""

from __future__ import annotations

import numpy as np

from trackflow import Pose
from trackflow.dataflow import SimulatedSensor
from trackflow.graph import MotionSpec, SpatialRelationshipGraph
from trackflow.math import quat_exp

T_T_C = Pose([0.03, -0.05, 0.02], quat_exp(np.array([0.1, 0.2, 0.05])))
T_A_M = Pose([0.0, 0.0, 1.2], quat_exp(np.array([0.0, 3.0, 0.0])))
MOTION = MotionSpec(n_dp=1, n_do=1, noise=(1.0, 3.0))


def tracker_truth(t):
    """Target swinging in yaw (+-40 deg at 0.5 Hz) and sliding sideways, looking at M."""
    t = np.asarray(t, dtype=float)
    yaw = np.radians(40) * np.sin(2 * np.pi * 0.5 * t)
    axis = np.zeros(t.shape + (3,))
    axis[..., 1] = yaw
    pos = np.zeros(t.shape + (3,))
    pos[..., 0] = 0.1 * np.sin(2 * np.pi * 0.3 * t)
    pos[..., 2] = 0.5
    return Pose(pos, quat_exp(axis))


def camera_truth(t):
    return (tracker_truth(t) @ T_T_C).inverse() @ T_A_M


def graph(stamp_offset_s: float = 0.0, cam_rate: float = 30.0) -> SpatialRelationshipGraph:
    g = SpatialRelationshipGraph()
    g.add_measured(
        "art",
        "A",
        "T",
        latency_s=0.02,
        rate_hz=60,
        motion=MOTION,
        covariance=np.diag([1e-8] * 3 + [1e-7] * 3),
    )
    g.add_static("mount", "T", "C", T_T_C, np.diag([1e-10] * 6))
    g.add_measured(
        "cam",
        "C",
        "M",
        latency_s=0.05,
        rate_hz=cam_rate,
        motion=MOTION,
        covariance=np.diag([1e-6] * 3 + [1e-4] * 3),
        stamp_offset_s=stamp_offset_s,
    )
    return g


def sensors(seed=1, end_s=4.0, stamp_offset_s=0.0, noise=True, art_end_s=None):
    rng = np.random.default_rng(seed)
    k = 1.0 if noise else 0.01  # nearly noise-free, with a non-singular covariance
    art = SimulatedSensor(
        "art",
        tracker_truth,
        rate_hz=60,
        latency_s=0.02,
        sigma_pos=1e-4 * k,
        sigma_ori=3e-4 * k,
        rng=rng,
        start_s=0.0,
        end_s=art_end_s or end_s,
    )
    cam = SimulatedSensor(
        "cam",
        camera_truth,
        rate_hz=30,
        latency_s=0.05,
        sigma_pos=1e-3 * k,
        sigma_ori=1e-2 * k,
        rng=rng,
        start_s=0.007,
        end_s=end_s,
        stamp_offset_s=stamp_offset_s,
    )
    return {"art": art, "cam": cam}
