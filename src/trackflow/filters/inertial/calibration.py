"""Estimating the inertial filter's parameters from data.

* :func:`allan_deviation` and :func:`noise_from_static`: white-noise densities and bias
  instability from a static segment (IEEE 952 overlapping Allan deviation).
* :func:`angular_velocity_from_poses`: body-frame angular velocity of a pose recording.
* :func:`imu_clock_offset`: IMU-to-tracker clock offset from the cross-correlation of the
  angular speeds ``|omega|`` (independent of the unknown mounting rotation;
  :func:`trackflow.timesync.correlation_offset`).
* :func:`estimate_imu_rotation`: ``R_b_s`` from gyro and pose angular velocities (Wahba's
  problem, solved by SVD), with the gyro bias.
* :func:`estimate_gravity`: gravity in the tracker's world frame from poses and accelerometer.
"""

from __future__ import annotations

import numpy as np

from trackflow.math import (
    quat_from_matrix,
    quat_make_continuous,
    quat_rminus,
    quat_rotate,
    quat_slerp,
    umeyama,
)
from trackflow.timesync import correlation_offset

from ...errors import InputError
from .model import GRAVITY, ImuNoise

__all__ = [
    "world_acceleration",
    "allan_deviation",
    "angular_velocity_from_poses",
    "imu_clock_offset",
    "estimate_gravity",
    "estimate_imu_rotation",
    "noise_from_static",
]


def allan_deviation(samples, rate_hz: float, taus=None) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping Allan deviation of a rate signal (per axis).

    Parameters
    ----------
    samples : array_like (N, D)
        Rate samples (e.g. gyro [rad/s]) of a static recording.
    rate_hz : float
    taus : array_like, optional
        Averaging times [s]; default 30 log-spaced values from one sample to N/9 samples.

    Returns
    -------
    taus : ndarray (T,)
    adev : ndarray (T, D)
    """
    x = np.asarray(samples, dtype=float)
    x = x.reshape(x.shape[0], -1)
    n = x.shape[0]
    if n < 20:
        raise InputError(f"Allan deviation needs at least 20 samples, got {n}")
    dt = 1.0 / float(rate_hz)
    if taus is None:
        m = np.unique(np.logspace(0, np.log10(max(n // 9, 2)), 30).astype(int))
    else:
        m = np.unique(np.maximum(1, np.rint(np.asarray(taus, float) / dt).astype(int)))
    m = m[m <= (n - 1) // 2]
    theta = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0) * dt])
    out = np.empty((m.shape[0], x.shape[1]))
    for i, mi in enumerate(m):
        tau = mi * dt
        d = theta[2 * mi :] - 2.0 * theta[mi:-mi] + theta[: -2 * mi]
        out[i] = np.sqrt(0.5 * np.mean(d**2, axis=0)) / tau
    return m * dt, out


def _white_density(taus, adev) -> float:
    """Angular/velocity random walk: mean over axes of ``adev(tau) sqrt(tau)`` at short taus."""
    k = max(1, min(5, taus.shape[0] // 5))
    return float(np.median(adev[:k] * np.sqrt(taus[:k, None])))


def noise_from_static(gyro, accel, rate_hz: float) -> ImuNoise:
    """:class:`ImuNoise` from a static IMU segment (Allan deviation).

    White densities from the slope -1/2 part (``adev(tau) sqrt(tau)`` at the shortest
    averaging times); bias random walks from the minimum of the Allan deviation (the bias
    instability ``B``), taken as a random walk reaching ``B`` over the averaging time of the
    minimum: ``B / sqrt(tau_min)``.
    """
    out = {}
    for name, x in (("gyro", gyro), ("accel", accel)):
        taus, adev = allan_deviation(x, rate_hz)
        white = _white_density(taus, adev)
        mean = adev.mean(axis=1)
        i = int(np.argmin(mean))
        out[name] = white
        out[name + "_bias"] = float(mean[i] / np.sqrt(taus[i]))
    return ImuNoise(out["gyro"], out["accel"], out["gyro_bias"], out["accel_bias"])


def angular_velocity_from_poses(t, quaternion) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame angular velocity between consecutive poses (midpoint times).

    Returns ``(t_mid (N-1,), omega_b (N-1, 3) [rad/s])`` with
    ``omega_b = Log(q[k]^* q[k+1]) / dt``.
    """
    t = np.asarray(t, dtype=float)
    q = quat_make_continuous(np.asarray(quaternion, dtype=float))
    dt = np.diff(t)
    inc = quat_rminus(q[1:], q[:-1])
    return 0.5 * (t[1:] + t[:-1]), inc / dt[:, None]


