"""Analytic Jacobians of pose operations in trackflow's error convention.

The error of a pose ``T_a_b`` is ``e = (dt, dtheta)`` with ``t_true = t + dt`` (frame a) and
``R_true = R Exp(dtheta)`` (right, frame b); see ``docs/conventions.md``. Each function returns
``J_<out>_<in> = d e_out / d e_in`` evaluated at zero error, batched over leading dimensions.
All are checked against central finite differences in ``tests/math/test_jacobians.py``.
"""

from __future__ import annotations

import numpy as np

from ._quaternion import (
    quat_conjugate,
    quat_exp,
    quat_multiply,
    quat_rminus,
    quat_to_matrix,
    skew,
    so3_right_jacobian,
    so3_right_jacobian_inverse,
)

__all__ = [
    "jacobians_compose",
    "jacobian_inverse",
    "jacobians_between",
    "jacobians_interpolate",
    "jacobians_transform_point",
    "propagate_covariance",
]


def _block(tl, tr, bl, br) -> np.ndarray:
    shape = np.broadcast_shapes(tl.shape[:-2], tr.shape[:-2], bl.shape[:-2], br.shape[:-2])
    j = np.empty(shape + (6, 6))
    j[..., :3, :3] = tl
    j[..., :3, 3:] = tr
    j[..., 3:, :3] = bl
    j[..., 3:, 3:] = br
    return j


def jacobians_compose(t_a, q_a, t_b, q_b) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of ``T_c = T_a @ T_b`` with respect to the errors of ``T_a`` and ``T_b``.

    Perturbing ``T_a`` by ``(dt_a, dtheta_a)`` and ``T_b`` by ``(dt_b, dtheta_b)``::

        dt_c     = dt_a - R_a [t_b]x dtheta_a + R_a dt_b
        dtheta_c = R_b^T dtheta_a + dtheta_b

    Returns
    -------
    J_c_a, J_c_b : ndarray, shape (..., 6, 6)
        ``J_c_a = [[I, -R_a [t_b]x], [0, R_b^T]]``, ``J_c_b = [[R_a, 0], [0, I]]``.
    """
    r_a = quat_to_matrix(q_a)
    r_b = quat_to_matrix(q_b)
    eye = np.broadcast_to(np.eye(3), r_a.shape)
    zero = np.zeros(np.broadcast_shapes(r_a.shape, r_b.shape))
    J_c_a = _block(
        np.broadcast_to(np.eye(3), zero.shape), -r_a @ skew(t_b), zero, np.swapaxes(r_b, -1, -2)
    )
    J_c_b = _block(r_a, zero, zero, np.broadcast_to(eye, zero.shape))
    return J_c_a, J_c_b


def jacobian_inverse(t, q) -> np.ndarray:
    """Jacobian of ``T_i = T^-1`` (``t_i = -R^T t``, ``R_i = R^T``) w.r.t. the error of ``T``.

    ::

        dt_i     = -R^T dt + [t_i]x dtheta
        dtheta_i = -R dtheta

    The minus sign in the rotation block matters: with ``+R`` the translation-rotation
    cross-covariance of the inverse would come out with the wrong sign.

    Returns
    -------
    J_i_a : ndarray, shape (..., 6, 6)
    """
    r = quat_to_matrix(q)
    rt = np.swapaxes(r, -1, -2)
    t_i = -np.einsum("...ij,...j->...i", rt, np.asarray(t, dtype=float))
    return _block(-rt, skew(t_i), np.zeros_like(r), -r)


def jacobians_between(t_a, q_a, t_b, q_b) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of ``T_c = T_a^-1 @ T_b`` (the relative pose, "a inverse times b").

    This is the chain rule through the inversion, not the plain composition Jacobians::

        dt_c     = -R_a^T dt_a + [t_c]x dtheta_a + R_a^T dt_b
        dtheta_c = -R_c^T dtheta_a + dtheta_b

    Returns
    -------
    J_c_a, J_c_b : ndarray, shape (..., 6, 6)
    """
    r_a = quat_to_matrix(q_a)
    r_at = np.swapaxes(r_a, -1, -2)
    d = np.asarray(t_b, dtype=float) - np.asarray(t_a, dtype=float)
    t_c = np.einsum("...ij,...j->...i", r_at, d)
    r_c = quat_to_matrix(quat_multiply(quat_conjugate(q_a), q_b))
    shape = np.broadcast_shapes(r_a.shape, r_c.shape)
    zero = np.zeros(shape)
    J_c_a = _block(np.broadcast_to(-r_at, shape), skew(t_c), zero, -np.swapaxes(r_c, -1, -2))
    J_c_b = _block(np.broadcast_to(r_at, shape), zero, zero, np.broadcast_to(np.eye(3), shape))
    return J_c_a, J_c_b


