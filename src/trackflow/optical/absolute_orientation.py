"""Absolute orientation: the pose of a rigid body from measured points of its markers.

Closed form first (:func:`trackflow.math.umeyama`: the weighted cross-covariance's SVD, no
scale), then
Gauss-Newton with each point's full 3x3 covariance, which makes the estimate the
best linear unbiased one and gives its 6x6 covariance in trackflow's convention
(``docs/conventions.md``): error ``(dt, dtheta)`` with ``t_true = t + dt`` (world frame, m)
and ``R_true = R Exp(dtheta)`` (body frame, rad).

A measured point ``x_i`` of model point ``m_i`` is ``x_i = R m_i + t + n_i`` with
``n_i ~ N(0, C_i)``; the residual's Jacobian with respect to the pose error is
``J_i = [I, -R [m_i]x]`` and the covariance is ``(sum_i J_i^T C_i^-1 J_i)^-1``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..math import Pose, UncertainPose, kernels_for
from . import _kernels

__all__ = ["PoseFit", "fit_pose"]


@dataclass
class PoseFit:
    """Result of :func:`fit_pose`.

    Attributes
    ----------
    pose : UncertainPose
        ``T_world_body`` with its 6x6 covariance over ``(dt, dtheta)``.
    chi2 : float
        ``sum_i r_i^T C_i^-1 r_i`` (chi-square with ``3 M - 6`` degrees of freedom).
    point_chi2 : ndarray (M,)
        Each point's Mahalanobis residual.
    """

    pose: UncertainPose
    chi2: float
    point_chi2: np.ndarray


def fit_pose(model, measured, covariance, iterations: int = 2) -> PoseFit:
    """Pose ``T_world_body`` of a rigid body and its covariance from measured marker points.

    Parameters
    ----------
    model : array_like (M, 3)
        Marker positions in the body frame [m].
    measured : array_like (M, 3)
        The same markers measured in the world frame [m].
    covariance : array_like (M, 3, 3)
        Covariance of each measured point [m^2] (independent points).
    iterations : int
        Gauss-Newton steps after the closed form (one is enough to first order).

    Returns
    -------
    PoseFit
    """
    m = np.asarray(model, dtype=float)
    x = np.asarray(measured, dtype=float)
    C = np.asarray(covariance, dtype=float)
    if C.shape != m.shape + (3,) or x.shape != m.shape:
        raise InputError(
            f"model (M, 3), measured (M, 3) and covariance (M, 3, 3) must agree, got "
            f"{m.shape}, {x.shape}, {C.shape}"
        )
    if not (np.all(np.isfinite(m)) and np.all(np.isfinite(x)) and np.all(np.isfinite(C))):
        raise InputError("model, measured points and covariances must be finite")
    if len(m) < 3:
        raise InputError(f"need at least 3 points, got {len(m)}")
    sv = np.linalg.svd(m - m.mean(axis=0), compute_uv=False)
    if sv[1] <= 1e-9 * sv[0]:
        raise InputError("the points are collinear: the rotation about their line is unknown")
    if np.any(np.linalg.eigvalsh(C)[:, 0] <= 0):
        raise InputError("a point covariance is not positive definite")
    t, q, cov, point_chi2 = kernels_for(_kernels).fit_pose_cov(
        np.ascontiguousarray(m), np.ascontiguousarray(x), np.ascontiguousarray(C), int(iterations)
    )
    pose = UncertainPose(Pose(t, q, normalize=True), cov)
    return PoseFit(pose, float(point_chi2.sum()), point_chi2)
