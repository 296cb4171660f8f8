"""Dorfmueller-Ulhaas's relative-motion EKF behind the streaming pose-filter contract.

:class:`RelativeMotionEKF` (``ekf``) estimates only the motion ``(omega, v, a)``; its pose at a
measurement time is the measured pose itself. ``predict(t)`` after the newest measurement is the
paper's F4 (:meth:`RelativeMotionEKF.predicted_pose`); in the past it interpolates the two stored
measured poses around ``t`` (lerp / slerp, :meth:`UncertainPose.interpolate`; the measurements
are independent, so the first-order covariance of the interpolation is exact for the
interpolated quantity; the model error of a straight interpolation is not included).
"""

from __future__ import annotations

import math

import numpy as np

from trackflow.math import UncertainPose, quat_rminus

from ...errors import InputError, NumericalError
from ..pose_history import GatedPoseFilter
from .ekf import RelativeMotionEKF, RelativeMotionState, process_noise

__all__ = ["RelativeMotionPoseFilter"]


class RelativeMotionPoseFilter(GatedPoseFilter):
    """:class:`RelativeMotionEKF` with the dataflow's pose-filter protocol (module docstring).

    Parameters
    ----------
    q_a : float
        White linear-acceleration density [m^2/s^3]: the velocity random walk of
        :func:`relative_motion.process_noise` gets ``velocity_sigma = sqrt(q_a)``.
    q_alpha : float
        White angular-acceleration density [rad^2/s^3] (``omega_sigma = sqrt(q_alpha)``).
    history : float
        Seconds of measured poses kept for past queries.
    origin : {"body", "world"}
        Motion origin of the EKF (``"body"`` keeps ``v`` the body's velocity far from the world
        origin; the paper uses ``"world"``).
    gate_probability : float or None
        Chi-square gate on the 6-dof NIS of the measurement against the F4 prediction from the
        previous pose (``None`` disables).
    reset_after : int
        Consecutive gated measurements after which the next one re-starts the filter.
    velocity_prior_sigma, omega_prior_sigma : float
        Prior standard deviations of ``v`` [m/s] and ``omega`` [rad/s] (mean zero).

    Notes
    -----
    The acceleration state of eq. 9 is held at zero (prior variance 1e-12, no random walk):
    a constant-velocity model like the other filters of the dataflow. The EKF's per-frame
    process noise is rebuilt for each interval from its length (variance ``sigma^2 dt``).
    """

    def __init__(
        self,
        q_a: float,
        q_alpha: float,
        *,
        history: float = 1.0,
        origin: str = "body",
        gate_probability: float | None = 0.999,
        reset_after: int = 10,
        velocity_prior_sigma: float = 10.0,
        omega_prior_sigma: float = 10.0,
    ):
        if not (q_a >= 0 and q_alpha >= 0 and math.isfinite(q_a) and math.isfinite(q_alpha)):
            raise InputError(f"q_a and q_alpha must be finite and >= 0, got {q_a}, {q_alpha}")
        if origin not in ("body", "world"):
            raise InputError(f"origin must be 'body' or 'world', got {origin!r}")
        self._sigmas = (math.sqrt(q_alpha), math.sqrt(q_a))
        self._origin = origin
        var = [omega_prior_sigma**2] * 3 + [velocity_prior_sigma**2] * 3 + [1e-12] * 3
        self._prior = RelativeMotionState(np.zeros(9), np.diag(var))
        self.ekf: RelativeMotionEKF
        super().__init__(history, gate_probability, reset_after)

    _correlated = False  # past queries interpolate independent measurements

    def _restart(self) -> None:
        self.ekf = RelativeMotionEKF(self._prior, np.zeros((9, 9)), origin=self._origin)

    def _accepts_time(self, t: float) -> bool:
        return t > self._t  # the EKF needs a positive interval

    def _first(self, t: float, z: UncertainPose) -> UncertainPose:
        self.ekf.step(t, z)
        return z

    def _nis(self, t: float, z: UncertainPose) -> float:
        pred = self.ekf.predicted_pose(t - self._t)
        r = np.concatenate(
            [
                z.position - pred.position,
                quat_rminus(z.quaternion, pred.quaternion),
            ]
        )  # (dt, dtheta) of z relative to the prediction, trackflow convention
        return self._innovation_nis(r, pred.covariance + z.covariance)

    def _step(self, t: float, z: UncertainPose) -> UncertainPose:
        dt = t - self._t
        self.ekf.Q = process_noise(dt, self._sigmas[0], self._sigmas[1], 0.0)
        self.ekf.step(t, z)
        if not np.all(np.isfinite(self.ekf.state.covariance)):
            raise NumericalError("non-finite EKF state")
        return z  # the EKF has no pose state: its pose at time t is the measurement

    def _forward(self, t: float) -> UncertainPose:
        return self.ekf.predicted_pose(t - self._t)
