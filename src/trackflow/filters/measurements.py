"""User-defined measurements of the pose (thesis 7.3.2): helpers for :class:`MeasurementFunction`.

A measurement is an object with ``covariance`` (m, m) and ``residual(pose) -> (y, J_h_pose)``
(:class:`trackflow.filters.MeasurementFunction`); a filter with a pose in its state integrates it
with :meth:`trackflow.filters.PoseKalmanFilter.update_measurement`. :func:`numerical_jacobian`
differentiates ``h`` numerically so that an analytic ``J_h_pose`` can be checked.
"""

from __future__ import annotations

import numpy as np

from trackflow.math import Pose, quat_exp, quat_multiply

from .contract import MeasurementFunction

__all__ = ["numerical_jacobian", "perturb"]


def perturb(pose: Pose, e: np.ndarray) -> Pose:
    """``T [+] e``: ``t + e[:3]`` (frame a, m), ``R Exp(e[3:])`` (rad), docs/conventions.md."""
    e = np.asarray(e, dtype=float)
    return Pose(pose.position + e[:3], quat_multiply(pose.quaternion, quat_exp(e[3:])))


def numerical_jacobian(measurement: MeasurementFunction, pose: Pose, eps: float = 1e-6):
    """Central-difference ``J_h_pose`` (m, 6) of a measurement at ``pose``.

    ``h(T [+] e) = z - y(T [+] e)``, so column ``k`` is ``-(y(T [+] eps u_k) - y(T [-] eps u_k))
    / (2 eps)``.
    """
    y0, _ = measurement.residual(pose)
    J = np.empty((np.size(y0), 6))
    for k in range(6):
        d = np.zeros(6)
        d[k] = eps
        yp, _ = measurement.residual(perturb(pose, d))
        ym, _ = measurement.residual(perturb(pose, -d))
        J[:, k] = -(np.asarray(yp) - np.asarray(ym)) / (2 * eps)
    return J
