"""Orientation from an IMU alone: an error-state Kalman filter on SO(3) with bounded motion.

Frames: ``w`` an east-north-up world (``z`` up; ``y`` magnetic north when a magnetometer is
fused, else the heading of the first sample), ``s`` the IMU's sensor frame.

Nominal state ``R = R_w_s``, gyro bias ``b_g``, and the velocity ``v`` and position ``p`` of
the sensor in ``w``, integrated from the accelerometer::

    R' = R [omega - b_g]x        v' = R f + g        p' = v        b_g' = n_bg

Error state (12,) ``(dtheta, db_g, dv, dp)`` with ``R_true = R Exp(dtheta)`` (right, sensor
frame, trackflow's convention). Why a velocity and a position: an orientation error tilts the
specific force, so gravity leaks into ``v`` and ``p`` (``dv' = -R [f]x dtheta``). A hand-held or
body-worn IMU stays near where it is, so ``v = 0`` and ``p = 0`` are fused as pseudo-measurements
with the spread of the motion (``velocity_sigma``, ``position_sigma``). The linear acceleration
integrates to a bounded velocity and position and barely moves the estimate, while a tilt error
grows them without bound and is corrected: a third-order separation of gravity from motion,
without a low-pass filter or a gate on ``|f| - g``. The pseudo-measurements are correlated from
sample to sample; each gets the variance ``sigma^2 * correlation_time / dt`` (one independent
look per correlation time, whatever the sample rate).

Gyro bias: a random walk in the state, observed through gravity while the IMU moves, and
directly at rest (the low-passed gyro and accelerometer deviations stay below thresholds for
``rest_time``; then each gyro sample measures the bias).

Magnetometer (optional, "9D"): the heading of the horizontal part of ``R m`` against north,
a scalar measurement whose row turns the estimate about the vertical only (a disturbed field
cannot tilt it) and that leaves the gyro bias out of its update (a Schmidt "consider" update:
the field's errors depend on the orientation, a soft-iron or mounting error reads as a heading
offset that changes as the sensor turns, and would otherwise be learnt as a bias).

Initialisation: tilt (and gravity's magnitude) from the mean accelerometer of the first
``init_time`` seconds, heading from the mean magnetometer of the same samples (or zero).

The kernels are :mod:`.orientation_kernel`; the measured figures against ``vqf`` and
``imufusion`` on BROAD are in ``docs/inertial.md``.
"""

from __future__ import annotations

import types
from dataclasses import asdict, dataclass

import numpy as np

from trackflow.math import kernels_for, quat_conjugate, quat_from_matrix, quat_multiply

from ...errors import InputError
from . import orientation_kernel as _okernel

__all__ = [
    "ImuOrientationFilter",
    "ImuOrientationModel",
    "ImuOrientationResult",
    "heading_inclination_errors",
    "initial_orientation",
    "run_imu_orientation",
]


def kernels() -> types.ModuleType:
    """The orientation kernels of the active backend (:func:`trackflow.math.kernels_for`)."""
    return kernels_for(_okernel)


