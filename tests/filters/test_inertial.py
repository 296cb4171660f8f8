"""Inertial error-state filter: Jacobians vs finite differences, bias convergence, NEES/NIS."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from trackflow.filters import (
    ImuExtrinsics,
    ImuNoise,
    InertialFilter,
    InertialModel,
    run_inertial,
)
from trackflow.filters.inertial import (
    allan_deviation,
    estimate_imu_rotation,
    imu_clock_offset,
    noise_from_static,
)
from trackflow.filters.inertial import kernel as K
from trackflow.math import Pose, UncertainPose, quat_from_matrix, quat_to_matrix
from trackflow.math import _lie as L

G = np.array([0.0, 0.0, -9.80665])
EXTR = ImuExtrinsics(np.array([0.1, -0.2, 0.3, 0.927]) / np.linalg.norm([0.1, -0.2, 0.3, 0.927]),
                     np.array([0.05, -0.02, 0.1]))  # fmt: skip


def _state(rng):
    x = np.zeros(15)
    x[0:3] = rng.normal(size=3)
    x[3:6] = rng.normal(size=3)
    x[9:12] = rng.normal(scale=0.05, size=3)
    x[12:15] = rng.normal(scale=0.2, size=3)
    return x, L.so3_exp(rng.normal(size=3))


def _perturb(x, r, d, n):
    x2 = x.copy()
    x2[0:3] += d[0:3]
    x2[3:6] += d[3:6]
    x2[9:12] += d[9:12]
    if n == 15:
        x2[12:15] += d[12:15]
    return x2, r @ L.so3_exp(d[6:9])


def _difference(xa, ra, xb, rb, n):
    """Error state taking (xb, rb) to (xa, ra)."""
    e = np.zeros(n)
    e[0:3] = xa[0:3] - xb[0:3]
    e[3:6] = xa[3:6] - xb[3:6]
    e[6:9] = L.so3_log(rb.T @ ra)
    e[9:12] = xa[9:12] - xb[9:12]
    if n == 15:
        e[12:15] = xa[12:15] - xb[12:15]
    return e


def _step(x, r, gyro, accel, dt, n):
    x = x.copy()
    P = np.zeros((n, n))
    r = K.propagate(x, r, P, gyro, accel, dt, G, np.ones(4), n)
    return x, r


@pytest.mark.parametrize("n", [15, 12])
def test_transition_jacobians_match_finite_differences(n):
    rng = np.random.default_rng(1)
    eps = 1e-6
    for _ in range(5):
        x, r = _state(rng)
        gyro, accel, dt = rng.normal(size=3) * 3, rng.normal(size=3) * 5, 0.01
        F, Gm, A = K.transition(x, r, gyro, accel, dt, G, n)
        x0, r0 = _step(x, r, gyro, accel, dt, n)
        J_fd = np.zeros((n, n))
        for i in range(n):
            d = np.zeros(15)
            d[i if i < 12 or n == 15 else i] = eps
            if n == 12 and i >= 12:
                continue
            xp, rp = _perturb(x, r, d, n)
            x1, r1 = _step(xp, rp, gyro, accel, dt, n)
            J_fd[:, i] = _difference(x1, r1, x0, r0, n) / eps
        np.testing.assert_allclose(F, J_fd, atol=1e-6)
        J_gyro = np.zeros((n, 3))
        J_accel = np.zeros((n, 3))
        for i in range(3):
            d = np.zeros(3)
            d[i] = eps
            x1, r1 = _step(x, r, gyro + d, accel, dt, n)
            J_gyro[:, i] = _difference(x1, r1, x0, r0, n) / eps
            x1, r1 = _step(x, r, gyro, accel + d, dt, n)
            J_accel[:, i] = _difference(x1, r1, x0, r0, n) / eps
        np.testing.assert_allclose(Gm, J_gyro, atol=1e-6)
        np.testing.assert_allclose(A, J_accel, atol=1e-6)


@pytest.mark.parametrize("n", [15, 12])
def test_pose_and_gravity_jacobians_match_finite_differences(n):
    rng = np.random.default_rng(2)
    r_sb, t_sb = EXTR.sensor_to_body()
    eps = 1e-6
    for _ in range(5):
        x, r = _state(rng)

        def pose(xx, rr):
            return xx[0:3] + rr @ t_sb, rr @ r_sb

        def accel(xx, rr):
            return -(rr.T @ G) + (xx[12:15] if n == 15 else 0.0)

        p0, R0 = pose(x, r)
        a0 = accel(x, r)
        J_pose_fd = np.zeros((6, n))
        J_acc_fd = np.zeros((3, n))
        for i in range(n):
            d = np.zeros(15)
            d[i] = eps
            xp, rp = _perturb(x, r, d, n)
            p1, R1 = pose(xp, rp)
            J_pose_fd[:3, i] = (p1 - p0) / eps
            J_pose_fd[3:, i] = L.so3_log(R0.T @ R1) / eps
            J_acc_fd[:, i] = (accel(xp, rp) - a0) / eps
        np.testing.assert_allclose(K.pose_jacobian(x, r, r_sb, t_sb, n), J_pose_fd, atol=1e-6)
        np.testing.assert_allclose(K.gravity_jacobian(x, r, G, n), J_acc_fd, rtol=1e-5, atol=1e-6)


def test_so3_helpers_round_trip():
    rng = np.random.default_rng(3)
    for phi in list(rng.normal(size=(20, 3))) + [np.array([np.pi - 1e-5, 0, 0]), np.zeros(3)]:
        r = L.so3_exp(phi)
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
        back = L.so3_log(r)
        np.testing.assert_allclose(L.so3_exp(back), r, atol=1e-9)
    phi, d = rng.normal(size=3), rng.normal(size=3) * 1e-6
    lhs = L.so3_exp(phi + d)
    rhs = L.so3_exp(phi) @ L.so3_exp(L.right_jac(phi) @ d)
    np.testing.assert_allclose(lhs, rhs, atol=1e-11)


# -- synthetic recordings ------------------------------------------------------------------
RATE, POSE_EVERY, SECONDS = 200.0, 4, 20.0
TRUE_BG = np.array([0.02, -0.015, 0.01])
TRUE_BA = np.array([0.1, -0.08, 0.12])
NOISE = ImuNoise(gyro=2e-3, accel=2e-2, gyro_bias=1e-5, accel_bias=1e-4)
SIG_P, SIG_R = 1e-3, np.radians(0.3)


def _rot(axis: int, angle: np.ndarray) -> np.ndarray:
    """Rotations about one axis, (n, 3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    m = np.zeros((angle.shape[0], 3, 3))
    i, j = ((1, 2), (2, 0), (0, 1))[axis]  # the right-handed order after the axis
    m[:, axis, axis] = 1.0
    m[:, i, i], m[:, j, j], m[:, i, j], m[:, j, i] = c, c, -s, s
    return m


def _truth():
    """True IMU inputs and the trajectory, in closed form (independent of the filter's
    integrator): attitude ``R = Rz(a) Ry(b) Rx(c)`` with sinusoidal angles, so the body rate
    is ``w = Rx(c)^T Ry(b)^T (0, 0, a') + Rx(c)^T (0, b', 0) + (c', 0, 0)``; position
    sinusoids with their derivatives, so the specific force is ``R^T (p'' - g)``."""
    n = int(SECONDS * RATE)
    t = np.arange(n) / RATE
    a, da = 0.8 * np.sin(0.7 * t), 0.56 * np.cos(0.7 * t)
    b, db = 0.4 * np.sin(1.1 * t + 0.3), 0.44 * np.cos(1.1 * t + 0.3)
    c, dc = 0.5 * np.sin(0.9 * t + 1.0), 0.45 * np.cos(0.9 * t + 1.0)
    rx, ry, rz = _rot(0, c), _rot(1, b), _rot(2, a)
    rs = rz @ ry @ rx
    zero = np.zeros_like(t)
    w = (
        np.einsum("nji,nkj,nk->ni", rx, ry, np.stack([zero, zero, da], 1))
        + np.einsum("nji,nj->ni", rx, np.stack([zero, db, zero], 1))
        + np.stack([dc, zero, zero], 1)
    )
    pos = np.stack([-2 / 0.81 * np.sin(0.9 * t), -1.5 / 1.69 * np.cos(1.3 * t),
                    -1 / 0.36 * np.sin(0.6 * t)], 1)  # fmt: skip
    vel = np.stack([-2 / 0.9 * np.cos(0.9 * t), 1.5 / 1.3 * np.sin(1.3 * t),
                    -1 / 0.6 * np.cos(0.6 * t)], 1)  # fmt: skip
    acc = np.stack([2 * np.sin(0.9 * t), 1.5 * np.cos(1.3 * t), np.sin(0.6 * t)], 1)
    f = np.einsum("nji,nj->ni", rs, acc - G)
    xs = np.zeros((n, 15))
    xs[:, 0:3], xs[:, 3:6] = pos, vel
    return t, w, f, xs, rs


def test_the_closed_form_truth_is_consistent():
    """The truth's rate and specific force against finite differences of its own attitude
    and position (so that a wrong formula cannot pass as truth)."""
    t, w, f, xs, rs = TRUTH
    h = 1 / RATE
    k = np.arange(1, t.shape[0] - 1)
    w_fd = np.array([L.so3_log(rs[i - 1].T @ rs[i + 1]) / (2 * h) for i in k])
    np.testing.assert_allclose(w_fd, w[k], atol=1e-4)
    acc_fd = (xs[k + 1, 0:3] - 2 * xs[k, 0:3] + xs[k - 1, 0:3]) / h**2
    np.testing.assert_allclose(np.einsum("nji,nj->ni", rs[k], acc_fd - G), f[k], atol=1e-3)
    np.testing.assert_allclose((xs[k + 1, 0:3] - xs[k - 1, 0:3]) / (2 * h), xs[k, 3:6],
                               atol=1e-4)  # fmt: skip


TRUTH = _truth()


def _recording(seed):
    t, w, f, xs, rs = TRUTH
    rng = np.random.default_rng(seed)
    gyro = w + TRUE_BG + rng.normal(scale=NOISE.gyro * np.sqrt(RATE), size=w.shape)
    accel = f + TRUE_BA + rng.normal(scale=NOISE.accel * np.sqrt(RATE), size=f.shape)
    r_sb, t_sb = EXTR.sensor_to_body()
    k = np.arange(0, t.shape[0], POSE_EVERY)
    p_b = xs[k, 0:3] + np.einsum("kij,j->ki", rs[k], t_sb)
    r_b = rs[k] @ r_sb
    p_meas = p_b + rng.normal(scale=SIG_P, size=p_b.shape)
    noise_r = np.array([L.so3_exp(v) for v in rng.normal(scale=SIG_R, size=(k.shape[0], 3))])
    q_meas = quat_from_matrix(r_b @ noise_r)
    return t, gyro, accel, t[k], p_meas, q_meas, k


def _model(mode="strapdown"):
    return InertialModel(mode=mode, noise=NOISE, extrinsics=EXTR, gravity=G,
                         gyro_bias_sigma=0.05, accel_bias_sigma=0.3)  # fmt: skip


def test_biases_converge_on_synthetic_data():
    t, gyro, accel, tp, p, q, _ = _recording(7)
    C = np.diag([SIG_P**2] * 3 + [SIG_R**2] * 3)
    res = run_inertial(t, gyro, accel, tp, p, q, C, _model())
    s = res.final
    sd = np.sqrt(np.diag(s.covariance))
    assert np.all(np.abs(s.gyro_bias - TRUE_BG) < 4 * sd[9:12])
    assert np.all(np.abs(s.accel_bias - TRUE_BA) < 4 * sd[12:15])
    assert np.all(sd[9:12] < 2e-3) and np.all(sd[12:15] < 0.03)  # actually learned
    np.testing.assert_allclose(s.gyro_bias, TRUE_BG, atol=3e-3)
    np.testing.assert_allclose(s.accel_bias, TRUE_BA, atol=0.05)


def test_nees_and_nis_inside_95_percent_band():
    _, _, _, xs, rs = TRUTH
    C = np.diag([SIG_P**2] * 3 + [SIG_R**2] * 3)
    runs, nees, nis = 25, [], []
    for seed in range(runs):
        t, gyro, accel, tp, p, q, k = _recording(100 + seed)
        res = run_inertial(t, gyro, accel, tp, p, q, C, _model())
        s = res.final
        x_true = xs[-1]
        e = np.zeros(15)
        e[0:3] = s.position - x_true[0:3]
        e[3:6] = s.velocity - x_true[3:6]
        e[6:9] = L.so3_log(quat_to_matrix(s.quaternion).T @ rs[-1])
        e[9:12] = s.gyro_bias - TRUE_BG
        e[12:15] = s.accel_bias - TRUE_BA
        nees.append(e @ np.linalg.solve(s.covariance, e))
        nis.extend(res.nis[len(res.nis) // 2 :].tolist())
    nees, nis = np.array(nees), np.array(nis)
    lo, hi = chi2.ppf([0.025, 0.975], 15 * runs) / runs
    assert lo <= nees.mean() <= hi, (nees.mean(), lo, hi)
    m = nis.shape[0]
    lo, hi = chi2.ppf([0.025, 0.975], 6 * m) / m
    assert lo <= nis.mean() <= hi, (nis.mean(), lo, hi)


def test_streaming_filter_matches_offline_run_and_predicts():
    t, gyro, accel, tp, p, q, k = _recording(11)
    C = np.diag([SIG_P**2] * 3 + [SIG_R**2] * 3)
    model = _model()
    res = run_inertial(t, gyro, accel, tp, p, q, C, model, horizons=(0.0, 0.05))
    f = InertialFilter(model)
    v0 = (p[1] - p[0]) / (tp[1] - tp[0])
    f.initialize(tp[0], UncertainPose(Pose(p[0], q[0]), C), v0, 1.0)
    j = 1
    for i in range(t.shape[0]):
        while j < tp.shape[0] and tp[j] < t[i]:
            f.update_pose(tp[j], UncertainPose(Pose(p[j], q[j]), C))
            j += 1
        if t[i] >= tp[0]:
            f.update_imu(t[i], gyro[i], accel[i])
        if j == 200 and i == k[200] - 1:
            mid = f.predict(tp[200])
    s = f.state()
    np.testing.assert_allclose(s.position, res.final.position, atol=1e-6)
    np.testing.assert_allclose(s.gyro_bias, res.final.gyro_bias, atol=1e-8)
    assert np.isfinite(mid.covariance).all()
    # the filtered pose at h = 0 is close to the truth
    _, _, _, xs, rs = TRUTH
    pp, _ = res.predictions[0.0]
    err = np.linalg.norm(
        pp[100:] - (xs[k[100:], 0:3] + rs[k[100:]] @ EXTR.sensor_to_body()[1]), axis=1
    )
    assert np.sqrt(np.mean(err**2)) < SIG_P


def test_gyro_only_variant_tracks_orientation_and_gyro_bias():
    t, gyro, accel, tp, p, q, _ = _recording(5)
    C = np.diag([SIG_P**2] * 3 + [SIG_R**2] * 3)
    model = InertialModel(mode="gyro", noise=ImuNoise(gyro=2e-3, accel=3.0), extrinsics=EXTR)
    res = run_inertial(t, gyro, accel, tp, p, q, C, model)
    assert res.final.covariance.shape == (12, 12)
    np.testing.assert_allclose(res.final.gyro_bias, TRUE_BG, atol=3e-3)
    np.testing.assert_array_equal(res.final.accel_bias, 0.0)


def test_bad_input_is_rejected_with_a_reason():
    f = InertialFilter(_model())
    with pytest.raises(RuntimeError, match="before its first pose"):
        f.predict(0.0)
    C = np.eye(6) * 1e-4
    f.update_pose(1.0, UncertainPose(Pose(np.zeros(3), [0, 0, 0, 1.0]), C))
    with pytest.raises(ValueError, match="older than the filter state"):
        f.update_pose(0.5, UncertainPose(Pose(np.zeros(3), [0, 0, 0, 1.0]), C))
    with pytest.raises(ValueError, match="not finite"):
        f.update_imu(1.1, [np.nan, 0, 0], [0, 0, 9.8])
    with pytest.raises(ValueError, match="mode"):
        InertialModel(mode="magic")
    with pytest.raises(ValueError, match="ImuNoise.gyro"):
        ImuNoise(gyro=-1.0)
    with pytest.raises(ValueError, match="IMU recording starts after"):
        run_inertial([10.0, 11.0], np.zeros((2, 3)), np.zeros((2, 3)), [0.0, 1.0],
                     np.zeros((2, 3)), np.tile([0, 0, 0, 1.0], (2, 1)), C)  # fmt: skip


def test_noise_from_a_static_segment_recovers_the_white_densities():
    rng = np.random.default_rng(21)
    rate, n = 200.0, 60_000  # five minutes at rest
    gyro = rng.normal(scale=3e-3 * np.sqrt(rate), size=(n, 3)) + [0.01, -0.02, 0.005]
    accel = rng.normal(scale=4e-2 * np.sqrt(rate), size=(n, 3)) + [0, 0, 9.81]
    noise = noise_from_static(gyro, accel, rate)
    assert abs(noise.gyro / 3e-3 - 1) < 0.1
    assert abs(noise.accel / 4e-2 - 1) < 0.1
    taus, adev = allan_deviation(gyro, rate)
    # white noise: slope -1/2 in log-log
    slope = np.polyfit(np.log(taus[:10]), np.log(adev[:10, 0]), 1)[0]
    assert abs(slope + 0.5) < 0.05


def test_mounting_rotation_and_gyro_bias_are_recovered():
    t, gyro, _, _, _, _, _ = _recording(3)
    _, _, _, _, rs = TRUTH
    r_bs = quat_to_matrix(EXTR.quaternion)
    q_wb = quat_from_matrix(rs @ r_bs.T)  # the body's orientation, poses at the IMU rate
    q_est, bias = estimate_imu_rotation(t, gyro, t, q_wb)
    err = L.so3_log(quat_to_matrix(q_est).T @ r_bs)
    assert np.degrees(np.linalg.norm(err)) < 0.5
    np.testing.assert_allclose(bias, TRUE_BG, atol=5e-3)


@pytest.mark.parametrize("shift", [-0.0123, 0.0371])
def test_clock_offset_is_recovered_on_euroc(shared_data, shift):
    from trackflow.io import read_imu, read_stream

    gt, _ = read_stream(shared_data / "euroc" / "V1_01_easy_groundtruth_200hz.txt")
    imu, _ = read_imu(shared_data / "euroc" / "V1_01_easy_imu0.csv")
    t0 = int(gt.t_ns[0])
    tp = (gt.t_ns - t0) * 1e-9
    ti = (imu.t_ns - t0) * 1e-9 - shift  # an IMU clock behind by `shift`
    d = imu_clock_offset(ti, imu.gyro, tp, gt.quaternion, max_offset=0.1)
    assert abs(d - shift) < 1e-3  # the two share a clock: the offset is the shift
