"""A pose Kalman filter replicated by adopting another copy's states answers exactly as it."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.filters import FilterSnapshot, MotionModel, PoseKalmanFilter
from trackflow.math import Pose, UncertainPose, quat_exp


def _measurements(n, rng, jump_at=None):
    for i in range(n):
        t = i / 100
        p = [0.3 * np.sin(t), 0.1 * np.cos(2 * t), 1.0] + rng.normal(0, 1e-3, 3)
        if jump_at is not None and i >= jump_at:
            p = p + 5.0  # far outside the gate: gated, then a reset after reset_after
        q = quat_exp([0.1 * np.sin(t), 0.0, 0.4 * np.sin(0.7 * t)])
        yield t, UncertainPose(Pose(p, q), np.diag([1e-6] * 3 + [1e-5] * 3))


@pytest.mark.parametrize(
    "n_dp,n_do,formulation",
    [(1, 1, "error_state"), (1, 1, "additive"), (2, 1, "error_state"), (0, 0, "error_state")],
)
def test_replica_answers_bit_identically(n_dp, n_do, formulation):
    rng = np.random.default_rng(3)
    model = MotionModel(n_dp, n_do)
    src = PoseKalmanFilter(model, history=0.3, formulation=formulation)
    rep = PoseKalmanFilter(model, history=0.3, formulation=formulation)
    adopted, last = 0, None
    for i, (t, z) in enumerate(_measurements(150, rng, jump_at=110)):
        src.update_pose(t, z)
        snap = src.snapshot()
        if snap.x is last:
            continue  # nothing new (an invalid measurement)
        last = snap.x  # a new state, also after a gated measurement (a pure prediction)
        assert rep.adopt(snap)
        adopted += 1
        if i % 3:
            continue  # ask every third step (the kernels in Python are slow under test-min)
        for tq in (t + 0.013, t, t - 0.004, t - 0.1, t - 0.28):
            if tq >= 0.3:  # the same states: the same answers to the last bit
                a, b = src.predict(tq), rep.predict(tq)
                assert np.array_equal(a.position, b.position)
                assert np.array_equal(a.quaternion, b.quaternion)
                assert np.array_equal(a.covariance, b.covariance)
    assert src.stats["resets"] >= 1 and src.stats["rejected_gate"] >= 10  # gated, then reset
    assert rep.stats["updates"] == adopted == 150


def test_snapshot_and_adopt_contract():
    model = MotionModel(1, 1)
    f = PoseKalmanFilter(model)
    with pytest.raises(ValueError, match="no measurement"):
        f.snapshot()
    z = UncertainPose(Pose([0, 0, 1], [0, 0, 0, 1]), np.eye(6) * 1e-6)
    f.update_pose(1.0, z)
    s = f.snapshot()
    assert s.segment_start and s.t == 1.0  # the first state starts a segment
    f.update_pose(1.01, z)
    assert not f.snapshot().segment_start
    r = PoseKalmanFilter(model)
    assert r.adopt(f.snapshot())
    assert not r.adopt(s)  # older than the newest state: refused, counted
    assert r.stats["rejected_old"] == 1
    assert r.adopt(f.snapshot())  # the same time again replaces the newest state
    with pytest.raises(ValueError, match="does not fit"):
        r.adopt(FilterSnapshot(2.0, np.zeros(7), np.eye(6), False))