@dataclass(frozen=True)
class ImuOrientationModel:
    """Settings of :func:`run_imu_orientation`.

    The defaults are BROAD's "trial-agnostic good parameters" on its four undisturbed trials
    in ``../shared/data`` (the grid point with the lowest mean error over all four, 6D
    inclination for the first parameters, 9D total error for ``heading_sigma``;
    ``bench/imu_orientation.py``); the figures in ``docs/inertial.md`` score every trial
    with parameters chosen on the other three instead.

    Attributes
    ----------
    gyro_noise : float
        Gyro white noise [rad/s/sqrt(Hz)] (with unmodelled scale and misalignment errors).
    gyro_bias_walk : float
        Gyro bias random walk [rad/s^2/sqrt(Hz)].
    accel_noise : float
        Accelerometer white noise [m/s^2/sqrt(Hz)].
    velocity_sigma, position_sigma : float
        Spread of the sensor's velocity [m/s] and position [m] about zero (the motion bound).
    correlation_time : float
        Time [s] over which the velocity, position and magnetic disturbances decorrelate.
    heading_sigma : float
        Heading noise of the magnetometer [rad] (disturbances of the field).
    rest_gyro, rest_accel : float
        Rest thresholds on the RMS deviation of the gyro [rad/s] and accelerometer [m/s^2]
        from their low passes (and the low-passed rate must stay below ``4 * rest_gyro``).
    rest_time : float
        How long [s] the thresholds must hold before a sample counts as rest.
    rest_tau : float
        Time constant [s] of the rest detector's low passes.
    init_time : float
        Samples of the first ``init_time`` seconds give the initial tilt, heading and |g|.
    tilt_sigma, gyro_bias_sigma : float
        Initial standard deviations of the tilt [rad] and the gyro bias [rad/s].
    gravity : float or None
        Magnitude of gravity [m/s^2]; ``None`` takes the initial accelerometer's (which also
        absorbs an accelerometer scale error).
    """

    gyro_noise: float = 4e-3
    gyro_bias_walk: float = 1e-4
    accel_noise: float = 0.05
    velocity_sigma: float = 0.5
    position_sigma: float = 0.3
    correlation_time: float = 0.1
    heading_sigma: float = 0.5
    rest_gyro: float = float(np.radians(2.0))
    rest_accel: float = 0.5
    rest_time: float = 1.5
    rest_tau: float = 0.5
    init_time: float = 0.5
    tilt_sigma: float = float(np.radians(2.0))
    gyro_bias_sigma: float = float(np.radians(1.0))
    gravity: float | None = None

    def __post_init__(self):
        for name, value in asdict(self).items():
            if name == "gravity" and value is None:
                continue
            if not (np.isfinite(value) and value > 0):
                raise InputError(f"ImuOrientationModel.{name} must be finite and > 0: {value!r}")

    def noise(self) -> np.ndarray:
        """``(gyro_noise, gyro_bias_walk, accel_noise)`` (3,) for the kernels."""
        return np.array([self.gyro_noise, self.gyro_bias_walk, self.accel_noise])

    def bounds(self) -> np.ndarray:
        """``(velocity_sigma, position_sigma, correlation_time, heading_sigma)`` (4,)."""
        return np.array(
            [self.velocity_sigma, self.position_sigma, self.correlation_time, self.heading_sigma]
        )

    def rest(self) -> np.ndarray:
        """``(rest_gyro, rest_accel, rest_time, rest_tau)`` (4,)."""
        return np.array([self.rest_gyro, self.rest_accel, self.rest_time, self.rest_tau])

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class ImuOrientationResult:
    """Output of :func:`run_imu_orientation`.

    Attributes
    ----------
    quaternions : ndarray (M, 4)
        ``R_w_s`` after each sample ``(x, y, z, w)``.
    rest : ndarray of bool (M,)
        Samples the rest detector classified as rest.
    gyro_bias : ndarray (3,)
        Final gyro bias estimate [rad/s].
    covariance : ndarray (12, 12)
        Final error-state covariance over ``(dtheta, db_g, dv, dp)``.
    gravity : float
        Magnitude of gravity used [m/s^2].
    """

    quaternions: np.ndarray
    rest: np.ndarray
    gyro_bias: np.ndarray
    covariance: np.ndarray
    gravity: float


def initial_orientation(accel, mag=None) -> np.ndarray:
    """``R_w_s`` (3, 3) of an IMU at rest from its mean specific force (and magnetic field).

    Parameters
    ----------
    accel : array_like (3,)
        Specific force in the sensor frame (points up at rest).
    mag : array_like (3,), optional
        Magnetic field in the sensor frame; the world's ``y`` axis is its horizontal part
        (north). Without it the heading is the smallest rotation that levels the sensor.
    """
    up = np.asarray(accel, dtype=float).reshape(3)
    n_up = np.linalg.norm(up)
    if not np.isfinite(n_up) or n_up == 0.0:
        raise InputError(f"cannot level the IMU: accelerometer reads {up.tolist()}")
    up = up / n_up
    if mag is None:
        axis = np.cross(up, [0.0, 0.0, 1.0])
        s, c = np.linalg.norm(axis), float(up[2])
        if s < 1e-12:
            return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
        return _okernel.so3_exp(axis / s * np.arctan2(s, c))
    m = np.asarray(mag, dtype=float).reshape(3)
    north = m - (m @ up) * up
    n_north = np.linalg.norm(north)
    if not np.isfinite(n_north) or n_north < 1e-9 * max(np.linalg.norm(m), 1e-300):
        raise InputError(f"magnetic field {m.tolist()} has no horizontal part: no heading")
    north /= n_north
    east = np.cross(north, up)
    return np.vstack([east, north, up])  # rows: world axes in the sensor frame


