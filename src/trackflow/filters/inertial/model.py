"""The inertial filter's model: IMU noise, IMU-to-body extrinsics and the filter settings.

Frames: ``w`` the tracker's world frame, ``b`` the tracked body (what the pose sensor reports,
``T_w_b``), ``s`` the IMU's sensor frame, rigidly mounted on the body at ``T_b_s``.

Strapdown model (``mode="strapdown"``), nominal state ``p = p_w_s``, ``v = v_w_s``,
``R = R_w_s``, gyro bias ``b_g`` and accelerometer bias ``b_a``::

    p' = v        v' = R (f - b_a) + g        R' = R [omega - b_g]x        b_g' = n_bg   b_a' = n_ba

with the gyro reading ``omega`` and the specific force ``f`` [m/s^2]. The 15-dimensional error
state is ``(dp, dv, dtheta, db_g, db_a)``: ``p_true = p + dp`` (world), ``R_true = R Exp(dtheta)``
(right, sensor frame), as trackflow's pose covariance (``docs/conventions.md``). A pose
measurement ``T_w_b = T_w_s T_s_b`` has the error ``(dp_b, dtheta_b)`` with
``J_pose_x = [[I, 0, -R [t_s_b]x, 0, 0], [0, 0, R_b_s, 0, 0]]``.

Gyro-only model (``mode="gyro"``): the gyro drives the orientation (with its bias) and the
position follows a constant-velocity model with white acceleration; 12 error states
``(dp, dv, dtheta, db_g)``. It needs no accelerometer and no gravity.

The equations and their Jacobians are in :mod:`.kernel`; ``docs/inertial.md`` has the
derivation and measured figures.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from trackflow.math import check_quaternion, quat_to_matrix

from ...errors import InputError
from .extrapolation import GyroExtrapolation

__all__ = ["GRAVITY", "MODES", "ImuExtrinsics", "ImuNoise", "InertialModel"]

#: Standard gravity [m/s^2].
GRAVITY = 9.80665
#: Filter variants.
MODES = ("strapdown", "gyro")


@dataclass(frozen=True)
class ImuNoise:
    """White-noise densities of an IMU (data-sheet units, one sigma per axis).

    Attributes
    ----------
    gyro : float
        Angular random walk [rad/s/sqrt(Hz)].
    accel : float
        Velocity random walk [m/s^2/sqrt(Hz)]. In ``mode="gyro"`` it is the white acceleration
        of the constant-velocity position model instead.
    gyro_bias : float
        Gyro bias random walk [rad/s^2/sqrt(Hz)].
    accel_bias : float
        Accelerometer bias random walk [m/s^3/sqrt(Hz)].
    """

    gyro: float = 2e-3
    accel: float = 2e-2
    gyro_bias: float = 2e-5
    accel_bias: float = 3e-3

    def __post_init__(self):
        for name in ("gyro", "accel", "gyro_bias", "accel_bias"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise InputError(f"ImuNoise.{name} must be finite and >= 0, got {v!r}")
        if self.gyro <= 0 or self.accel <= 0:
            raise InputError("ImuNoise.gyro and ImuNoise.accel must be > 0")

    def as_array(self) -> np.ndarray:
        """``(gyro, accel, gyro_bias, accel_bias)``, shape (4,)."""
        return np.array([self.gyro, self.accel, self.gyro_bias, self.accel_bias], dtype=float)

    def scaled(self, gyro: float = 1.0, accel: float = 1.0) -> ImuNoise:
        """The same densities with the white parts scaled (the tuning's knobs)."""
        return replace(self, gyro=self.gyro * gyro, accel=self.accel * accel)

    def as_dict(self) -> dict:
        return {k: float(getattr(self, k)) for k in ("gyro", "accel", "gyro_bias", "accel_bias")}


@dataclass(frozen=True)
class ImuExtrinsics:
    """Pose of the IMU on the body, ``T_b_s``: rotation ``(x, y, z, w)`` and lever arm [m].

    Attributes
    ----------
    quaternion : ndarray, shape (4,)
        ``R_b_s``: maps sensor-frame vectors into the body frame.
    lever_arm : ndarray, shape (3,)
        ``t_b_s``: the IMU's origin in the body frame [m].
    """

    quaternion: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))
    lever_arm: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        q = np.asarray(self.quaternion, dtype=float).reshape(4)
        check_quaternion(q)
        t = np.asarray(self.lever_arm, dtype=float).reshape(3)
        if not np.all(np.isfinite(t)):
            raise InputError(f"lever arm must be finite, got {t.tolist()}")
        object.__setattr__(self, "quaternion", q)
        object.__setattr__(self, "lever_arm", t)

    def sensor_to_body(self) -> tuple[np.ndarray, np.ndarray]:
        """``(R_s_b (3, 3), t_s_b (3,))``: the body in the sensor frame, ``T_s_b = T_b_s^-1``."""
        r_bs = quat_to_matrix(self.quaternion)
        return np.ascontiguousarray(r_bs.T), np.ascontiguousarray(-(r_bs.T @ self.lever_arm))

    def as_dict(self) -> dict:
        return {"quaternion": self.quaternion.tolist(), "lever_arm": self.lever_arm.tolist()}


