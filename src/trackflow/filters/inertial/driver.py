"""Drivers of the inertial filter: the streaming :class:`InertialFilter` and :func:`run_inertial`.

Both run the kernels of :mod:`.kernel`, compiled with numba when ``trackflow.math`` uses the
numba backend (``TRACKFLOW_BACKEND=numpy`` runs the same source as Python).
"""

from __future__ import annotations

import types
from dataclasses import dataclass

import numpy as np

from trackflow.math import (
    Pose,
    UncertainPose,
    kernels_for,
    quat_from_matrix,
    quat_to_matrix,
)

from ...errors import InputError, StateError
from . import kernel as _kernel
from .model import InertialModel

__all__ = [
    "InertialFilter",
    "InertialResult",
    "InertialState",
    "kernels",
    "run_inertial",
]


def kernels() -> types.ModuleType:
    """The kernel namespace of the active backend (the library's one seam,
    :func:`trackflow.math.kernels_for`; compiled lazily on first use)."""
    return kernels_for(_kernel)


@dataclass(frozen=True)
class InertialState:
    """Filter state at time ``t``.

    Attributes
    ----------
    t : float
        Time [s].
    position, velocity : ndarray (3,)
        ``p_w_s`` [m] and ``v_w_s`` [m/s] of the IMU in the world frame.
    quaternion : ndarray (4,)
        ``R_w_s`` ``(x, y, z, w)``.
    gyro_bias, accel_bias : ndarray (3,)
        [rad/s], [m/s^2] (the accelerometer bias stays 0 in ``mode="gyro"``).
    covariance : ndarray (n, n)
        Over ``(dp, dv, dtheta, db_g[, db_a])`` (``docs/inertial.md``).
    """

    t: float
    position: np.ndarray
    velocity: np.ndarray
    quaternion: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    covariance: np.ndarray


