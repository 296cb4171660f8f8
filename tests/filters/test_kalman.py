"""Pose Kalman filter: consistency (NEES/NIS), least squares, time handling, robustness."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from trackflow import Pose, UncertainPose
from trackflow.filters import MotionModel, PoseKalmanFilter, chi2_gate, run_filter
from trackflow.filters.gating import chi2_survival
from trackflow.math import quat_exp, quat_multiply, use_backend


def random_spd(rng, n, scale):
    a = rng.normal(size=(n, n))
    return scale * (a @ a.T / n + 0.2 * np.eye(n))


def simulate(model, n_steps, dt, rng, rate=1.0):
    """Truth trajectory drawn from the motion model itself: x_{k+1} = f(x_k) [+] w_k."""
    x = model.initial_state()
    npl = model.n_dp + 1
    x[3 * npl : 3 * npl + 4] = Rotation.random(random_state=rng).as_quat()
    x[3:9] = rng.normal(0.0, rate, 6)  # velocity, acceleration
    x[3 * npl + 4 :] = rng.normal(0.0, rate, 3 * model.n_do)
    L = np.linalg.cholesky(model.process_noise(dt))
    out = [x]
    for _ in range(n_steps - 1):
        x, _ = model.transition(x, dt)
        x = model.retract(x, L @ rng.normal(size=L.shape[0]))
        out.append(x)
    return np.array(out)


def measure(x, npl, C, rng):
    e = np.linalg.cholesky(C) @ rng.normal(size=6)
    p = x[:3] + e[:3]
    q = quat_multiply(x[3 * npl : 3 * npl + 4], quat_exp(e[3:]))
    return UncertainPose(Pose(p, q), C)


def test_nees_and_nis_inside_95_percent_band():
    """50 seeded runs on motion drawn from the model: average NEES/NIS per step in the band."""
    model = MotionModel(2, 1, noise=(0.0, 0.0, 3.0, 0.0, 2.0))
    runs, steps, dt, burn = 50, 150, 0.01, 30
    n_x, n_z = model.error_size, 6
    nees = np.zeros((runs, steps))
    nis = np.zeros((runs, steps))
    for r in range(runs):
        rng = np.random.default_rng(1000 + r)
        C = random_spd(rng, 6, 1.0)
        C[:3, :3] *= 1e-6
        C[3:, 3:] *= 1e-4
        C[:3, 3:] *= 1e-5
        C[3:, :3] *= 1e-5
        truth = simulate(model, steps, dt, rng)
        kf = PoseKalmanFilter(model, gate_probability=None)
        for k in range(steps):
            kf.update_pose(k * dt, measure(truth[k], 3, C, rng))
            x, P = kf.state
            e = model.local(truth[k], x)
            nees[r, k] = e @ np.linalg.solve(P, e)
            nis[r, k] = kf.nis
    for name, val, dof in (("NEES", nees, n_x), ("NIS", nis, n_z)):
        avg = val[:, burn:].mean(axis=0)
        lo, hi = chi2.ppf([0.025, 0.975], runs * dof) / runs
        inside = np.mean((avg > lo) & (avg < hi))
        assert inside > 0.85, f"{name}: only {inside:.0%} of steps in [{lo:.2f}, {hi:.2f}]"
        assert abs(avg.mean() / dof - 1.0) < 0.1, f"{name} mean {avg.mean():.2f} vs {dof}"


def test_static_model_is_batch_least_squares(rng):
    """Recursive estimate and covariance equal the batch weighted least squares to 1e-9."""
    n = 40
    p0 = np.array([0.3, -1.2, 2.0])
    zs, Cs = [], []
    kf = PoseKalmanFilter(MotionModel.static(), gate_probability=None)
    for k in range(n):
        C = np.zeros((6, 6))
        blk = random_spd(rng, 4, 1e-4)  # (px, py, pz, rz): correlated
        idx = [0, 1, 2, 5]
        C[np.ix_(idx, idx)] = blk
        C[3:5, 3:5] = random_spd(rng, 2, 1e-4)
        e = np.linalg.cholesky(C[np.ix_(idx, idx)]) @ rng.normal(size=4)
        z = np.array([*(p0 + e[:3]), 0.0, 0.0, 0.8 + e[3]])
        q = Rotation.from_rotvec(z[3:]).as_quat()
        kf.update_pose(float(k), UncertainPose(Pose(z[:3], q), C))
        zs.append(z)
        Cs.append(C)
    W = [np.linalg.inv(C) for C in Cs]
    P = np.linalg.inv(sum(W))
    xhat = P @ sum(w @ z for w, z in zip(W, zs, strict=True))
    est = kf.predict(float(n))
    angle = Rotation.from_quat(est.quaternion).as_rotvec()
    np.testing.assert_allclose(est.position, xhat[:3], rtol=0, atol=1e-9)
    np.testing.assert_allclose(angle, xhat[3:], rtol=0, atol=1e-9)
    np.testing.assert_allclose(est.covariance / np.abs(P).max(), P / np.abs(P).max(), atol=1e-9)
    # position-only measurements with full 3x3 covariances
    kf = PoseKalmanFilter(MotionModel(0, -1, noise=(0.0,)), gate_probability=None)
    zs = rng.normal(size=(30, 3))
    Cs = [random_spd(rng, 3, 1e-3) for _ in range(30)]
    for k, (z, C) in enumerate(zip(zs, Cs, strict=True)):
        kf.update_position(k * 0.1, z, C)
    W = [np.linalg.inv(C) for C in Cs]
    P = np.linalg.inv(sum(W))
    xhat = P @ sum(w @ z for w, z in zip(W, zs, strict=True))
    est = kf.predict(5.0)
    np.testing.assert_allclose(est.position, xhat, atol=1e-9)
    np.testing.assert_allclose(est.covariance[:3, :3] / P.max(), P / P.max(), atol=1e-9)


def mixed_stream(rng, n=120):
    """Pose at 100 Hz, gyro in between, velocity now and then: (t, kind, value, cov)."""
    out = []
    for k in range(n):
        t = 0.01 * k
        q = (
            Rotation.from_rotvec([0.0, 0.0, 0.1]) * Rotation.from_rotvec([0.2 * t, 0.5 * t, 0])
        ).as_quat()
        p = np.array([np.sin(t), 0.5 * t, 0.1 * t * t]) + rng.normal(0, 1e-3, 3)
        out.append((t, "pose", UncertainPose(Pose(p, q), np.diag([1e-6] * 3 + [1e-5] * 3))))
        out.append((t + 0.004, "gyro", rng.normal([0.2, 0.5, 0.0], 0.01), np.eye(3) * 1e-4))
        if k % 7 == 3:
            v = [np.cos(t + 0.007), 0.5, 0.2 * (t + 0.007)]
            out.append((t + 0.007, "vel", rng.normal(v, 0.05), np.eye(3) * 3e-3))
    return out


def feed(kf, item):
    t, kind, v = item[0], item[1], item[2]
    if kind == "pose":
        return kf.update_pose(t, v)
    if kind == "gyro":
        return kf.update_angular_velocity(t, v, item[3])
    return kf.update_velocity(t, v, item[3])


def test_out_of_order_equals_in_order(rng):
    stream = mixed_stream(rng)
    model = MotionModel(2, 1, noise=(0, 0, 5.0, 0, 3.0))
    a = PoseKalmanFilter(model, history=0.3)
    for item in stream:
        feed(a, item)
    # deliver with random latency of up to 0.1 s: arrival order != time order
    arrival = np.array([it[0] for it in stream]) + rng.uniform(0, 0.1, len(stream))
    b = PoseKalmanFilter(model, history=0.3)
    for i in np.argsort(arrival):
        feed(b, stream[i])
    assert b.stats["out_of_order"] > 50
    assert b.stats["rejected_old"] == 0
    xa, Pa = a.state
    xb, Pb = b.state
    np.testing.assert_allclose(xb, xa, rtol=0, atol=1e-12)
    np.testing.assert_allclose(Pb, Pa, rtol=1e-12, atol=1e-18)
    for t in (1.0, 1.1, 1.19, 1.25, 1.5):
        pa, pb = a.predict(t), b.predict(t)
        np.testing.assert_allclose(pb.position, pa.position, atol=1e-12)
        np.testing.assert_allclose(pb.covariance, pa.covariance, rtol=1e-10, atol=1e-18)
    sa, sb = a.stats, b.stats
    assert (sa["updates"], sa["rejected_gate"]) == (sb["updates"], sb["rejected_gate"])
    assert sa["rejected_gate"] < 5


def test_too_old_measurements_are_rejected_and_counted():
    kf = PoseKalmanFilter(MotionModel(1, 1), history=0.2)
    C = np.diag([1e-6] * 3 + [1e-5] * 3)
    for k in range(50):
        assert kf.update_pose(k * 0.01, UncertainPose(Pose([0.01 * k, 0, 0], [0, 0, 0, 1]), C))
    before = kf.state
    assert not kf.update_pose(0.1, UncertainPose(Pose([5.0, 0, 0], [0, 0, 0, 1]), C))
    assert kf.stats["rejected_old"] == 1
    np.testing.assert_array_equal(kf.state[0], before[0])
    with pytest.raises(ValueError, match="older than the stored history"):
        kf.predict(0.05)


def test_future_prediction_grows_and_past_is_smoothed(rng):
    model = MotionModel(2, 1, noise=(0, 0, 2.0, 0, 1.0))
    kf = PoseKalmanFilter(model, history=1.0)
    C = np.diag([1e-6] * 3 + [1e-5] * 3)
    for k in range(100):
        t = 0.02 * k
        q = Rotation.from_rotvec([0, 0, 0.5 * t]).as_quat()
        kf.update_pose(t, UncertainPose(Pose([t, 0, 0] + rng.normal(0, 1e-3, 3), q), C))
    tr = [np.trace(kf.predict(kf.time + h).covariance) for h in (0, 0.05, 0.1, 0.5)]
    assert np.all(np.diff(tr) > 0)
    # the pose-rows-only prediction equals the pose block of the full state prediction
    x, P = kf.predict_state(kf.time + 0.1)
    fast = kf.predict(kf.time + 0.1)
    np.testing.assert_allclose(fast.position, x[:3], atol=1e-15)
    sel = [0, 1, 2, 9, 10, 11]
    np.testing.assert_allclose(fast.covariance, P[np.ix_(sel, sel)], rtol=1e-12, atol=1e-20)
    # between two stored measurements: close to the truth and at most as uncertain as the
    # forward prediction from the earlier state
    t = 1.51
    s = kf.predict(t)
    assert np.linalg.norm(s.position - [t, 0, 0]) < 3e-3
    ang = Rotation.from_quat(s.quaternion).as_rotvec()
    assert abs(ang[2] - 0.5 * t) < 5e-3
    x_prev, P_prev = kf.predict_state(1.50)  # the stored state at 1.50 smoothed by 1.52
    forward = model.transition(x_prev, 0.01)[0]
    assert np.linalg.norm(forward[:3] - s.position) < 1e-3
    assert np.all(np.diag(s.covariance) <= np.diag(kf.predict(kf.time + 0.01).covariance))
    # smoothing is continuous across a stored measurement time
    a, b = kf.predict(1.54 - 1e-9), kf.predict(1.54)
    np.testing.assert_allclose(a.position, b.position, atol=1e-6)


def test_gating_rejects_outliers_and_counts():
    kf = PoseKalmanFilter(MotionModel(1, 1), gate_probability=0.999)
    C = np.diag([1e-6] * 3 + [1e-5] * 3)
    rng = np.random.default_rng(5)
    for k in range(30):
        kf.update_pose(k * 0.01, UncertainPose(Pose(rng.normal(0, 1e-3, 3), [0, 0, 0, 1]), C))
    assert not kf.update_pose(0.30, UncertainPose(Pose([0.05, 0, 0], [0, 0, 0, 1]), C))
    assert kf.stats["rejected_gate"] == 1
    assert np.linalg.norm(kf.predict(0.3).position) < 5e-3


def test_quaternion_sign_is_irrelevant(rng):
    model = MotionModel(1, 1)
    a, b = PoseKalmanFilter(model), PoseKalmanFilter(model)
    C = np.diag([1e-6] * 3 + [1e-5] * 3)
    for k in range(40):
        q = Rotation.from_rotvec([0.1 * k, 0, 0.05]).as_quat()
        p = rng.normal(0, 1e-3, 3)
        a.update_pose(k * 0.01, UncertainPose(Pose(p, q), C))
        b.update_pose(k * 0.01, UncertainPose(Pose(p, -q if k % 3 == 0 else q), C))
    pa, pb = a.predict(0.5), b.predict(0.5)
    assert abs(abs(pa.quaternion @ pb.quaternion) - 1) < 1e-12
    np.testing.assert_allclose(pa.covariance, pb.covariance, atol=1e-15)
    assert b.stats["rejected_gate"] == 0


def test_lost_filter_resets_and_logs(caplog):
    kf = PoseKalmanFilter(MotionModel(1, 1), reset_after=5)
    C = np.diag([1e-6] * 3 + [1e-5] * 3)
    for k in range(20):
        kf.update_pose(k * 0.01, UncertainPose(Pose([0, 0, 0], [0, 0, 0, 1]), C))
    with caplog.at_level(logging.WARNING, logger="trackflow.filters"):
        for k in range(20, 40):  # the object jumps by 1 m (re-identification)
            kf.update_pose(k * 0.01, UncertainPose(Pose([1.0, 0, 0], [0, 0, 0, 1]), C))
    assert kf.stats["resets"] == 1
    assert kf.stats["rejected_gate"] == 5
    assert "reset" in caplog.text
    assert np.linalg.norm(kf.predict(0.4).position - [1, 0, 0]) < 1e-3


def test_angular_velocity_limit_keeps_covariance_valid():
    kf = PoseKalmanFilter(MotionModel(0, 1, noise=(0.1, 0.0, 50.0)), max_angular_velocity=2.0)
    C = np.diag([1e-6] * 3 + [1e-6] * 3)
    for k in range(50):
        q = Rotation.from_rotvec([0, 0, 10.0 * k * 0.01]).as_quat()  # 10 rad/s
        kf.update_pose(k * 0.01, UncertainPose(Pose([0, 0, 0], q), C))
    x, P = kf.state
    assert np.linalg.norm(x[7:10]) <= 2.0 + 1e-12
    np.testing.assert_array_equal(P, P.T)
    assert np.linalg.eigvalsh(P).min() > 0


def test_sensor_fusion_of_velocity_and_gyro_reduces_uncertainty(rng):
    model = MotionModel(1, 1, noise=(0, 1.0, 0, 1.0))
    a, b = PoseKalmanFilter(model), PoseKalmanFilter(model)
    for item in mixed_stream(rng, 60):
        if item[1] == "pose":
            feed(a, item)
        feed(b, item)
    ca, cb = a.predict(0.6).covariance, b.predict(0.6).covariance
    assert np.trace(cb[3:, 3:]) < np.trace(ca[3:, 3:])
    _, Pb = b.state
    _, Pa = a.state
    assert Pb[9, 9] < 0.5 * Pa[9, 9]  # angular velocity variance
    xb, Pb = b.state
    sigma = np.sqrt(np.diag(Pb)[9:12])
    assert np.all(np.abs(xb[10:13] - [0.2, 0.5, 0.0]) < 4 * sigma), (xb[10:13], sigma)


def test_measurement_kinds_need_matching_derivatives():
    kf = PoseKalmanFilter(MotionModel(0, 0))
    with pytest.raises(ValueError, match="velocity"):
        kf.update_velocity(0.0, np.zeros(3), np.eye(3))
    with pytest.raises(ValueError, match="angular velocity"):
        kf.update_angular_velocity(0.0, np.zeros(3), np.eye(3))
    with pytest.raises(ValueError, match="finite"):
        kf.update_position(math.nan, np.zeros(3), np.eye(3))
    with pytest.raises(ValueError, match="no measurement"):
        kf.predict(0.0)
    with pytest.raises(ValueError):
        kf.update_orientation(0.0, [0, 0, 0, 2.0], np.eye(3))


def stability_stream(n, rng):
    t = np.arange(n) * 1e-3
    rv = np.stack([0.3 * np.sin(t), 3.0 * t, np.full(n, 0.1)], axis=1)
    q = Rotation.from_rotvec(rv).as_quat()
    p = np.stack([np.cos(t), np.sin(t), 0.01 * t], axis=1) + rng.normal(0, 1e-4, (n, 3))
    return t, p, q, np.diag([1e-8] * 3 + [1e-8] * 3)


def test_long_run_stability_1e5_steps():
    """1e5 steps at 1 kHz: covariance stays symmetric positive definite, quaternion unit."""
    model = MotionModel(2, 1, noise=(0, 0, 1.0, 0, 1.0))
    n = 100_000
    t, p, q, C = stability_stream(n, np.random.default_rng(7))
    res = run_filter(t, UncertainPose._trusted(p, q, np.broadcast_to(C, (n, 6, 6))), model)
    cov = res.filtered.covariance
    np.testing.assert_array_equal(cov, np.swapaxes(cov, -1, -2))
    assert np.linalg.eigvalsh(cov[::100]).min() > 0
    np.testing.assert_allclose(np.linalg.norm(res.filtered.quaternion, axis=1), 1.0, atol=1e-12)
    assert res.stats["resets"] == 0
    assert res.stats["rejected_gate"] < 0.005 * n
    # the streaming filter's full state covariance over the first 1e4 steps
    kf = PoseKalmanFilter(model, history=0.005)
    for k in range(10_000):
        kf.update_pose(t[k], UncertainPose(Pose(p[k], q[k]), C))
        if k % 1000 == 999:
            x, P = kf.state
            np.testing.assert_array_equal(P, P.T)
            assert np.linalg.eigvalsh(P).min() > 0
            assert abs(np.linalg.norm(x[9:13]) - 1) < 1e-12


def test_run_filter_equals_streaming(rng):
    model = MotionModel(2, 1, noise=(0, 0, 3.0, 0, 2.0))
    n = 200
    t = np.cumsum(rng.uniform(0.005, 0.015, n))
    q = Rotation.from_rotvec(np.outer(t, [0.3, 1.0, 0.2])).as_quat()
    p = np.stack([np.sin(t), np.cos(t), t], axis=1) + rng.normal(0, 1e-3, (n, 3))
    p[50] = np.nan  # a dropout
    C = np.broadcast_to(np.diag([1e-6] * 3 + [1e-5] * 3), (n, 6, 6)).copy()
    poses = UncertainPose._trusted(p, q, C)
    res = run_filter(t, poses, model, horizons=(0.0, 0.05))
    kf = PoseKalmanFilter(model, history=0.0)
    for i in range(n):
        if i == 50:
            continue
        kf.update_pose(t[i], UncertainPose(Pose(p[i], q[i]), C[i]))
        f = kf.predict(t[i])
        np.testing.assert_allclose(res.filtered.position[i], f.position, atol=1e-12)
        np.testing.assert_allclose(res.filtered.covariance[i], f.covariance, atol=1e-15)
        g = kf.predict(t[i] + 0.05)
        np.testing.assert_allclose(res.predictions[0.05].position[i], g.position, atol=1e-12)
    assert res.stats["rejected_invalid"] == 1
    assert res.stats["updates"] == n - 1
    np.testing.assert_allclose(res.predictions[0.0].position, res.filtered.position)


@pytest.mark.parametrize("formulation", ["error_state", "additive"])
def test_run_filter_predictions_are_predict_pose_bit_for_bit(rng, formulation):
    """The offline loop predicts each horizon with :func:`predict_pose`'s operations (inline,
    on its own scratch arrays): the same bits as that kernel from the same states."""
    from trackflow.filters.derivative.offline import _prepared, _run_segments
    from trackflow.filters.derivative.streaming import kernels
    from trackflow.math import frozen

    model = MotionModel(2, 1, noise=(0, 0, 3.0, 0, 2.0))
    n = 60
    t = np.cumsum(rng.uniform(0.005, 0.015, n))
    q = Rotation.from_rotvec(np.outer(t, [0.3, 1.0, 0.2])).as_quat()
    p = np.stack([np.sin(t), np.cos(t), t], axis=1) + rng.normal(0, 1e-3, (n, 3))
    C = np.broadcast_to(np.diag([1e-6] * 3 + [1e-5] * 3), (n, 6, 6)).copy()
    h = (0.02, 0.05)
    kf, _, hs, _, rows = _prepared(t, UncertainPose._trusted(p, q, C), model, h, None,
                                   0.999, formulation, 50.0, 10)  # fmt: skip
    out = _run_segments(kf, rows, hs, True, None, states=True)
    pred_t, pred_q, pred_c, status, xs, ps = out[3], out[4], out[5], out[7], out[8], out[9]
    assert np.all(status != 3)  # every row updated: each prediction starts at its row's state
    n_dp, n_do, add, kind, sp, so = kf.kernel_settings.params
    for i in range(n):
        for j, hv in enumerate(h):
            x, pp = frozen(xs[i]), frozen(ps[i])
            pos, quat, cov = kernels().predict_pose(x, pp, hv, n_dp, n_do, add, kind, sp, so)
            np.testing.assert_array_equal(pred_t[j, i], pos)
            np.testing.assert_array_equal(pred_q[j, i], quat)
            np.testing.assert_array_equal(pred_c[j, i], cov)


def test_run_filter_sorts_out_of_order_rows(rng):
    model = MotionModel(1, 1)
    n = 50
    t = np.arange(n) * 0.01
    q = np.tile([0.0, 0, 0, 1], (n, 1))
    p = rng.normal(0, 1e-3, (n, 3))
    C = np.broadcast_to(np.eye(6) * 1e-6, (n, 6, 6)).copy()
    perm = np.arange(n)
    perm[[10, 11]] = [11, 10]
    a = run_filter(t, UncertainPose._trusted(p, q, C), model)
    b = run_filter(t[perm], UncertainPose._trusted(p[perm], q[perm], C[perm]), model)
    np.testing.assert_allclose(b.filtered.position, a.filtered.position[perm], atol=1e-15)
    assert b.stats["out_of_order"] == 2


def test_numpy_and_numba_backends_agree(rng):
    model = MotionModel(2, 1, noise=(0, 0, 3.0, 0, 2.0))
    stream = mixed_stream(rng, 15)
    results = []
    for backend in ("numpy", "numba"):
        with use_backend(backend):
            for form in ("error_state", "additive"):
                kf = PoseKalmanFilter(model, formulation=form)
                for item in stream:
                    feed(kf, item)
                results.append((kf.state, kf.predict(0.1), kf.predict(0.2)))
    for a, b in zip(results[:2], results[2:], strict=True):
        np.testing.assert_allclose(a[0][0], b[0][0], rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(a[0][1], b[0][1], rtol=1e-9, atol=1e-16)
        for u, v in zip(a[1:], b[1:], strict=True):
            np.testing.assert_allclose(u.position, v.position, atol=1e-12)
            np.testing.assert_allclose(u.covariance, v.covariance, rtol=1e-9, atol=1e-16)


def test_additive_formulation_tracks_like_error_state(rng):
    model = MotionModel(2, 1, noise=(0, 0, 3.0, 0, 2.0))
    truth = simulate(model, 200, 0.01, rng)
    C = np.diag([1e-6] * 3 + [1e-4] * 3)
    filters = {f: PoseKalmanFilter(model, formulation=f) for f in ("error_state", "additive")}
    err = {f: [] for f in filters}
    raw = []  # what a filter that only echoed its measurements would answer
    for k in range(200):
        z = measure(truth[k], 3, C, rng)
        raw.append(abs(z.quaternion @ truth[k][9:13]))
        for f, kf in filters.items():
            kf.update_pose(k * 0.01, z)
            est = kf.predict(k * 0.01)
            q_true = truth[k][9:13]
            err[f].append(abs(est.quaternion @ q_true))
            assert abs(np.linalg.norm(est.quaternion) - 1) < 1e-12
    rms = {}
    for f, e in (*err.items(), ("raw", raw)):
        ang = 2 * np.arccos(np.minimum(np.array(e[50:]), 1.0))
        rms[f] = np.sqrt(np.mean(ang**2))
    assert rms["error_state"] < 0.85 * rms["raw"], rms  # it filters (0.012 vs 0.017 rad)
    assert rms["additive"] < 1.2 * rms["error_state"], rms
    # the additive filter reports its covariance in trackflow's convention as well
    ca = filters["additive"].predict(2.0).covariance
    ce = filters["error_state"].predict(2.0).covariance
    np.testing.assert_allclose(np.diag(ca), np.diag(ce), rtol=0.3)


def test_partial_models_and_measurement_kinds(rng):
    # orientation-only model: position reported as unknown
    kf = PoseKalmanFilter(MotionModel(-1, 1, noise=(0.0, 1.0)))
    q = Rotation.from_rotvec([0.1, 0.2, 0.3]).as_quat()
    assert kf.update_pose(0.0, UncertainPose(Pose([5.0, 0, 0], q), np.eye(6) * 1e-6))
    out = kf.predict(0.01)
    assert np.all(out.position == 0) and out.covariance[0, 0] >= 1e12
    assert abs(abs(out.quaternion @ q) - 1) < 1e-9
    with pytest.raises(ValueError, match="position"):
        kf.update_position(0.02, np.zeros(3), np.eye(3))
    # position, then acceleration and orientation measured separately
    kf = PoseKalmanFilter(MotionModel(2, 0, noise=(0, 0, 1.0, 0.1)))
    assert kf.update_position(0.0, [1.0, 2.0, 3.0], np.eye(3) * 1e-6)
    for k in range(1, 30):
        t = 0.01 * k
        assert kf.update_acceleration(t, [2.0, 0, 0], np.eye(3) * 1e-4)
        assert kf.update_position(t, [1.0 + t * t, 2.0, 3.0], np.eye(3) * 1e-8)
    assert kf.update_orientation(0.3, q, np.eye(3) * 1e-6)
    x, _ = kf.state
    np.testing.assert_allclose(x[6:9], [2.0, 0, 0], atol=0.05)  # acceleration
    np.testing.assert_allclose(x[3:6], [0.6, 0, 0], atol=0.05)  # velocity 2 a t
    assert abs(abs(kf.predict(0.3).quaternion @ q) - 1) < 1e-9


def test_prediction_beats_holding_the_last_pose_on_a_real_recording(shared_data):
    """Thesis 9.2: on real handheld motion the 50 ms prediction error is far below the error of
    not predicting; and both formulations agree on this smooth recording."""
    d = np.loadtxt(shared_data / "ar_table" / "table_01.txt", comments="#")[:3000]
    t, p, q = d[:, 0] - d[0, 0], d[:, 1:4], d[:, 4:8]
    n = len(t)
    C = np.diag([0.5e-3**2] * 3 + [np.radians(0.2) ** 2] * 3)
    poses = UncertainPose._trusted(p, q / np.linalg.norm(q, axis=1)[:, None], np.tile(C, (n, 1, 1)))
    model = MotionModel(2, 1, noise=(0, 0, 30.0, 0, 20.0))
    h = 5  # rows = 50 ms at 100 Hz
    res = {
        f: run_filter(t, poses, model, horizons=(0.05,), formulation=f)
        for f in ("error_state", "additive")
    }
    pred = res["error_state"].predictions[0.05].position[100:-h]
    truth = p[100 + h :]
    assert np.allclose(t[100 + h :] - t[100:-h], 0.05, atol=2e-3)
    err_kf = np.sqrt(np.mean(np.sum((pred - truth) ** 2, axis=1)))
    err_hold = np.sqrt(np.mean(np.sum((p[100:-h] - truth) ** 2, axis=1)))
    assert err_kf < 0.3 * err_hold
    other = res["additive"].predictions[0.05].position[100:-h]
    assert np.max(np.abs(other - pred)) < 1e-4
    assert res["error_state"].stats["resets"] == 0


def test_past_queries_are_consistent_smoothed_estimates():
    """predict(t) in the past: more accurate than the filtered estimate at t, and its covariance
    consistent with the error (pose NEES at the stored times averaged over runs near 6)."""
    model = MotionModel(2, 1, noise=(0.0, 0.0, 3.0, 0.0, 2.0))
    C = np.diag([1e-6] * 3 + [1e-4] * 3)
    err_f, err_s, err_mid, nees = [], [], [], []

    def error(x_true, est):
        dq = quat_multiply(est.quaternion * [-1, -1, -1, 1], x_true[9:13])
        return np.concatenate([x_true[:3] - est.position, Rotation.from_quat(dq).as_rotvec()])

    for r in range(10):
        rng = np.random.default_rng(500 + r)
        truth = simulate(model, 120, 0.01, rng)
        kf = PoseKalmanFilter(model, history=10.0, gate_probability=None)
        filtered = []
        for k in range(120):
            kf.update_pose(k * 0.01, measure(truth[k], 3, C, rng))
            filtered.append(kf.predict(k * 0.01))
        for k in range(40, 100):
            s = kf.predict(k * 0.01)
            e = error(truth[k], s)
            nees.append(e @ np.linalg.solve(s.covariance, e))
            err_s.append(np.sum(e[:3] ** 2))
            err_f.append(np.sum(error(truth[k], filtered[k])[:3] ** 2))
            mid = kf.predict(k * 0.01 + 0.005)  # between stored states
            x_mid = model.transition(truth[k], 0.005)[0]
            err_mid.append(np.sum(error(x_mid, mid)[:3] ** 2))
    assert np.mean(err_s) < 0.5 * np.mean(err_f)
    assert 5.0 < np.mean(nees) < 7.0, np.mean(nees)
    assert np.sqrt(np.mean(err_mid)) < 1e-3  # measurement noise: 1.7 mm RMS


@pytest.mark.parametrize("dof", [1, 2, 3, 4, 6, 9, 15, 40])
@pytest.mark.parametrize("probability", [1e-4, 0.5, 0.9, 0.99, 0.999, 1 - 1e-9])
def test_chi2_gate_is_the_chi_square_quantile(probability, dof):
    """The closed-form quantile (no scipy at filter import) against scipy's."""
    assert chi2_gate(probability, dof) == pytest.approx(chi2.ppf(probability, dof), rel=1e-10)
    x = chi2.ppf(probability, dof)
    assert chi2_survival(x, dof) == pytest.approx(chi2.sf(x, dof), rel=1e-10)
    assert chi2_gate(None, dof) == float("inf")
    assert chi2_gate(1.0, dof) == float("inf")


@pytest.mark.parametrize("bad", [(1.5, 3), (-0.1, 3), (0.9, 0), (0.9, 2.5)])
def test_chi2_gate_rejects_bad_arguments(bad):
    with pytest.raises(ValueError, match="probability"):
        chi2_gate(*bad)