def jacobians_interpolate(q_a, q_b, s) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of the interpolation ``T_s = lerp/slerp(T_a, T_b, s)``.

    With ``phi = Log(R_a^T R_b)`` and ``R_s = R_a Exp(s phi)``, ``t_s = (1-s) t_a + s t_b``::

        dt_s     = (1 - s) dt_a + s dt_b
        dtheta_s = [Exp(s phi)^T - s J_r(s phi) J_r^-1(-phi)] dtheta_a
                   + s J_r(s phi) J_r^-1(phi) dtheta_b

    Returns
    -------
    J_s_a, J_s_b : ndarray, shape (..., 6, 6)
    """
    s = np.asarray(s, dtype=float)
    phi = quat_rminus(q_b, q_a)
    sphi = s[..., None] * phi
    jr_s = so3_right_jacobian(sphi)
    rot_s_t = np.swapaxes(quat_to_matrix(quat_exp(sphi)), -1, -2)
    ss = s[..., None, None]
    rot_a = rot_s_t - ss * jr_s @ so3_right_jacobian_inverse(-phi)
    rot_b = ss * jr_s @ so3_right_jacobian_inverse(phi)
    eye = np.eye(3)
    zero = np.zeros(rot_a.shape)
    J_s_a = _block((1.0 - ss) * np.broadcast_to(eye, zero.shape), zero, zero, rot_a)
    J_s_b = _block(ss * np.broadcast_to(eye, zero.shape), zero, zero, rot_b)
    return J_s_a, J_s_b


def jacobians_transform_point(q, point) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of ``x_a = R x_b + t`` w.r.t. the pose error and the point error.

    ::

        dx_a = dt - R [x_b]x dtheta + R dx_b

    Returns
    -------
    J_x_pose : ndarray, shape (..., 3, 6)
    J_x_point : ndarray, shape (..., 3, 3)
    """
    r = quat_to_matrix(q)
    x = np.asarray(point, dtype=float)
    rot = -r @ skew(x)
    J_x_pose = np.empty(rot.shape[:-2] + (3, 6))
    J_x_pose[..., :3] = np.eye(3)
    J_x_pose[..., 3:] = rot
    return J_x_pose, np.broadcast_to(r, rot.shape).copy()


def propagate_covariance(J_y_a, C_a, J_y_b=None, C_b=None, C_ab=None) -> np.ndarray:
    """First-order covariance of ``y = f(a, b)``.

    ``C_y = J_a C_a J_a^T + J_b C_b J_b^T + J_a C_ab J_b^T + J_b C_ab^T J_a^T``, where
    ``C_ab = E[e_a e_b^T]`` is the cross-covariance (omitted: independent inputs). The result
    is symmetrised exactly.
    """
    c = J_y_a @ C_a @ np.swapaxes(J_y_a, -1, -2)
    if J_y_b is not None:
        c = c + J_y_b @ C_b @ np.swapaxes(J_y_b, -1, -2)
        if C_ab is not None:
            x = J_y_a @ C_ab @ np.swapaxes(J_y_b, -1, -2)
            c = c + x + np.swapaxes(x, -1, -2)
    return 0.5 * (c + np.swapaxes(c, -1, -2))
