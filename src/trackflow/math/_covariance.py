"""Converters between trackflow's pose covariance convention and those of other systems.

trackflow's error (``docs/conventions.md``): ``t_true = t + dt`` (frame a, metres),
``R_true = R Exp(dtheta)`` (right, radians), covariance over ``(dt, dtheta)``. Each ``cov_to_X``
returns ``J C J^T`` with the Jacobian of the other convention's error w.r.t. ours, and
``cov_from_X`` its exact inverse. All accept batches: covariance (..., 6, 6), quaternion
(..., 4) ``(x, y, z, w)``.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ._quaternion import quat_to_matrix

__all__ = [
    "cov_to_thesis",
    "cov_from_thesis",
    "cov_to_ros",
    "cov_from_ros",
    "cov_to_gtsam",
    "cov_from_gtsam",
    "cov_to_additive_quaternion",
    "cov_from_additive_quaternion",
    "quat_left_matrix",
]

_HALF = np.diag([1.0, 1.0, 1.0, 0.5, 0.5, 0.5])
_TWICE = np.diag([1.0, 1.0, 1.0, 2.0, 2.0, 2.0])


def _sandwich(j, c):
    out = j @ np.asarray(c, dtype=float) @ np.swapaxes(j, -1, -2)
    return 0.5 * (out + np.swapaxes(out, -1, -2))


def cov_to_thesis(covariance) -> np.ndarray:
    """To the thesis's / Ubitrack ErrorPose units: rotation error as the vector part ``e`` of
    a small quaternion ``(e, 1)``, ``e = dtheta / 2`` (first order). Rotation rows scale by 1/2."""
    return _sandwich(_HALF, covariance)


def cov_from_thesis(covariance) -> np.ndarray:
    """Inverse of :func:`cov_to_thesis`: ``dtheta = 2 e``."""
    return _sandwich(_TWICE, covariance)


def _rot_block(quaternion, transpose: bool) -> np.ndarray:
    r = quat_to_matrix(quaternion)
    if transpose:
        r = np.swapaxes(r, -1, -2)
    j = np.zeros(r.shape[:-2] + (6, 6))
    j[..., :3, :3] = np.eye(3)
    j[..., 3:, 3:] = r
    return j


def cov_to_ros(covariance, quaternion) -> np.ndarray:
    """To ROS ``PoseWithCovariance``: rotation error about the fixed axes of frame a.

    ROS perturbs on the left, ``R_true = Exp(dphi) R``, so ``dphi = R dtheta``; translation is
    the same. Returns the 6x6 matrix in ROS's order ``(x, y, z, rot_x, rot_y, rot_z)``.
    """
    return _sandwich(_rot_block(quaternion, transpose=False), covariance)


def cov_from_ros(covariance, quaternion) -> np.ndarray:
    """From ROS ``PoseWithCovariance`` (``dtheta = R^T dphi``)."""
    return _sandwich(_rot_block(quaternion, transpose=True), covariance)


def cov_to_gtsam(covariance, quaternion) -> np.ndarray:
    """To GTSAM ``Pose3`` tangent space ``xi = (omega, v)``, ``T_true = T Exp(xi)``.

    To first order ``dtheta = omega`` and ``dt = R v`` (GTSAM's translation error lives in
    frame b and comes second), so ``(omega, v) = [[0, I], [R^T, 0]] (dt, dtheta)``.
    """
    rt = np.swapaxes(quat_to_matrix(quaternion), -1, -2)
    j = np.zeros(rt.shape[:-2] + (6, 6))
    j[..., :3, 3:] = np.eye(3)
    j[..., 3:, :3] = rt
    return _sandwich(j, covariance)


def cov_from_gtsam(covariance, quaternion) -> np.ndarray:
    """From GTSAM ``Pose3`` (``(dt, dtheta) = [[0, R], [I, 0]] (omega, v)``)."""
    r = quat_to_matrix(quaternion)
    j = np.zeros(r.shape[:-2] + (6, 6))
    j[..., :3, 3:] = r
    j[..., 3:, :3] = np.eye(3)
    return _sandwich(j, covariance)


def quat_left_matrix(quaternion) -> np.ndarray:
    """``L(q)`` with ``q * p = L(q) p`` for quaternions ``(x, y, z, w)`` (thesis eq. 6.12)."""
    q = np.asarray(quaternion, dtype=float)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [
        [w, -z, y, x],
        [z, w, -x, y],
        [-y, x, w, z],
        [-x, -y, -z, w],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def cov_to_additive_quaternion(covariance, quaternion, scalar_variance: float = 0.0):
    """7x7 covariance of ``(t, q)`` with an additive quaternion error (thesis 6.1.4).

    ``q_true = q * (dtheta/2, 1) ~ q + dq`` with ``dq = L(q)[:, :3] dtheta / 2``. The error
    quaternion's scalar part has no variance to first order, so the 7x7 matrix is singular;
    ``scalar_variance`` adds that much variance along ``q`` itself (the thesis sets it to 1 to
    keep the matrix invertible; it does not change the 6x6 covariance recovered by
    :func:`cov_from_additive_quaternion`).

    Returns
    -------
    ndarray (..., 7, 7) over ``(t_x, t_y, t_z, q_x, q_y, q_z, q_w)``.
    """
    c = np.asarray(covariance, dtype=float)
    left = quat_left_matrix(quaternion)
    j = np.zeros(left.shape[:-2] + (7, 6))
    j[..., :3, :3] = np.eye(3)
    j[..., 3:, 3:] = 0.5 * left[..., :, :3]
    out = j @ c @ np.swapaxes(j, -1, -2)
    if scalar_variance:
        q = np.asarray(quaternion, dtype=float)
        out[..., 3:, 3:] += scalar_variance * q[..., :, None] * q[..., None, :]
    return 0.5 * (out + np.swapaxes(out, -1, -2))


def cov_from_additive_quaternion(covariance7, quaternion) -> np.ndarray:
    """6x6 covariance from the 7x7 additive-quaternion form: ``dtheta = 2 [q^* dq]_xyz``.

    The component of ``dq`` along ``q`` (a change of length, not a rotation) is dropped.
    """
    c = np.asarray(covariance7, dtype=float)
    if c.shape[-2:] != (7, 7):
        raise InputError(f"additive-quaternion covariance must be (..., 7, 7), got {c.shape}")
    left_t = np.swapaxes(quat_left_matrix(quaternion), -1, -2)  # L(q^*) = L(q)^T
    j = np.zeros(left_t.shape[:-2] + (6, 7))
    j[..., :3, :3] = np.eye(3)
    j[..., 3:, 3:] = 2.0 * left_t[..., :3, :]
    return _sandwich(j, c)
