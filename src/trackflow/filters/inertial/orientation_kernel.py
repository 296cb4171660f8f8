"""Numeric kernels of the IMU-only orientation filter (plain NumPy, compiled by numba if present).

The model is documented in :mod:`.orientation`. Nominal state: ``R`` (3, 3) = ``R_w_s`` and
``x`` (9,) = ``(b_g, v_w, p_w)``; error state (12,) = ``(dtheta, db_g, dv, dp)`` with
``R_true = R Exp(dtheta)`` (right, sensor frame), ``b_true = b + db`` and so on.
"""

from __future__ import annotations

import numpy as np

from trackflow.math._lie import hat, right_jac, so3_exp

__all__ = [
    "KERNELS",
    "orientation_transition",
    "orientation_step",
    "heading_of",
    "heading_jacobian",
    "scalar_update",
    "orientation_sample",
    "run_orientation",
]

KERNEL_SOURCES = ("trackflow.math._lie",)
KERNELS = (
    "orientation_transition",
    "orientation_step",
    "heading_of",
    "heading_jacobian",
    "scalar_update",
    "orientation_sample",
    "run_orientation",
)

# error-state blocks
ITH, IBG, IV, IP = 0, 3, 6, 9
N_STATES = 12


def orientation_transition(r, x, gyro, accel, dt):
    """``J_xnext_x`` (12, 12): the exact Jacobian of :func:`orientation_step`'s mean update.

    Parameters
    ----------
    r : ndarray (3, 3)
        ``R_w_s`` before the step.
    x : ndarray (9,)
        ``(b_g, v, p)`` before the step.
    gyro, accel : ndarray (3,)
        Angular velocity [rad/s] and specific force [m/s^2] held over the step (sensor frame).
    dt : float
        Step [s].
    """
    phi = (gyro - x[0:3]) * dt
    e = so3_exp(phi).T
    jr = right_jac(phi)
    rf = r @ hat(accel)
    F = np.eye(N_STATES)
    for i in range(3):
        for j in range(3):
            F[ITH + i, ITH + j] = e[i, j]
            F[ITH + i, IBG + j] = -jr[i, j] * dt
            F[IV + i, ITH + j] = -rf[i, j] * dt
            F[IP + i, ITH + j] = -0.5 * rf[i, j] * dt * dt
        F[IP + i, IV + i] = dt
    return F


def orientation_step(r, x, P, gyro, accel, dt, g, noise):
    """One prediction step in place (``x``, ``P``); returns the new ``R_w_s`` (3, 3).

    The sample is held over the step: ``R' = R Exp((omega - b_g) dt)``, ``v' = v + a dt``,
    ``p' = p + v dt + a dt^2 / 2`` with ``a = R f + g``. ``noise`` (3,) holds the white-noise
    densities of the gyro [rad/s/sqrt(Hz)], the gyro bias random walk [rad/s^2/sqrt(Hz)] and
    the accelerometer [m/s^2/sqrt(Hz)].
    """
    if dt <= 0.0:
        return r
    F = orientation_transition(r, x, gyro, accel, dt)
    a = r @ accel + g
    for i in range(3):
        x[6 + i] += x[3 + i] * dt + 0.5 * a[i] * dt * dt
        x[3 + i] += a[i] * dt
    r_new = r @ so3_exp((gyro - x[0:3]) * dt)
    Pn = F @ P @ F.T
    qg = noise[0] * noise[0] * dt
    qb = noise[1] * noise[1] * dt
    qa = noise[2] * noise[2] * dt
    for i in range(3):
        Pn[ITH + i, ITH + i] += qg
        Pn[IBG + i, IBG + i] += qb
        Pn[IV + i, IV + i] += qa
        Pn[IP + i, IP + i] += qa * dt * dt / 3.0
        Pn[IP + i, IV + i] += qa * dt / 2.0
        Pn[IV + i, IP + i] += qa * dt / 2.0
    P[:, :] = 0.5 * (Pn + Pn.T)
    return r_new


def heading_of(r, mag):
    """Heading residual [rad] of a magnetometer sample ``mag`` (3,) under ``R_w_s``.

    The world frame is east-north-up: the horizontal part of ``R mag`` should point north
    (+y). Returns ``atan2(m_x, m_y)`` of ``m = R mag``: 0 when it does, positive when the
    estimate has to turn by that angle about the world z axis (right-handed) to align.
    """
    m = r @ mag
    return np.arctan2(m[0], m[1])


def heading_jacobian(r):
    """``J_heading_x`` (12,) of :func:`heading_of` for a turn about the world's vertical.

    Turning the estimate by ``alpha`` about world z (``R -> Exp(alpha e_z) R``, i.e.
    ``alpha = e_z^T R dtheta``) changes the residual by ``-alpha`` whatever the field's dip, so
    the row is ``-e_z^T R`` on ``dtheta``. The residual's dependence on the tilt (through the
    field's vertical part) is left out on purpose: the magnetometer corrects heading only and
    a disturbed field cannot tilt the estimate.
    """
    H = np.zeros(N_STATES)
    for j in range(3):
        H[ITH + j] = -r[2, j]
    return H