class InertialFilter:
    """Error-state Kalman filter driven by an IMU and corrected by pose measurements.

    Call :meth:`update_imu` for every IMU sample and :meth:`update_pose` for every tracker pose
    ``T_w_b`` (both in time order); :meth:`predict` answers ``T_w_b`` at any later time,
    between IMU samples and ahead of the last one. The filter initialises on its first pose.

    Parameters
    ----------
    model : InertialModel
    """

    def __init__(self, model: InertialModel | None = None):
        self.model = model if model is not None else InertialModel()
        self._k = kernels()
        self._n = self.model.n_states
        self._noise = self.model.noise.as_array()
        self._g = self.model.gravity.copy()
        self._r_sb, self._t_sb = self.model.extrinsics.sensor_to_body()
        self._gate = self.model.gate()
        self.reset()

    def reset(self) -> None:
        """Forget the state (the next pose initialises again)."""
        self._x = np.zeros(15)
        self._r = np.eye(3)
        self._P = np.zeros((self._n, self._n))
        self._t: float | None = None
        self._gyro: np.ndarray | None = None
        self._accel: np.ndarray | None = None
        self._t_imu: float | None = None
        self._trend = np.zeros((4, 3))
        cw, ca = self.model.extrapolation_weights([0.0])
        self._wbuf = np.zeros((cw.shape[1] // 3, 3))
        self._abuf = np.zeros((ca.shape[1], 3))
        self.nis = float("nan")
        self.n_rejected = 0

    @property
    def initialized(self) -> bool:
        return self._t is not None

    @property
    def time(self) -> float | None:
        """Time of the state [s], or ``None`` before the first pose."""
        return self._t

    def state(self) -> InertialState:
        """A copy of the current state (after :meth:`initialize` or the first pose)."""
        if self._t is None:
            raise StateError("the inertial filter has no state before its first pose")
        return InertialState(
            self._t,
            self._x[0:3].copy(),
            self._x[3:6].copy(),
            quat_from_matrix(self._r),
            self._x[9:12].copy(),
            self._x[12:15].copy(),
            self._P.copy(),
        )

    def initialize(self, t: float, pose: UncertainPose, velocity=None, velocity_sigma=1.0):
        """Start from a measured pose ``T_w_b`` (and optionally the velocity ``v_w_s``)."""
        r_wb = quat_to_matrix(pose.quaternion)
        r_ws = r_wb @ self._r_sb.T
        p_ws = pose.position - r_ws @ self._t_sb
        self._x[:] = 0.0
        self._x[0:3] = p_ws
        if velocity is not None:
            self._x[3:6] = np.asarray(velocity, dtype=float).reshape(3)
        self._r = np.ascontiguousarray(r_ws)
        # the pose error of T_w_s: rotation error maps by R_s_b, lever arm couples them
        J = np.zeros((6, 6))
        J[:3, :3] = np.eye(3)
        J[:3, 3:] = r_ws @ self._k.hat(self._t_sb)
        J[3:, 3:] = self._r_sb
        C = J @ np.asarray(pose.covariance, dtype=float).reshape(6, 6) @ J.T
        self._P = self.model.initial_covariance(C, velocity_sigma)
        self._t = float(t)

    def _check_time(self, t: float, what: str) -> float:
        t = float(t)
        if not np.isfinite(t):
            raise InputError(f"{what} time must be finite, got {t}")
        if self._t is not None and t < self._t:
            raise InputError(f"{what} at t={t} is older than the filter state (t={self._t})")
        return t

    def update_imu(self, t: float, gyro, accel) -> None:
        """Propagate to ``t`` with this IMU sample (trapezoid with the previous sample).

        ``gyro`` [rad/s] and ``accel`` [m/s^2] are in the sensor frame, shape (3,).
        """
        w = np.asarray(gyro, dtype=float).reshape(3)
        a = np.asarray(accel, dtype=float).reshape(3)
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(a))):
            raise InputError(f"IMU sample at t={t} is not finite: gyro {w}, accel {a}")
        t = float(t)
        if self._t_imu is not None and t <= self._t_imu:
            raise InputError(f"IMU sample at t={t} is not after the previous one (t={self._t_imu})")
        if self._t is not None and t > self._t and self._gyro is not None:
            if self.model.input_hold == "preceding":
                wi, ai = w, a
            else:
                wi, ai = 0.5 * (self._gyro + w), 0.5 * (self._accel + a)
            self._r = self._k.propagate(
                self._x, self._r, self._P, wi, ai, t - self._t, self._g, self._noise, self._n
            )
            self._t = t
        elif self._t is not None and t > self._t:
            self._t = t  # first sample: nothing to integrate yet
        if self._t is not None:
            dt = 0.0 if self._t_imu is None else t - self._t_imu
            self._k.update_trend(
                self._trend, self._x, self._r, w, a, self._g, dt, self.model.smoothing_s, self._n
            )
            self._k.push_gyro(self._wbuf, self._abuf, self._trend, self._x, self._r, w)
        self._gyro, self._accel, self._t_imu = w, a, t

    def _advance(self, t: float) -> None:
        if t > self._t:
            if self._gyro is not None:
                self._r = self._k.propagate(
                    self._x, self._r, self._P, self._gyro, self._accel, t - self._t,
                    self._g, self._noise, self._n,
                )  # fmt: skip
            self._t = t

    def update_pose(self, t: float, pose: UncertainPose) -> bool:
        """Fuse a tracker pose ``T_w_b`` at ``t``; returns False when the gate rejected it."""
        t = self._check_time(t, "pose")
        if self._t is None:
            self.initialize(t, pose)
            return True
        self._advance(t)
        z_r = quat_to_matrix(pose.quaternion)
        Rm = np.ascontiguousarray(np.asarray(pose.covariance, dtype=float).reshape(6, 6))
        self._r, nis, ok = self._k.update_pose(
            self._x, self._r, self._P, np.asarray(pose.position, dtype=float).reshape(3),
            z_r, Rm, self._r_sb, self._t_sb, self._gate, self._n,
        )  # fmt: skip
        self.nis = float(nis)
        if not ok:
            self.n_rejected += 1
        return bool(ok)

    def update_gravity(self, accel) -> bool:
        """Fuse the last IMU sample's accelerometer as the direction of gravity (no tracker)."""
        if self._t is None:
            raise StateError("initialise the filter before fusing gravity")
        a = np.asarray(accel, dtype=float).reshape(3)
        self._r, nis, ok = self._k.update_gravity(
            self._x, self._r, self._P, a, self._g, self.model.gravity_sigma, 0.0, self._n
        )
        self.nis = float(nis)
        return bool(ok)

    def predict(self, t: float) -> UncertainPose:
        """``T_w_b`` at ``t >= time`` with covariance, holding the last IMU sample."""
        t = self._check_time(t, "prediction")
        if self._t is None:
            raise StateError("the inertial filter has no state before its first pose")
        x, r, P = self._x.copy(), self._r.copy(), self._P.copy()
        if t > self._t and self._gyro is not None:
            r = self._k.propagate(
                x, r, P, self._gyro, self._accel, t - self._t, self._g, self._noise, self._n
            )
        elif t > self._t:  # no IMU yet: hold the pose, grow the covariance as if at rest
            r = self._k.propagate(
                x, r, P, np.zeros(3), -(r.T @ self._g), t - self._t, self._g, self._noise,
                self._n,
            )  # fmt: skip
        H = self._k.pose_jacobian(x, r, self._r_sb, self._t_sb, self._n)
        C = H @ P @ H.T
        if self._gyro is None:
            return UncertainPose(Pose(x[0:3] + r @ self._t_sb, quat_from_matrix(r @ self._r_sb)), C)
        # the mean follows the input trend (the covariance that of the held sample)
        p_b, r_b = np.empty(3), np.empty((3, 3))
        h = t - self._t
        cw, ca = self.model.extrapolation_weights([h])
        self._k.predict_ahead(
            self._x, self._r, self._trend, self.model.use_slope, cw, self._wbuf, ca, self._abuf,
            h, 0, self._r_sb, self._t_sb, p_b, r_b,
        )  # fmt: skip
        return UncertainPose(Pose(p_b, quat_from_matrix(r_b)), C)