def imu_clock_offset(
    imu_t, gyro, pose_t, quaternion, max_offset: float = 0.5, step: float | None = None
) -> float:
    """Clock offset ``d`` [s] such that IMU time ``t_imu + d`` is tracker time.

    The angular speeds of the two (gyro norm; pose angular velocity norm) are cross-correlated
    over ``[-max_offset, max_offset]`` on a grid of ``step`` (default: half the median pose
    interval, at most 5 ms) by :func:`trackflow.timesync.correlation_offset`, with the tracker
    as host clock and the IMU as remote clock (``d = host - remote``); call that directly for
    the offset's standard error. The speed is independent of the IMU-to-body rotation, so this
    works before that rotation is known.

    Raises
    ------
    ValueError
        The recordings overlap less than ``12 max_offset``, or the correlation peaks at the
        edge of the search range.
    """
    ti = np.asarray(imu_t, float)
    tp_mid, w_pose = angular_velocity_from_poses(pose_t, quaternion)
    ok = np.all(np.isfinite(w_pose), axis=1)
    tp_mid, w_pose = tp_mid[ok], w_pose[ok]
    if step is None:
        step = min(0.5 * float(np.median(np.diff(pose_t))), 0.005)
    if min(ti[-1], tp_mid[-1]) - max(ti[0], tp_mid[0]) < 12 * max_offset:
        raise InputError("IMU and pose recordings overlap too little to estimate a clock offset")
    speed_imu = np.linalg.norm(np.asarray(gyro, float), axis=1)
    r = correlation_offset(
        tp_mid, np.linalg.norm(w_pose, axis=1), ti, speed_imu, max_offset_s=max_offset,
        step_s=step, min_peak=0.0,
    )  # fmt: skip
    return r.offset_s


def estimate_imu_rotation(
    imu_t, gyro, pose_t, quaternion, min_speed: float = 0.3
) -> tuple[np.ndarray, np.ndarray]:
    """``R_b_s`` and the gyro bias from gyro and pose angular velocities (same clock).

    Solves ``omega_b = R_b_s (omega_s - b_g)`` in the least-squares sense over the pose
    intervals turning faster than ``min_speed`` [rad/s]: the bias is the offset of the
    centred problem, ``R_b_s`` the SVD solution of Wahba's problem.

    Returns
    -------
    quaternion : ndarray (4,)
        ``R_b_s`` ``(x, y, z, w)``.
    gyro_bias : ndarray (3,)
        [rad/s] in the sensor frame.
    """
    tp_mid, w_b = angular_velocity_from_poses(pose_t, quaternion)
    ti = np.asarray(imu_t, float)
    g = np.asarray(gyro, float)
    # average the gyro over each pose interval (the pose increment integrates it)
    t = np.asarray(pose_t, float)
    cum = np.concatenate(
        [np.zeros((1, 3)), np.cumsum(0.5 * (g[1:] + g[:-1]) * np.diff(ti)[:, None], axis=0)]
    )
    inside = (t[:-1] >= ti[0]) & (t[1:] <= ti[-1])
    c0 = np.stack([np.interp(t[:-1], ti, cum[:, i]) for i in range(3)], axis=1)
    c1 = np.stack([np.interp(t[1:], ti, cum[:, i]) for i in range(3)], axis=1)
    w_s = (c1 - c0) / np.diff(t)[:, None]
    use = inside & (np.linalg.norm(w_b, axis=1) > min_speed) & np.all(np.isfinite(w_b), axis=1)
    if np.count_nonzero(use) < 10:
        raise InputError("too little rotation to estimate the IMU-to-body rotation")
    a, b = w_s[use], w_b[use]
    # w_b = R_b_s (w_s - bias): T_b_s's rotation, its translation is -R_b_s bias
    fit = umeyama(b, a, allow_collinear=True)
    r_bs = fit.rotation
    bias = -r_bs.T @ fit.translation
    return quat_from_matrix(r_bs), bias


def estimate_gravity(imu_t, accel, pose_t, quaternion, imu_quaternion=None) -> np.ndarray:
    """Gravity in the tracker's world frame [m/s^2], shape (3,).

    Averages the specific force rotated into the world, ``R_w_b R_b_s f``, over the recording
    (linear accelerations average out over seconds): gravity is minus that mean direction,
    with standard magnitude.
    """
    ti = np.asarray(imu_t, float)
    tp = np.asarray(pose_t, float)
    q = quat_make_continuous(np.asarray(quaternion, float))
    inside = (ti >= tp[0]) & (ti <= tp[-1])
    if np.count_nonzero(inside) < 10:
        raise InputError("IMU and pose recordings do not overlap")
    tq = ti[inside]
    j = np.clip(np.searchsorted(tp, tq, side="right") - 1, 0, tp.shape[0] - 2)
    s = (tq - tp[j]) / (tp[j + 1] - tp[j])
    q_wb = quat_slerp(q[j], q[j + 1], s)
    f = np.asarray(accel, float)[inside]
    if imu_quaternion is not None:
        f = quat_rotate(np.asarray(imu_quaternion, float), f)
    mean = quat_rotate(q_wb, f).mean(axis=0)
    return -GRAVITY * mean / np.linalg.norm(mean)


def world_acceleration(imu_t, accel, pose_t, quaternion, imu_quaternion, gravity) -> np.ndarray:
    """World acceleration ``R_w_b R_b_s f + g`` at the IMU samples inside the pose recording
    (orientation slerped between poses), shape (M', 3), and the mask of those samples."""
    ti = np.asarray(imu_t, float)
    tp = np.asarray(pose_t, float)
    q = quat_make_continuous(np.asarray(quaternion, float))
    inside = (ti >= tp[0]) & (ti <= tp[-1])
    tq = ti[inside]
    j = np.clip(np.searchsorted(tp, tq, side="right") - 1, 0, tp.shape[0] - 2)
    s = (tq - tp[j]) / (tp[j + 1] - tp[j])
    q_wb = quat_slerp(q[j], q[j + 1], s)
    f = quat_rotate(np.asarray(imu_quaternion, float), np.asarray(accel, float)[inside])
    return quat_rotate(q_wb, f) + np.asarray(gravity, float), inside
