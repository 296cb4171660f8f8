"""Ude's quaternion-space filter behind the streaming pose-filter contract.

A pose measurement enters the adjustment of eq. 24 *directly* as a term of the least-squares
criterion, ``|W_z (p - z_p, Log(q z_q^-1))|^2`` with ``W_z^T W_z = C_z^-1`` (world-frame rotation
error, the filter's own parameterisation), next to the prediction prior; Gauss-Newton on the
manifold then minimises it as it would image features. This is exact for a pose sensor (no
virtual cameras or marker model whose geometry would re-shape the noise). ``predict(t)`` after
the newest measurement is the constant-velocity prediction (eqs. 11-23); in the past it
interpolates the two stored filtered poses around ``t`` with a covariance that bounds every
correlation between them (:func:`trackflow.filters.pose_history.interpolate_estimates`). The
adapter also counts ``unconverged`` (accepted adjustments whose Gauss-Newton iteration hit
``max_iterations`` before the stopping rule of eq. 29).
"""

from __future__ import annotations

import numpy as np

from trackflow.math import (
    UncertainPose,
    quat_conjugate,
    quat_log,
    quat_multiply,
    quat_to_matrix,
    so3_right_jacobian_inverse,
)

from ...errors import InputError
from ..pose_history import GatedPoseFilter
from .gauss_newton import QuaternionSpaceFilter, QuaternionSpaceState

__all__ = ["QuaternionSpacePoseFilter"]

# Added to the diagonal of a pose measurement's covariance before whitening it (m^2, rad^2):
# lets exact poses (zero covariance) in without changing any realistic covariance (>= 1e-10).
_VARIANCE_FLOOR = 1e-14


class _PoseTerm:
    """A pose measurement as a term of Ude's least-squares criterion (eq. 24).

    Offers the one method :func:`manifold_gn.adjust_state` asks of an observation,
    ``whitened_residual(p, q) -> (h, J_h_pose)``: ``h = W_z (p - z_p, Log(q z_q^-1))`` with
    ``W_z^T W_z = C_z^-1``, ``C_z`` the measurement covariance over the filter's error
    ``(e_p, e_phi)`` (``p_true = p + e_p``, ``q_true = Exp(e_phi) q``, world frame): from
    trackflow's ``(dt, dtheta)``, ``e_phi = R dtheta``, ``C_z = T C T^T``, ``T = diag(I, R)``.
    ``J_h_pose`` is over ``(dp, dphi)`` of ``p + dp``, ``Exp(dphi) q``:
    ``d Log(Exp(dphi) q z_q^-1) / d dphi = J_l^-1(Log(q z_q^-1))``.
    """

    size = 6

    def __init__(self, z: UncertainPose):
        self.position = z.position
        self.quaternion = z.quaternion
        self.covariance = self.world_covariance(z)
        L = np.linalg.cholesky(self.covariance + _VARIANCE_FLOOR * np.eye(6))
        self.whitening = np.linalg.solve(L, np.eye(6))

    @staticmethod
    def world_covariance(z: UncertainPose) -> np.ndarray:
        """``C_z = T C T^T`` with ``T = diag(I, R)`` (trackflow -> world-frame rotation error)."""
        T = np.eye(6)
        T[3:, 3:] = quat_to_matrix(z.quaternion)
        c = T @ z.covariance @ T.T
        return 0.5 * (c + c.T)

    def residual(self, position, quaternion) -> tuple[np.ndarray, np.ndarray]:
        """Unwhitened ``r = (p - z_p, Log(q z_q^-1))`` and ``J_r_pose`` (6, 6)."""
        phi = quat_log(quat_multiply(np.asarray(quaternion), quat_conjugate(self.quaternion)))
        r = np.concatenate([np.asarray(position) - self.position, phi])
        J = np.eye(6)
        J[3:, 3:] = so3_right_jacobian_inverse(-phi)  # J_l^-1(phi) = J_r^-1(-phi)
        return r, J

    def whitened_residual(self, position, quaternion) -> tuple[np.ndarray, np.ndarray]:
        r, J = self.residual(position, quaternion)
        return self.whitening @ r, self.whitening @ J


class QuaternionSpacePoseFilter(GatedPoseFilter):
    """:class:`QuaternionSpaceFilter` with the dataflow's pose-filter protocol.

    Each pose measurement is one term of the least-squares criterion of eq. 24, adjusted with
    the prediction prior by Gauss-Newton on the manifold (module docstring, :class:`_PoseTerm`).

    Parameters
    ----------
    q_a, q_alpha : float
        White linear / angular acceleration densities: Ude's ``a`` [m^2/s^3] and ``alpha``
        [rad^2/s^3] (eq. 23).
    history : float
        Seconds of filtered poses kept for past queries.
    gate_probability : float or None
        Chi-square gate on the 6-dof NIS of the measurement against the prediction.
    reset_after : int
        Consecutive gated measurements after which the next one re-initialises the filter.
    velocity_variance, angular_velocity_variance : float
        Initial variances of the zero velocities [(m/s)^2, (rad/s)^2] (the paper: 1e8; the
        default 1e2 matches the pose KF's prior of 10 m/s and 10 rad/s).
    method, gradient_tolerance, max_iterations
        Options of :class:`QuaternionSpaceFilter` (Gauss-Newton or Levenberg-Marquardt).

    Attributes
    ----------
    state : QuaternionSpaceState or None
        The filtered state at :attr:`time` (``(p, q, v, w)`` with 12x12 covariance).
    """

    _extra_counters = ("unconverged",)
    _correlated = True  # successive filtered states are correlated (cross-covariance not kept)

    def __init__(
        self,
        q_a: float,
        q_alpha: float,
        *,
        history: float = 1.0,
        gate_probability: float | None = 0.999,
        reset_after: int = 10,
        velocity_variance: float = 1e2,
        angular_velocity_variance: float = 1e2,
        method: str = "gauss_newton",
        gradient_tolerance: float = 1e-6,
        max_iterations: int = 20,
    ):
        self.filter = QuaternionSpaceFilter(
            a=q_a,
            alpha=q_alpha,
            method=method,
            gradient_tolerance=gradient_tolerance,
            max_iterations=max_iterations,
        )
        if not (velocity_variance > 0 and angular_velocity_variance > 0):
            raise InputError("initial velocity variances must be > 0")
        self._init_var = (float(velocity_variance), float(angular_velocity_variance))
        self.state: QuaternionSpaceState | None = None
        super().__init__(history, gate_probability, reset_after)

    def _restart(self) -> None:
        self.state = None

    def _accepts_time(self, t: float) -> bool:
        return t >= self._t  # a second pose at the same time is fused (prediction over 0 s)

    def _first(self, t: float, z: UncertainPose) -> UncertainPose:
        self.state = self.filter.initial_state(
            t, z.position, z.quaternion, _PoseTerm.world_covariance(z), *self._init_var
        )
        return self.state.uncertain_pose()

    def _nis(self, t: float, z: UncertainPose) -> float:
        pred = self.filter.predict(self.state, t)
        term = _PoseTerm(z)
        r, _ = term.residual(pred.position, pred.quaternion)
        return self._innovation_nis(-r, pred.covariance[:6, :6] + term.covariance)

    def _step(self, t: float, z: UncertainPose) -> UncertainPose:
        pred = self.filter.predict(self.state, t)
        state, report = self.filter.update(pred, [_PoseTerm(z)])
        if not report.converged:
            self._counts["unconverged"] += 1
        self.state = state
        return state.uncertain_pose()

    def _forward(self, t: float) -> UncertainPose:
        return self.filter.predict(self.state, t).uncertain_pose()