def run_imu_orientation(
    imu_t, gyro, accel, mag=None, model: ImuOrientationModel | None = None
) -> ImuOrientationResult:
    """Orientation ``R_w_s`` of every sample of an IMU recording, from the IMU alone.

    Parameters
    ----------
    imu_t : array_like (M,)
        Strictly increasing sample times [s].
    gyro : array_like (M, 3)
        Angular velocity in the sensor frame [rad/s].
    accel : array_like (M, 3)
        Specific force in the sensor frame [m/s^2].
    mag : array_like (M, 3), optional
        Magnetic field in the sensor frame (any unit). Given, the heading is absolute
        (``y`` = magnetic north, "9D"); else it starts at zero and drifts with the gyro ("6D").
    model : ImuOrientationModel, optional

    Returns
    -------
    ImuOrientationResult
    """
    model = model if model is not None else ImuOrientationModel()
    t = np.ascontiguousarray(imu_t, dtype=float).reshape(-1)
    w = np.ascontiguousarray(gyro, dtype=float)
    a = np.ascontiguousarray(accel, dtype=float)
    m_count = t.shape[0]
    arrays = {"gyro": w, "accel": a}
    if mag is not None:
        arrays["mag"] = np.ascontiguousarray(mag, dtype=float)
    for name, arr in arrays.items():
        if arr.shape != (m_count, 3):
            raise InputError(f"IMU {name} must have shape ({m_count}, 3), got {arr.shape}")
        bad = ~np.isfinite(arr).all(axis=1)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise InputError(f"IMU {name} sample {k} is not finite: {arr[k].tolist()}")
    if m_count < 2:
        raise InputError(f"need at least two IMU samples, got {m_count}")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(~(np.diff(t) > 0))[0]) + 1 if np.isfinite(t).all() else 0
        raise InputError(f"IMU times must be finite and increase strictly (sample {k})")
    head = t <= t[0] + model.init_time
    m0 = arrays["mag"][head].mean(axis=0) if mag is not None else None
    r0, x, P, g = _initial_state(model, a[head].mean(axis=0), m0)
    out_r = np.empty((m_count, 3, 3))
    out_rest = np.zeros(m_count, dtype=bool)
    mags = arrays["mag"] if mag is not None else np.zeros((m_count, 3))
    kernels().run_orientation(
        t, w, a, mags, mag is not None, r0, x, P, g, model.noise(), model.bounds(), model.rest(),
        out_r, out_rest,
    )  # fmt: skip
    return ImuOrientationResult(quat_from_matrix(out_r), out_rest, x[0:3].copy(), P, -g[2])


def _initial_state(model: ImuOrientationModel, accel, mag):
    """``(R_w_s, x (9,), P (12, 12), g (3,))`` from the mean accelerometer (and field) at rest."""
    r0 = np.ascontiguousarray(initial_orientation(accel, mag))
    g_mag = float(np.linalg.norm(accel)) if model.gravity is None else float(model.gravity)
    P = np.zeros((12, 12))
    heading_var = model.heading_sigma**2 if mag is not None else np.pi**2
    # tilt about the world's horizontal axes, heading about its vertical, in the sensor frame
    P[0:3, 0:3] = r0.T @ np.diag([model.tilt_sigma**2] * 2 + [heading_var]) @ r0
    P[3:6, 3:6] = np.eye(3) * model.gyro_bias_sigma**2
    P[6:9, 6:9] = np.eye(3) * model.velocity_sigma**2
    P[9:12, 9:12] = np.eye(3) * model.position_sigma**2
    return r0, np.zeros(9), P, np.array([0.0, 0.0, -g_mag])


