"""Pose trajectories in float seconds: interpolation, velocities and speeds (internal).

A :class:`Trajectory` holds one stream's samples as float seconds from a shared epoch (so two
streams of Unix-time recordings keep sub-microsecond resolution), positions in metres and
sign-continuous unit quaternions ``(x, y, z, w)``. Interpolation is linear in position and
slerp in orientation; a query falling into a gap longer than ``max_gap_s`` is marked invalid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..io import PoseStream
from ..math import (
    quat_conjugate,
    quat_exp,
    quat_log,
    quat_make_continuous,
    quat_multiply,
    quat_rminus,
    quat_to_matrix,
    so3_right_jacobian_inverse,
)

__all__ = ["Sampled", "Trajectory", "common_epoch_ns", "make_trajectory", "trajectory"]


@dataclass(frozen=True)
class Trajectory:
    """Samples of ``T_source_target``: ``t`` (N,) seconds, ``p`` (N, 3) m, ``q`` (N, 4)."""

    t: np.ndarray
    p: np.ndarray
    q: np.ndarray
    name: str = "stream"
    step: np.ndarray | None = None  # (N-1, 3) Log(q_i^-1 q_i+1), filled by ``trajectory``
    period: float | None = None  # median interval, filled by ``trajectory``

    @property
    def period_s(self) -> float:
        """Median sample interval in seconds."""
        if self.period is None:
            return float(np.median(np.diff(self.t)))
        return self.period

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0])

    def sample(self, tq, max_gap_s: float | None = None) -> Sampled:
        """Interpolate at times ``tq`` (M,) seconds; see :class:`Sampled`."""
        return interpolate(self, tq, max_gap_s)


@dataclass(frozen=True)
class Sampled:
    """Interpolated poses with their time derivatives.

    ``p`` (M, 3) and ``q`` (M, 4) the pose, ``v`` (M, 3) the velocity in the source frame
    [m/s], ``w`` (M, 3) the body angular velocity in the target frame [rad/s] (``R(t + h) ~
    R(t) Exp(w h)``), both constant over a sample interval; ``valid`` (M,) is False outside the
    stream or inside a gap.
    """

    p: np.ndarray
    q: np.ndarray
    v: np.ndarray
    w: np.ndarray
    valid: np.ndarray


def common_epoch_ns(*streams: PoseStream) -> int:
    """The earliest first timestamp of the streams, the origin of their float seconds."""
    return int(min(int(s.t_ns[0]) for s in streams))


def trajectory(stream: PoseStream, epoch_ns: int, name: str | None = None) -> Trajectory:
    """A :class:`Trajectory` of ``stream`` in seconds from ``epoch_ns``.

    Raises ``ValueError`` when the stream has fewer than 2 samples.
    """
    label = name or f"{stream.source}->{stream.target}"
    if len(stream) < 2:
        raise InputError(f"{label}: need at least 2 samples, got {len(stream)}")
    t = (np.asarray(stream.t_ns, np.int64) - np.int64(epoch_ns)).astype(float) * 1e-9
    q = quat_make_continuous(np.asarray(stream.quaternion, float))
    return make_trajectory(t, np.asarray(stream.position, float), q, label)


def make_trajectory(t, p, q, name: str = "stream") -> Trajectory:
    """A :class:`Trajectory` from arrays (seconds, metres, quaternions) with its cached steps."""
    t, p, q = np.asarray(t, float), np.asarray(p, float), np.asarray(q, float)
    if np.any(np.diff(t) <= 0):
        raise InputError(f"{name}: timestamps must be strictly increasing")
    step = quat_rminus(q[1:], q[:-1])
    return Trajectory(t, p, q, name, step, float(np.median(np.diff(t))))


def interpolate(traj: Trajectory, tq, max_gap_s: float | None = None) -> Sampled:
    """Pose, velocity and body angular velocity of ``traj`` at times ``tq`` (seconds).

    ``max_gap_s`` defaults to 2.5 median sample intervals; queries between two samples
    farther apart, or outside ``[t0, tN]``, are invalid (their values are clamped copies).
    """
    tq = np.asarray(tq, float)
    t = traj.t
    gap = 2.5 * traj.period_s if max_gap_s is None else float(max_gap_s)
    i = np.clip(np.searchsorted(t, tq, side="right") - 1, 0, len(t) - 2)
    dt = t[i + 1] - t[i]
    s = np.clip((tq - t[i]) / dt, 0.0, 1.0)
    valid = (tq >= t[0]) & (tq <= t[-1]) & (dt <= gap)
    v = (traj.p[i + 1] - traj.p[i]) / dt[:, None]
    p = traj.p[i] + s[:, None] * (traj.p[i + 1] - traj.p[i])
    if traj.step is None:
        step = quat_rminus(traj.q[i + 1], traj.q[i])
    else:
        step = traj.step[i]
    q = quat_multiply(traj.q[i], quat_exp(s[:, None] * step))
    return Sampled(p, q, v, step / dt[:, None], valid)


def body_rates(traj: Trajectory, tq, half_window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed body angular velocity (M, 3) [rad/s] and validity by central differences.

    ``w(t) = Log(R(t - h)^T R(t + h)) / 2h`` with ``h = half_window_s``: a difference over a
    window longer than the sample interval averages the sensor's orientation noise.
    """
    tq = np.asarray(tq, float)
    a = interpolate(traj, tq - half_window_s)
    b = interpolate(traj, tq + half_window_s)
    w = quat_rminus(b.q, a.q) / (2.0 * half_window_s)
    return w, a.valid & b.valid