def scalar_update(r, x, P, H, y, var, keep_bias):
    """Fuse a scalar innovation ``y`` with row ``H`` (12,) and variance ``var`` in place.

    Returns the new ``R_w_s``. Joseph form for a scalar measurement (numerically safe at
    the small variances of the rest and pseudo-measurements, and exact for any gain).
    ``keep_bias`` leaves the gyro bias out of the update (a Schmidt "consider" update: the
    measurement's errors are not allowed to teach the bias; its uncertainty still counts).
    """
    PH = P @ H
    s = H @ PH + var
    K = PH / s
    if keep_bias:
        for i in range(3):
            K[IBG + i] = 0.0
    dx = K * y
    for i in range(3):
        x[i] += dx[IBG + i]
        x[3 + i] += dx[IV + i]
        x[6 + i] += dx[IP + i]
    r_new = r @ so3_exp(dx[ITH : ITH + 3])
    # (I - K H) P (I - K H)^T + K var K^T
    A = P - np.outer(K, PH)
    Pn = A - np.outer(A @ H, K) + np.outer(K, K) * var
    P[:, :] = 0.5 * (Pn + Pn.T)
    return r_new


def orientation_sample(r, x, P, det, gyro, accel, mag, use_mag, dt, g, noise, bounds, rest):
    """Process one IMU sample in place; returns the new ``R_w_s`` (3, 3).

    Predicts over ``dt`` with the sample, fuses the motion bound (``v = 0``, ``p = 0``), the
    heading of ``mag`` (``use_mag``), runs the rest detector and, at rest, the gyro as a bias
    measurement. ``dt = 0`` (the first sample) only starts the detector.

    Parameters
    ----------
    r, x, P : nominal ``R_w_s`` (3, 3), ``(b_g, v, p)`` (9,), covariance (12, 12)
    det : ndarray (10,)
        Rest detector state: gyro and accelerometer low passes (3 + 3), their mean squared
        deviations (2), time at rest so far [s], started flag. Zeros before the first sample.
    gyro, accel, mag : ndarray (3,)
        Sensor-frame angular velocity [rad/s], specific force [m/s^2], magnetic field (any
        unit; only its direction is used).
    use_mag : bool
    dt : float
        Time since the previous sample [s].
    g : (3,) gravity in the world frame [m/s^2]
    noise : (3,) see :func:`orientation_step`
    bounds : (4,)
        ``(velocity_sigma [m/s], position_sigma [m], correlation_time [s], heading_sigma [rad])``:
        the pseudo-measurements ``v = 0`` and ``p = 0`` and the heading measurement each carry
        the variance ``sigma^2 * correlation_time / dt`` (one independent look per correlation
        time, spread over the samples).
    rest : (4,)
        ``(gyro_threshold [rad/s], accel_threshold [m/s^2], rest_time [s], filter_tau [s])``:
        the sensor is at rest when the RMS deviations of gyro and accelerometer from their
        low passes stay below the thresholds (and the low-passed rate below four times the
        gyro threshold) for ``rest_time``.
    """
    if det[9] == 0.0:
        for i in range(3):
            det[i] = gyro[i]
            det[3 + i] = accel[i]
        det[6] = 0.0
        det[7] = 0.0
        det[8] = 0.0
        det[9] = 1.0
    if dt <= 0.0:
        return r
    r = orientation_step(r, x, P, gyro, accel, dt, g, noise)
    H = np.zeros(N_STATES)
    for i in range(6):
        sig = bounds[0] if i < 3 else bounds[1]
        H[:] = 0.0
        H[IV + i] = 1.0  # v then p: the blocks are adjacent
        r = scalar_update(r, x, P, H, -x[3 + i], sig * sig * bounds[2] / dt, False)
    if use_mag:
        # the field's orientation-dependent errors must not teach the gyro bias
        var = bounds[3] * bounds[3] * bounds[2] / dt
        r = scalar_update(r, x, P, heading_jacobian(r), -heading_of(r, mag), var, True)
    al = 1.0 - np.exp(-dt / rest[3])
    dw2 = 0.0
    da2 = 0.0
    lp2 = 0.0
    for i in range(3):
        det[i] += al * (gyro[i] - det[i])
        det[3 + i] += al * (accel[i] - det[3 + i])
        dw2 += (gyro[i] - det[i]) ** 2
        da2 += (accel[i] - det[3 + i]) ** 2
        lp2 += det[i] * det[i]
    det[6] += al * (dw2 - det[6])
    det[7] += al * (da2 - det[7])
    still = np.sqrt(det[6]) < rest[0] and np.sqrt(det[7]) < rest[1] and np.sqrt(lp2) < 4 * rest[0]
    det[8] = det[8] + dt if still else 0.0
    if det[8] >= rest[2]:
        for i in range(3):  # at rest the reading is the bias plus white noise
            H[:] = 0.0
            H[IBG + i] = 1.0
            r = scalar_update(r, x, P, H, gyro[i] - x[i], noise[0] * noise[0] / dt, False)
    return r


def run_orientation(t, gyro, accel, mag, use_mag, r, x, P, g, noise, bounds, rest, out_r, out_rest):
    """Run :func:`orientation_sample` over a recording, writing ``R_w_s`` after each sample.

    Parameters
    ----------
    t : float (M,)
        Increasing sample times [s].
    gyro, accel, mag : (M, 3)
        Sensor-frame angular velocity [rad/s], specific force [m/s^2], magnetic field.
    use_mag : bool
    r, x, P : initial state (``x`` and ``P`` modified in place)
    g, noise, bounds, rest : see :func:`orientation_sample`
    out_r : (M, 3, 3)
        ``R_w_s`` after each sample.
    out_rest : bool (M,)
        Whether each sample was classified as rest.

    Returns
    -------
    R_w_s (3, 3) after the last sample.
    """
    det = np.zeros(10)
    for k in range(t.shape[0]):
        dt = t[k] - t[k - 1] if k > 0 else 0.0
        r = orientation_sample(
            r, x, P, det, gyro[k], accel[k], mag[k], use_mag, dt, g, noise, bounds, rest
        )
        out_rest[k] = det[8] >= rest[2]
        for i in range(3):
            for j in range(3):
                out_r[k, i, j] = r[i, j]
    return r
