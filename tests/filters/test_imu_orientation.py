"""IMU-only orientation filter: Jacobians vs finite differences, bias, consistency, BROAD."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from trackflow.filters import ImuOrientationModel, run_imu_orientation
from trackflow.filters.inertial import initial_orientation
from trackflow.filters.inertial import orientation_kernel as OK
from trackflow.math import _lie as L
from trackflow.math import quat_to_matrix

G = np.array([0.0, 0.0, -9.81])


def _boxminus(r_a, x_a, r_b, x_b):
    """Error state (12,) that takes nominal b to a: ``R_a = R_b Exp(d)``, ``x_a = x_b + d``."""
    return np.concatenate([L.so3_log(r_b.T @ r_a), x_a - x_b])


def _boxplus(r, x, d):
    return r @ L.so3_exp(d[0:3]), x + d[3:]


def test_transition_matches_finite_differences_of_the_step():
    rng = np.random.default_rng(0)
    r = L.so3_exp(rng.normal(size=3))
    x = rng.normal(scale=[0.05] * 3 + [0.5] * 3 + [1.0] * 3)
    gyro, accel, dt = rng.normal(scale=3.0, size=3), rng.normal(scale=5.0, size=3), 0.01
    noise = np.array([1e-3, 1e-4, 1e-2])

    def step(r0, x0):
        x1, P = x0.copy(), np.zeros((12, 12))
        r1 = OK.orientation_step(r0, x1, P, gyro, accel, dt, G, noise)
        return r1, x1

    r1, x1 = step(r, x)
    F = OK.orientation_transition(r, x, gyro, accel, dt)
    eps = 1e-6
    J = np.empty((12, 12))
    for j in range(12):
        d = np.zeros(12)
        d[j] = eps
        rp, xp = step(*_boxplus(r, x, d))
        rm, xm = step(*_boxplus(r, x, -d))
        J[:, j] = (_boxminus(rp, xp, r1, x1) - _boxminus(rm, xm, r1, x1)) / (2 * eps)
    np.testing.assert_allclose(F, J, atol=1e-7)


def test_heading_jacobian_matches_finite_differences_about_the_vertical():
    rng = np.random.default_rng(1)
    for _ in range(5):
        r = L.so3_exp(rng.normal(size=3))
        mag = rng.normal(size=3) * 40.0
        H = OK.heading_jacobian(r)
        eps = 1e-6
        for axis, expected in ((2, True), (0, False), (1, False)):
            d = r.T[:, axis] * eps  # error state that turns R about world axis `axis`
            num = OK.heading_of(r @ L.so3_exp(d), mag) - OK.heading_of(r @ L.so3_exp(-d), mag)
            num /= 2 * eps
            if expected:  # a turn about the vertical: the row is the exact derivative
                np.testing.assert_allclose(H[:3] @ d / eps, num, atol=1e-7)
            else:  # a tilt: left out by design (heading-only correction)
                np.testing.assert_allclose(H[:3] @ d, 0.0, atol=1e-15)
        assert np.all(H[3:] == 0.0)


def test_scalar_update_is_the_kalman_update():
    rng = np.random.default_rng(2)
    A = rng.normal(size=(12, 12))
    P = A @ A.T + np.eye(12)
    H, y, var = rng.normal(size=12), 0.3, 0.05
    x, r = np.zeros(9), np.eye(3)
    P1 = P.copy()
    r1 = OK.scalar_update(r, x, P1, H, y, var, False)
    k = P @ H / (H @ P @ H + var)
    np.testing.assert_allclose(P1, P - np.outer(k, H @ P), atol=1e-12)
    dx = k * y
    np.testing.assert_allclose(x, dx[3:], atol=1e-15)
    np.testing.assert_allclose(r1, L.so3_exp(dx[:3]), atol=1e-15)
    # consider update: the bias stays, the covariance is the Joseph form of the masked gain
    x2, P2 = np.zeros(9), P.copy()
    OK.scalar_update(r, x2, P2, H, y, var, True)
    km = k.copy()
    km[3:6] = 0.0
    ikh = np.eye(12) - np.outer(km, H)
    np.testing.assert_allclose(P2, ikh @ P @ ikh.T + var * np.outer(km, km), atol=1e-12)
    np.testing.assert_array_equal(x2[0:3], 0.0)
    assert np.linalg.eigvalsh(P2).min() > 0
    np.testing.assert_allclose(P2[3:6, 3:6], P[3:6, 3:6], atol=1e-12)  # its bias block stays


def test_initial_orientation_levels_and_points_north():
    rng = np.random.default_rng(3)
    r_ws = L.so3_exp(rng.normal(size=3))
    f = r_ws.T @ -G  # at rest the specific force points up
    north = np.array([0.0, 20.0, -40.0])  # east-north-up world, field dipping down
    r0 = initial_orientation(f, r_ws.T @ north)
    np.testing.assert_allclose(r0, r_ws, atol=1e-12)
    tilt_only = initial_orientation(f)
    np.testing.assert_allclose(tilt_only @ f, [0, 0, 9.81], atol=1e-12)
    with pytest.raises(ValueError, match="cannot level"):
        initial_orientation([0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="no horizontal part"):
        initial_orientation(f, f)


def _simulate(seed, n=4000, dt=0.005, rest=600, bias=(0.02, -0.03, 0.015), noise=None):
    """An IMU turning in place (no linear motion): rest, then smooth rotation.

    The accelerometer sample ``k`` is ``-R_(k-1)^T g`` (the filter holds each sample over the
    step that ends at its stamp, from the orientation at the step's start).
    """
    rng = np.random.default_rng(seed)
    noise = np.array([2e-3, 1e-4, 2e-2]) if noise is None else noise
    t = np.arange(n) * dt
    amp, freq, ph = rng.uniform(0.5, 2.0, 3), rng.uniform(0.1, 0.6, 3), rng.uniform(0, 6, 3)
    omega = amp * np.sin(2 * np.pi * freq * t[:, None] + ph)
    omega[:rest] = 0.0
    r = np.empty((n, 3, 3))
    r[0] = L.so3_exp(rng.normal(scale=0.3, size=3))
    for k in range(1, n):
        r[k] = r[k - 1] @ L.so3_exp(omega[k] * dt)
    b = np.array(bias) + np.cumsum(rng.normal(scale=noise[1] * np.sqrt(dt), size=(n, 3)), axis=0)
    gyro = omega + b + rng.normal(scale=noise[0] / np.sqrt(dt), size=(n, 3))
    r_prev = np.concatenate([r[:1], r[:-1]])
    accel = np.einsum("kji,j->ki", r_prev, -G) + rng.normal(
        scale=noise[2] / np.sqrt(dt), size=(n, 3)
    )
    mag_w = np.array([0.0, 20.0, -40.0])
    mag = np.einsum("kji,j->ki", r, mag_w) + rng.normal(scale=0.5, size=(n, 3))
    return t, gyro, accel, mag, r, b


def _exact_model(noise):
    """The filter's model of :func:`_simulate`: no translation, so v = p = 0 exactly."""
    return ImuOrientationModel(
        gyro_noise=noise[0], gyro_bias_walk=noise[1], accel_noise=noise[2],
        velocity_sigma=1e-3, position_sigma=1e-3, correlation_time=0.005, gravity=9.81,
        gyro_bias_sigma=0.05, tilt_sigma=0.05,
    )  # fmt: skip


def _up_angle_deg(q, r_true):
    up_est = quat_to_matrix(q)[..., 2, :]
    up_true = r_true[..., 2, :]
    return np.degrees(np.arccos(np.clip(np.sum(up_est * up_true, -1), -1, 1)))


def test_gyro_bias_converges_and_rest_is_detected():
    noise = np.array([5e-4, 1e-5, 1e-2])  # a consumer MEMS IMU
    t, gyro, accel, mag, r, b = _simulate(5, noise=noise)
    res = run_imu_orientation(t, gyro, accel, mag, _exact_model(noise))
    np.testing.assert_allclose(res.gyro_bias, b[-1], atol=2e-3)
    assert res.rest[400:600].all() and not res.rest[800:].any()
    assert np.sqrt(np.mean(_up_angle_deg(res.quaternions, r)[600:] ** 2)) < 0.3
    # with the magnetometer the heading is absolute: R_w_s itself
    err = [np.linalg.norm(L.so3_log(quat_to_matrix(q).T @ rt)) for q, rt in
           zip(res.quaternions[600::50], r[600::50])]  # fmt: skip
    assert np.degrees(np.max(err)) < 1.0


def test_nees_inside_95_percent_band():
    """Final (dtheta, db_g) NEES over 25 seeded runs of a recording the model describes."""
    noise = np.array([2e-3, 1e-4, 2e-2])
    runs, nees = 25, []
    for seed in range(runs):
        t, gyro, accel, mag, r, b = _simulate(100 + seed, n=2000, noise=noise)
        res = run_imu_orientation(t, gyro, accel, mag, _exact_model(noise))
        e = np.concatenate(
            [L.so3_log(quat_to_matrix(res.quaternions[-1]).T @ r[-1]), b[-1] - res.gyro_bias]
        )
        C = res.covariance[0:6, 0:6]
        nees.append(e @ np.linalg.solve(C, e))
    lo, hi = chi2.ppf([0.025, 0.975], 6 * runs) / runs
    assert lo <= np.mean(nees) <= hi, (np.mean(nees), lo, hi)


def test_bad_input_is_rejected_with_a_reason():
    t = np.arange(10) * 0.01
    w, a = np.zeros((10, 3)), np.tile([0, 0, 9.81], (10, 1))
    with pytest.raises(ValueError, match=r"accel must have shape \(10, 3\)"):
        run_imu_orientation(t, w, a[:5])
    bad = a.copy()
    bad[4, 1] = np.nan
    with pytest.raises(ValueError, match="accel sample 4 is not finite"):
        run_imu_orientation(t, w, bad)
    with pytest.raises(ValueError, match="increase strictly"):
        run_imu_orientation(t[::-1], w, a)
    with pytest.raises(ValueError, match="velocity_sigma"):
        ImuOrientationModel(velocity_sigma=-1.0)


def test_broad_slow_translation_inclination_below_half_a_degree(shared_data):
    """BROAD trial 10 (not the tuning trial): inclination RMSE over the movement phase."""
    from scipy.io import loadmat

    from trackflow.io import read_imu

    path = shared_data / "broad" / "10_undisturbed_slow_translation_A.mat"
    imu, _ = read_imu(path)
    m = loadmat(path)
    res = run_imu_orientation(imu.t_ns * 1e-9, imu.gyro, imu.accel)
    q_ref = m["opt_quat"][:, [1, 2, 3, 0]]  # (w, x, y, z) -> (x, y, z, w)
    ok = m["movement"].ravel().astype(bool) & np.isfinite(q_ref).all(axis=1)
    incl = _up_angle_deg(res.quaternions[ok], quat_to_matrix(q_ref[ok]))
    assert np.sqrt(np.mean(incl**2)) < 0.5


def test_heading_inclination_split_of_known_errors():
    from trackflow.filters import heading_inclination_errors
    from trackflow.math import quat_exp, quat_multiply

    rng = np.random.default_rng(6)
    q_ref = quat_exp(rng.normal(size=(50, 3)))
    yaw = quat_exp(np.array([0.0, 0.0, 0.4]))  # a world-frame heading error only
    h, i, tot = heading_inclination_errors(quat_multiply(yaw, q_ref), q_ref)
    np.testing.assert_allclose(h, 0.4, atol=1e-12)
    np.testing.assert_allclose(i, 0.0, atol=1e-6)
    np.testing.assert_allclose(tot, 0.4, atol=1e-12)
    tilt = quat_exp(np.array([0.3, -0.2, 0.0]))  # about a horizontal axis only
    h, i, tot = heading_inclination_errors(quat_multiply(tilt, q_ref), -q_ref)  # sign-blind
    np.testing.assert_allclose(i, np.hypot(0.3, 0.2), atol=1e-12)
    np.testing.assert_allclose(h, 0.0, atol=1e-6)
    # inclination is the angle between the two "up" directions, whatever the heading
    q_est = quat_multiply(quat_exp(rng.normal(scale=0.2, size=(50, 3))), q_ref)
    _, i, _ = heading_inclination_errors(q_est, q_ref)
    np.testing.assert_allclose(np.degrees(i), _up_angle_deg(q_est, quat_to_matrix(q_ref)),
                               atol=1e-5)  # fmt: skip


def test_streaming_filter_reproduces_the_recording_function():
    from trackflow.filters import ImuOrientationFilter

    noise = np.array([5e-4, 1e-5, 1e-2])
    t, gyro, accel, mag, _, _ = _simulate(7, n=1500, noise=noise)
    model = _exact_model(noise)
    for use_mag in (False, True):
        ref = run_imu_orientation(t, gyro, accel, mag if use_mag else None, model)
        f = ImuOrientationFilter(model, magnetometer=use_mag)
        out = [f.update(tk, w, a, m if use_mag else None)
               for tk, w, a, m in zip(t, gyro, accel, mag)]  # fmt: skip
        first = next(k for k, q in enumerate(out) if q is not None)
        assert t[first] > t[0] + model.init_time >= t[first - 1]
        q = np.array(out[first:])
        dots = np.abs(np.sum(q * ref.quaternions[first:], axis=1))
        np.testing.assert_allclose(dots, 1.0, atol=1e-12)
        np.testing.assert_allclose(f.gyro_bias, ref.gyro_bias, atol=1e-12)
        assert f.at_rest == ref.rest[-1]
    with pytest.raises(ValueError, match="not after the previous one"):
        f.update(t[-1], gyro[0], accel[0], mag[0])
    with pytest.raises(ValueError, match="mag missing"):
        f.update(t[-1] + 1.0, gyro[0], accel[0])
    with pytest.raises(ValueError, match="not finite"):
        f.update(t[-1] + 1.0, [np.nan, 0, 0], accel[0], mag[0])
