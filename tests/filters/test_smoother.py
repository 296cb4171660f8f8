"""The whole-recording smoother (``smooth_filter``) against the streaming filter's history
queries, which are the reference: same answers at stored states, between them, after a
segment's newest state and across a reset; bad queries rejected with the reason."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from trackflow import Pose, UncertainPose
from trackflow.filters import MotionModel, PoseKalmanFilter, smooth_filter
from trackflow.math import use_backend


def _recording(rng, n=240, jump_at=None):
    """Hand-held-like motion at ~100 Hz with noise; optionally a 0.5 m jump that the gate
    rejects until the filter resets (a new segment)."""
    t = np.cumsum(rng.uniform(0.006, 0.014, n))
    q = Rotation.from_rotvec(np.outer(np.sin(t), [0.3, 1.0, 0.2])).as_quat()
    p = np.stack([np.sin(t), np.cos(2 * t), 0.3 * t], axis=1) + rng.normal(0, 1e-3, (n, 3))
    if jump_at is not None:
        p[jump_at:] += [0.5, 0.0, 0.0]
    c = np.broadcast_to(np.diag([1e-6] * 3 + [1e-5] * 3), (n, 6, 6)).copy()
    return t, UncertainPose._trusted(p, q, c)


def _streaming_answers(t, poses, model, queries, reset_after=10):
    kf = PoseKalmanFilter(model, history=float(t[-1] - t[0]) + 1.0, reset_after=reset_after)
    for i in range(t.size):
        kf.update_pose(float(t[i]), UncertainPose(Pose(poses.position[i], poses.quaternion[i]),
                                                  poses.covariance[i]))  # fmt: skip
    return kf, [kf.predict(float(v)) for v in queries]


def _queries(rng, t):
    """At every third state, at random times between states, at the newest state and after."""
    between = rng.uniform(t[0], t[-1], 150)
    return np.concatenate([t[::3], between, [t[-1], t[-1] + 0.02]])


@pytest.mark.parametrize("backend", ["numba", "numpy"])
@pytest.mark.parametrize("jump_at", [None, 120])
def test_smoother_equals_streaming_history_queries(rng, backend, jump_at):
    model = MotionModel(2, 1, noise=(0, 0, 3.0, 0, 2.0))
    t, poses = _recording(rng, jump_at=jump_at)
    tq = _queries(rng, t)
    rng.shuffle(tq)  # any order
    with use_backend(backend):
        kf, ref = _streaming_answers(t, poses, model, tq)
        out = smooth_filter(t, poses, model, tq)
    if jump_at is not None:
        assert kf.stats["resets"] >= 1, "the jump must start a new segment"
    for i, r in enumerate(ref):
        np.testing.assert_allclose(out.position[i], r.position, atol=1e-12)
        np.testing.assert_allclose(out.quaternion[i], r.quaternion, atol=1e-12)
        np.testing.assert_allclose(out.covariance[i], r.covariance, rtol=1e-9, atol=1e-18)


def test_smoother_uses_later_measurements(rng):
    """Smoothing is not filtering: between states, the answer is closer to the truth than the
    filtered state (it sees the measurements after it) and its covariance is smaller."""
    model = MotionModel(2, 1, noise=(0, 0, 3.0, 0, 2.0))
    t, poses = _recording(rng, n=400)
    truth = np.stack([np.sin(t), np.cos(2 * t), 0.3 * t], axis=1)
    kf = PoseKalmanFilter(model, history=0.0)
    filtered = []
    for i in range(t.size):
        kf.update_pose(float(t[i]), poses[i])
        filtered.append(kf.predict(float(t[i])))
    smoothed = smooth_filter(t, poses, model, t)
    inner = slice(50, 350)
    err_f = np.linalg.norm(np.stack([f.position for f in filtered])[inner] - truth[inner], axis=1)
    err_s = np.linalg.norm(smoothed.position[inner] - truth[inner], axis=1)
    assert np.sqrt(np.mean(err_s**2)) < 0.9 * np.sqrt(np.mean(err_f**2))
    var_f = np.array([np.trace(f.covariance[:3, :3]) for f in filtered])[inner]
    var_s = np.trace(smoothed.covariance[inner, :3, :3], axis1=1, axis2=2)
    assert np.all(var_s < var_f)


def test_smoother_rejects_bad_queries(rng):
    model = MotionModel(1, 1)
    t, poses = _recording(rng, n=30)
    with pytest.raises(ValueError, match="before the first measurement"):
        smooth_filter(t, poses, model, [t[0] - 0.01])
    with pytest.raises(ValueError, match="finite"):
        smooth_filter(t, poses, model, [np.nan])
    assert smooth_filter(t, poses, model, []).shape == (0,)