@dataclass(frozen=True)
class InertialResult:
    """Output of :func:`run_inertial`.

    Attributes
    ----------
    predictions : dict[float, tuple[ndarray (K, 3), ndarray (K, 4)]]
        ``{h: (position, quaternion)}``: ``T_w_b`` predicted ``h`` seconds after each pose
        sample (or each query time, (Q, ...)) from everything up to it (``nan`` before the
        filter started).
    nis : ndarray (K,)
        Normalised innovation squared of each pose update (``nan`` if gated or not fused).
    final : InertialState
    """

    predictions: dict
    nis: np.ndarray
    final: InertialState


def run_inertial(
    imu_t,
    gyro,
    accel,
    pose_t,
    position,
    quaternion,
    pose_covariance,
    model: InertialModel | None = None,
    horizons=(0.0,),
    scored=None,
    velocity_sigma: float = 1.0,
    query_t=None,
) -> InertialResult:
    """Run the inertial filter over an IMU recording and a pose recording of the same clock.

    Parameters
    ----------
    imu_t : array_like (M,)
        Increasing IMU times [s].
    gyro, accel : array_like (M, 3)
        Sensor-frame angular velocity [rad/s] and specific force [m/s^2].
    pose_t : array_like (K,)
        Increasing pose times [s].
    position, quaternion : array_like (K, 3), (K, 4)
        Measured ``T_w_b`` [m, (x, y, z, w)].
    pose_covariance : array_like (6, 6)
        Measurement covariance over ``(dp, dtheta)`` (trackflow convention).
    model : InertialModel
    horizons : sequence of float
        Prediction horizons [s] (0: the filtered pose).
    scored : array_like of bool (K,), optional
        Poses after which predictions are made (default all); others only update.
    velocity_sigma : float
        Initial velocity standard deviation [m/s].
    query_t : array_like (Q,), optional
        Query times [s]: instead of after poses, predict ``horizons`` after each query time
        from the IMU samples and poses up to it (an application asking at any time); the
        predictions are then (Q, ...) arrays (``nan`` before the filter started).

    Returns
    -------
    InertialResult
    """
    model = model if model is not None else InertialModel()
    k = kernels()
    ti = np.ascontiguousarray(imu_t, dtype=float).reshape(-1)
    w = np.ascontiguousarray(gyro, dtype=float).reshape(-1, 3)
    a = np.ascontiguousarray(accel, dtype=float).reshape(-1, 3)
    tp = np.ascontiguousarray(pose_t, dtype=float).reshape(-1)
    p = np.ascontiguousarray(position, dtype=float).reshape(-1, 3)
    q = np.ascontiguousarray(quaternion, dtype=float).reshape(-1, 4)
    if w.shape[0] != ti.shape[0] or a.shape[0] != ti.shape[0]:
        raise InputError(f"IMU arrays disagree: t {ti.shape}, gyro {w.shape}, accel {a.shape}")
    if p.shape[0] != tp.shape[0] or q.shape[0] != tp.shape[0]:
        raise InputError(f"pose arrays disagree: t {tp.shape}, p {p.shape}, q {q.shape}")
    if tp.shape[0] < 2 or ti.shape[0] < 2:
        raise InputError("need at least two IMU samples and two poses")
    Rm = np.ascontiguousarray(pose_covariance, dtype=float).reshape(6, 6)
    h = np.ascontiguousarray(horizons, dtype=float).reshape(-1)
    sc = np.ones(tp.shape[0], bool) if scored is None else np.asarray(scored, bool).reshape(-1)
    # start at the first pose that has an IMU sample at or before it
    start = int(np.searchsorted(tp, ti[0], side="left"))
    if start >= tp.shape[0] - 1:
        raise InputError("the IMU recording starts after the last pose (clocks not aligned?)")
    f = InertialFilter(model)
    v0 = (p[start + 1] - p[start]) / (tp[start + 1] - tp[start])
    f.initialize(tp[start], UncertainPose(Pose(p[start], q[start]), Rm), v0, velocity_sigma)
    x, r, P = f._x, f._r, f._P
    imu_from = int(np.searchsorted(ti, tp[start], side="right")) - 1
    imu_from = max(imu_from, 0)
    n_imu = ti.shape[0] - imu_from
    t_ev = np.concatenate([ti[imu_from:], tp[start + 1 :]])
    kind = np.concatenate(
        [np.zeros(n_imu, np.int8), np.where(sc[start + 1 :], 2, 1).astype(np.int8)]
    )
    idx = np.concatenate([np.arange(imu_from, ti.shape[0]), np.arange(start + 1, tp.shape[0])])
    n_out = tp.shape[0]
    if query_t is not None:  # queries after the IMU samples and poses of the same time
        tq = np.ascontiguousarray(query_t, dtype=float).reshape(-1)
        n_out = tq.shape[0]
        kind[kind == 2] = 1
        keep = tq >= tp[start]
        t_ev = np.concatenate([t_ev, tq[keep]])
        kind = np.concatenate([kind, np.full(np.count_nonzero(keep), 3, np.int8)])  # queries
        idx = np.concatenate([idx, np.flatnonzero(keep)])
    order = np.argsort(t_ev, kind="stable")  # IMU first at equal times
    z_r = quat_to_matrix(q)
    out_p = np.full((h.shape[0], n_out, 3), np.nan)
    out_r = np.full((h.shape[0], n_out, 3, 3), np.nan)
    out_nis = np.full(tp.shape[0], np.nan)
    t_ev = np.ascontiguousarray(np.maximum(t_ev[order], tp[start]))
    r, t_end = k.run_events(
        kind[order], t_ev, idx[order].astype(np.int64), w, a, p, z_r, Rm, x, r, P,
        model.gravity, model.noise.as_array(), f._r_sb, f._t_sb, model.gate(), h,
        model.smoothing_s, model.use_slope,
        *model.extrapolation_weights(h), model.input_hold == "preceding", model.n_states,
        out_p, out_r, out_nis,
    )  # fmt: skip
    preds = {}
    for i, hv in enumerate(h.tolist()):
        qq = np.full((n_out, 4), np.nan)
        ok = np.isfinite(out_r[i, :, 0, 0])
        qq[ok] = quat_from_matrix(out_r[i, ok])
        preds[hv] = (out_p[i], qq)
    final = InertialState(
        float(t_end), x[0:3].copy(), x[3:6].copy(), quat_from_matrix(r), x[9:12].copy(),
        x[12:15].copy(), P.copy(),
    )  # fmt: skip
    return InertialResult(preds, out_nis, final)