def body_rate_jacobians(traj: Trajectory, tq, half_window_s: float):
    """Jacobians of :func:`body_rates` with respect to the samples' rotation errors.

    With right rotation errors ``d_n`` of the samples (conventions), the interpolated
    orientation's error is ``(1 - s) d_n + s d_n+1`` (to first order in the rotation between
    two samples) and ``w = Log(R_-^T R_+) / 2h`` moves by ``J_r^-1(phi) (e_+ - M^T e_-) / 2h``
    with ``M = R_-^T R_+ = Exp(phi)``.

    Returns
    -------
    J_w_d : ndarray, shape (M, 4, 3, 3)
        For the two samples around ``t - h`` and the two around ``t + h``.
    index : ndarray, shape (M, 4)
        Those samples' indices.
    """
    tq = np.asarray(tq, float)
    h = float(half_window_s)
    t = traj.t

    def bracket(x):
        i = np.clip(np.searchsorted(t, x, side="right") - 1, 0, len(t) - 2)
        return i, np.clip((x - t[i]) / (t[i + 1] - t[i]), 0.0, 1.0)[:, None, None]

    a, b = interpolate(traj, tq - h), interpolate(traj, tq + h)
    M = quat_multiply(quat_conjugate(a.q), b.q)
    Jinv = so3_right_jacobian_inverse(quat_log(M)) / (2.0 * h)
    JMt = Jinv @ np.swapaxes(quat_to_matrix(M), 1, 2)
    im, sm = bracket(tq - h)
    ip, sp = bracket(tq + h)
    J = np.stack([-(1 - sm) * JMt, -sm * JMt, (1 - sp) * Jinv, sp * Jinv], axis=1)
    return J, np.stack([im, im + 1, ip, ip + 1], axis=1)


def velocities(traj: Trajectory, tq, half_window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Velocity (M, 3) [m/s] and body angular velocity (M, 3) [rad/s] by central differences.

    Averaged over ``2 half_window_s``: the derivative of the expected pose, not of one noisy
    sample interval (a Jacobian built from noisy derivatives makes a covariance overconfident).
    """
    tq = np.asarray(tq, float)
    a = interpolate(traj, tq - half_window_s)
    b = interpolate(traj, tq + half_window_s)
    w = quat_rminus(b.q, a.q) / (2.0 * half_window_s)
    return (b.p - a.p) / (2.0 * half_window_s), w


def speeds(traj: Trajectory, tq, half_window_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angular speed [rad/s], linear speed [m/s] and validity at ``tq``, by central differences."""
    w, ok = body_rates(traj, tq, half_window_s)
    a = interpolate(traj, np.asarray(tq) - half_window_s)
    b = interpolate(traj, np.asarray(tq) + half_window_s)
    v = np.linalg.norm(b.p - a.p, axis=1) / (2.0 * half_window_s)
    return np.linalg.norm(w, axis=1), v, ok