@dataclass(frozen=True)
class InertialModel:
    """Settings of :class:`~trackflow.filters.InertialFilter`.

    Attributes
    ----------
    mode : {"strapdown", "gyro"}
        Strapdown (gyro + accelerometer drive orientation and position, both biases) or the
        lighter variant where the gyro drives the orientation only.
    noise : ImuNoise
    extrinsics : ImuExtrinsics
        ``T_b_s``.
    gravity : ndarray, shape (3,)
        Gravity in the world frame [m/s^2] (``(0, 0, -9.80665)`` for a z-up world; see
        :func:`~trackflow.filters.estimate_gravity` for trackers with another up axis).
    gyro_bias_sigma, accel_bias_sigma : float
        Initial standard deviation of the biases [rad/s], [m/s^2].
    gravity_sigma : float
        Per-axis accelerometer sigma [m/s^2] of :meth:`InertialFilter.update_gravity` (an
        accelerometer sample fused as the direction of gravity). Orientation from the IMU
        alone is :func:`~trackflow.filters.run_imu_orientation` with its own model.
    gate_probability : float or None
        Chi-square gate on the pose innovation (``None``: no gate).
    input_hold : {"trapezoid", "preceding"}
        How IMU samples are integrated: the mean of the two samples bounding each interval
        (point samples), or each sample over the interval that ends at its stamp (the output
        of a digital IMU that averages internally; what BROAD's reference alignment assumes).
    smoothing_s : float
        Time constant [s] of the input trend that predictions extrapolate (bias-corrected
        angular velocity and world acceleration, double exponential smoothing); 0 holds the
        last sample.
    use_slope : bool
        Extrapolate the trend's slope too (angular acceleration, jerk).
    gyro_extrapolation : GyroExtrapolation or None
        Learned rotation extrapolation from the gyro history (replaces the trend's rotation).
    accel_extrapolation : GyroExtrapolation or None
        Learned position extrapolation (beyond ``v h``) from the world-acceleration history
        (fitted with ``integrals=2``; replaces the trend's acceleration).
    """

    mode: str = "strapdown"
    noise: ImuNoise = field(default_factory=ImuNoise)
    extrinsics: ImuExtrinsics = field(default_factory=ImuExtrinsics)
    gravity: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -GRAVITY]))
    gyro_bias_sigma: float = 0.05
    accel_bias_sigma: float = 0.3
    gravity_sigma: float = 0.5
    gate_probability: float | None = None
    input_hold: str = "trapezoid"
    smoothing_s: float = 0.0
    use_slope: bool = False
    gyro_extrapolation: GyroExtrapolation | None = None
    accel_extrapolation: GyroExtrapolation | None = None

    def __post_init__(self):
        if self.mode not in MODES:
            raise InputError(f"mode must be one of {MODES}, got {self.mode!r}")
        g = np.asarray(self.gravity, dtype=float).reshape(3)
        if not np.all(np.isfinite(g)):
            raise InputError(f"gravity must be finite, got {g.tolist()}")
        object.__setattr__(self, "gravity", g)
        for name in ("gyro_bias_sigma", "accel_bias_sigma", "gravity_sigma"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"{name} must be finite and > 0, got {v!r}")
        if self.input_hold not in ("trapezoid", "preceding"):
            raise InputError(
                f"input_hold must be 'trapezoid' or 'preceding', got {self.input_hold!r}"
            )
        if not (np.isfinite(self.smoothing_s) and self.smoothing_s >= 0):
            raise InputError(f"smoothing_s must be finite and >= 0, got {self.smoothing_s!r}")
        p = self.gate_probability
        if p is not None and not 0.0 < p < 1.0:
            raise InputError(f"gate_probability must be in (0, 1) or None, got {p!r}")

    @property
    def n_states(self) -> int:
        """Error-state dimension: 15 (strapdown) or 12 (gyro)."""
        return 15 if self.mode == "strapdown" else 12

    def gate(self) -> float:
        """NIS threshold of the pose gate (0 = none)."""
        if self.gate_probability is None:
            return 0.0
        from scipy.stats import chi2

        return float(chi2.ppf(self.gate_probability, 6))

    def initial_covariance(self, pose_covariance: np.ndarray, velocity_sigma: float) -> np.ndarray:
        """Error-state covariance (n, n) after initialising from one pose of the sensor.

        ``pose_covariance`` (6, 6) is over ``(dp, dtheta)`` of ``T_w_s``.
        """
        n = self.n_states
        P = np.zeros((n, n))
        P[0:3, 0:3] = pose_covariance[:3, :3]
        P[0:3, 6:9] = pose_covariance[:3, 3:]
        P[6:9, 0:3] = pose_covariance[3:, :3]
        P[6:9, 6:9] = pose_covariance[3:, 3:]
        P[3:6, 3:6] = np.eye(3) * velocity_sigma**2
        P[9:12, 9:12] = np.eye(3) * self.gyro_bias_sigma**2
        if n == 15:
            P[12:15, 12:15] = np.eye(3) * self.accel_bias_sigma**2
        return P

    def as_dict(self) -> dict:
        return {
            "mode": self.mode,
            "noise": self.noise.as_dict(),
            "extrinsics": self.extrinsics.as_dict(),
            "gravity": self.gravity.tolist(),
            "gyro_bias_sigma": self.gyro_bias_sigma,
            "accel_bias_sigma": self.accel_bias_sigma,
            "gravity_sigma": self.gravity_sigma,
            "gate_probability": self.gate_probability,
            "input_hold": self.input_hold,
            "smoothing_s": self.smoothing_s,
            "use_slope": self.use_slope,
            "gyro_extrapolation": None
            if self.gyro_extrapolation is None
            else self.gyro_extrapolation.as_dict(),
            "accel_extrapolation": None
            if self.accel_extrapolation is None
            else self.accel_extrapolation.as_dict(),
        }

    def extrapolation_weights(self, horizons) -> tuple[np.ndarray, np.ndarray]:
        """Learned gyro and acceleration weights ((H, L), (H, La)) for ``horizons`` [s];
        (H, 0) where there is no learned model."""
        h = np.asarray(horizons, dtype=float).reshape(-1)
        out = []
        for ex in (self.gyro_extrapolation, self.accel_extrapolation):
            out.append(np.zeros((h.shape[0], 0)) if ex is None else ex.for_horizons(h))
        return out[0], out[1]