class ImuOrientationFilter:
    """The filter of :func:`run_imu_orientation`, one sample at a time (live IMUs).

    The first ``model.init_time`` seconds of samples are buffered; the first sample after
    them initialises the filter from their mean and replays them, so from then on every
    :meth:`update` gives the same orientation as :func:`run_imu_orientation` on the whole
    recording.

    Parameters
    ----------
    model : ImuOrientationModel, optional
    magnetometer : bool
        Fuse a magnetometer ("9D"); :meth:`update` then needs ``mag``.
    """

    def __init__(self, model: ImuOrientationModel | None = None, magnetometer: bool = False):
        self.model = model if model is not None else ImuOrientationModel()
        self.magnetometer = bool(magnetometer)
        self._k = kernels()
        self._args = (self.model.noise(), self.model.bounds(), self.model.rest())
        self._buffer: list = []
        self._state = None
        self._t: float | None = None

    @property
    def initialized(self) -> bool:
        return self._state is not None

    @property
    def quaternion(self) -> np.ndarray | None:
        """Current ``R_w_s`` ``(x, y, z, w)`` (``None`` while initialising)."""
        return None if self._state is None else quat_from_matrix(self._state[0])

    @property
    def at_rest(self) -> bool:
        """Whether the rest detector classifies the last sample as rest."""
        return self._state is not None and self._det[8] >= self.model.rest_time

    @property
    def gyro_bias(self) -> np.ndarray | None:
        """Gyro bias estimate [rad/s] (``None`` while initialising)."""
        return None if self._state is None else self._state[1][0:3].copy()

    def update(self, t: float, gyro, accel, mag=None) -> np.ndarray | None:
        """Fuse one sample (sensor frame: rad/s, m/s^2, any field unit) at time ``t`` [s].

        Returns ``R_w_s`` ``(x, y, z, w)`` after it, or ``None`` while initialising. Raises
        ``ValueError`` naming the problem for a non-finite sample or a time that does not
        increase.
        """
        t = float(t)
        w = np.asarray(gyro, dtype=float).reshape(3)
        a = np.asarray(accel, dtype=float).reshape(3)
        m = np.zeros(3) if mag is None else np.asarray(mag, dtype=float).reshape(3)
        if self.magnetometer and mag is None:
            raise InputError(f"IMU sample at t={t}: the filter fuses a magnetometer, mag missing")
        if not (np.isfinite(t) and np.isfinite(w).all() and np.isfinite(a).all()
                and np.isfinite(m).all()):  # fmt: skip
            raise InputError(f"IMU sample at t={t} is not finite: gyro {w}, accel {a}, mag {m}")
        if self._t is not None and t <= self._t:
            raise InputError(f"IMU sample at t={t} is not after the previous one (t={self._t})")
        if self._state is None:
            if not self._buffer or t <= self._buffer[0][0] + self.model.init_time:
                self._buffer.append((t, w, a, m))
                self._t = t
                return None
            self._start()
        self._step(t, w, a, m)
        return self.quaternion

    def _start(self) -> None:
        acc = np.mean([s[2] for s in self._buffer], axis=0)
        mag = np.mean([s[3] for s in self._buffer], axis=0) if self.magnetometer else None
        self._state = list(_initial_state(self.model, acc, mag))
        self._det = np.zeros(10)
        self._t = None
        for sample in self._buffer:
            self._step(*sample)
        self._buffer = []

    def _step(self, t, w, a, m) -> None:
        r, x, P, g = self._state
        dt = 0.0 if self._t is None else t - self._t
        self._state[0] = self._k.orientation_sample(
            r, x, P, self._det, w, a, m, self.magnetometer, dt, g, *self._args
        )
        self._t = t


def heading_inclination_errors(q_est, q_ref) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orientation error split as in BROAD (Laidig et al., Data 2021): heading, inclination, total.

    The error rotation ``E = R_est R_ref^T`` is taken in the earth frame (z up) and split into
    a rotation about the vertical (heading) and one about a horizontal axis (inclination, the
    angle between the two estimates of "up": ``acos(e_z . E e_z)``).

    Parameters
    ----------
    q_est, q_ref : array_like (..., 4)
        ``R_w_s`` estimated and true ``(x, y, z, w)``; both earth frames z-up.

    Returns
    -------
    heading, inclination, total : ndarray (...)
        Error angles [rad] in ``[0, pi]``.
    """
    qe = np.asarray(q_est, dtype=float)
    qr = np.asarray(q_ref, dtype=float)
    qe = qe / np.linalg.norm(qe, axis=-1, keepdims=True)
    qr = qr / np.linalg.norm(qr, axis=-1, keepdims=True)
    e = quat_multiply(qe, quat_conjugate(qr))
    w, z = np.abs(e[..., 3]), e[..., 2]
    total = 2.0 * np.arccos(np.clip(w, 0.0, 1.0))
    # twist about z: (z, w) normalised; swing: the rest (cos(incl / 2) = sqrt(w^2 + z^2))
    heading = 2.0 * np.arctan2(np.abs(z), w)
    heading = np.minimum(heading, 2.0 * np.pi - heading)
    inclination = 2.0 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0))
    return heading, inclination, total
