"""``run_inertial(query_t=...)``: predictions asked at any time, from the data up to then."""

from __future__ import annotations

import numpy as np

from trackflow.filters import ImuNoise, InertialModel, run_inertial
from trackflow.math import quat_angle, quat_exp

RATE = 200.0


def _recording(seed=0, seconds=6.0, pose_every=10):
    """A body turning and moving smoothly, its IMU at 200 Hz and poses at 20 Hz (z up)."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * RATE)) / RATE
    w = np.stack([0.8 * np.sin(1.3 * t), 0.5 * np.cos(0.9 * t), 0.3 + 0 * t], 1)
    rv = np.cumsum(w, axis=0) / RATE  # small-angle stand-in is fine: poses are measurements
    q = quat_exp(rv)
    p = np.stack([0.3 * np.sin(t), 0.2 * np.cos(0.7 * t), 0.05 * t], 1)
    gyro = w + rng.normal(scale=0.01, size=w.shape)
    accel = np.tile([0.0, 0.0, 9.80665], (t.shape[0], 1)) + rng.normal(scale=0.05, size=w.shape)
    k = np.arange(0, t.shape[0], pose_every)
    return t, gyro, accel, t[k], p[k], q[k]


C = np.diag([1e-6] * 3 + [1e-5] * 3)
MODEL = InertialModel(mode="gyro", noise=ImuNoise(gyro=5e-3, accel=1.0))
H = (0.0, 0.05)


def test_queries_at_pose_times_are_the_pose_predictions():
    ti, w, a, tp, p, q = _recording()
    at_poses = run_inertial(ti, w, a, tp, p, q, C, MODEL, H)
    at_queries = run_inertial(ti, w, a, tp, p, q, C, MODEL, H, query_t=tp)
    for h in H:
        (pp, pq), (qp, qq) = at_poses.predictions[h], at_queries.predictions[h]
        ok = np.isfinite(pp[:, 0])
        assert np.count_nonzero(ok) == tp.shape[0] - 1  # the first pose starts the filter
        np.testing.assert_allclose(qp[ok], pp[ok], atol=1e-12)
        assert np.all(quat_angle(qq[ok], pq[ok]) < 1e-9)
    # a query at the first pose already has the filter's initial state
    assert np.isfinite(at_queries.predictions[0.05][0][0]).all()


def test_queries_use_exactly_the_data_up_to_their_time():
    ti, w, a, tp, p, q = _recording(1)
    tq = np.arange(0.5, 5.5, 0.0137)  # between IMU samples and poses
    ref = run_inertial(ti, w, a, tp, p, q, C, MODEL, H, query_t=tq)
    i = 150
    # changing IMU samples and poses after the query time leaves its prediction unchanged
    w2, p2 = w.copy(), p.copy()
    w2[ti > tq[i]] += 0.5
    p2[tp > tq[i]] += 0.1
    res = run_inertial(ti, w2, a, tp, p2, q, C, MODEL, H, query_t=tq)
    for h in H:
        np.testing.assert_allclose(res.predictions[h][0][: i + 1], ref.predictions[h][0][: i + 1])
        assert not np.allclose(res.predictions[h][0][i + 20], ref.predictions[h][0][i + 20])
    # a query between IMU samples predicts from the last one, over the extra time (the
    # sample held, as the default prediction does)
    last = ti[np.searchsorted(ti, tq[i], side="right") - 1]
    at_last = run_inertial(ti, w, a, tp, p, q, C, MODEL, (0.05 + tq[i] - last,),
                           query_t=[last])  # fmt: skip
    np.testing.assert_allclose(
        at_last.predictions[0.05 + tq[i] - last][0][0], ref.predictions[0.05][0][i], atol=1e-12
    )
