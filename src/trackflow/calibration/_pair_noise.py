"""Jacobians of motion-pair residuals with respect to the station errors (internal).

Motion pairs ``(i, j)`` are built from a few stations each: station ``k`` appears in up to
``2 L`` pairs (``L`` the longest pair span in stations), so the pair residuals are not
independent and neither ``(J^T W J)^-1`` nor any single inflation factor is their covariance.
This module models the noise where it enters, at the stations: each stream's pose at station
``k`` carries an error ``e_k`` (6,) in the conventions of ``docs/conventions.md`` with

    Cov(e_k) = diag(s_p^2 I3, s_r^2 I3)  (per stream),   Cov(e_k, e_l) = rho^|k - l| Cov(e_k)

(white for ``rho = 0``; ``rho`` near 1 for the slowly wandering errors of real inside-out
trackers). A pair residual is, to first order, ``r_p = J_p dx + sum_k G_pk e_k`` over its two
stations and the two streams; the four scales and ``rho`` are fitted to the squared pair
residuals (their expectations are linear in the scales for a given ``rho``, and the growth of
the residual with the pair span tells ``rho``), and the estimate's covariance is the sandwich

    Cov(dx) = H^-1 (J^T W C W J) H^-1,   H = J^T W J,   C = Cov(sum_k G_pk e_k),

which is exact to first order for the weighted least squares the solver ran
(:mod:`._noise_sandwich`).
"""

from __future__ import annotations

import numpy as np

from ..math import quat_to_matrix, skew, so3_right_jacobian_inverse

__all__ = ["pair_noise_jacobians", "relative_pose_jacobians"]


def relative_pose_jacobians(q_i, a_p, a_q):
    """Jacobians of the relative pose ``a = T_i^-1 T_j`` with respect to the errors of ``T_i``
    and ``T_j`` (conventions: translation error in the source frame, rotation on the right).

    Parameters
    ----------
    q_i : ndarray, shape (M, 4)
        Rotation of the first pose of each pair.
    a_p, a_q : ndarray, shapes (M, 3), (M, 4)
        The relative poses.

    Returns
    -------
    J_a_i, J_a_j : ndarray, shape (M, 6, 6)
    """
    m = len(a_p)
    Ri_t = np.swapaxes(quat_to_matrix(q_i), 1, 2)
    Ra_t = np.swapaxes(quat_to_matrix(a_q), 1, 2)
    J_a_i = np.zeros((m, 6, 6))
    J_a_i[:, :3, :3] = -Ri_t
    J_a_i[:, :3, 3:] = skew(a_p)
    J_a_i[:, 3:, 3:] = -Ra_t
    J_a_j = np.zeros((m, 6, 6))
    J_a_j[:, :3, :3] = Ri_t
    J_a_j[:, 3:, 3:] = np.eye(3)
    return J_a_i, J_a_j


def pair_noise_jacobians(a_q, r_rot, q_E, X):
    """Jacobians of the pair residual of ``A_ij X = X B_ij`` with respect to the errors of the
    relative motions ``A_ij`` and ``B_ij``.

    Parameters
    ----------
    a_q : ndarray, shape (M, 4)
        Rotations of ``A_ij``.
    r_rot, q_E : ndarray, shapes (M, 3), (M, 4)
        Rotation part of the residual and the error quaternion ``q_Q^* q_P``.
    X : tuple (p (3,), q (4,))
        ``T_tool_body``.

    Returns
    -------
    J_r_a, J_r_b : ndarray, shape (M, 6, 6)
    """
    m = len(a_q)
    RA = quat_to_matrix(a_q)
    RX = quat_to_matrix(np.asarray(X[1], float))
    Jinv = so3_right_jacobian_inverse(r_rot)
    Et = np.swapaxes(quat_to_matrix(q_E), 1, 2)
    J_r_a = np.zeros((m, 6, 6))
    J_r_a[:, :3, :3] = np.eye(3)
    J_r_a[:, :3, 3:] = -RA @ skew(np.asarray(X[0], float))
    J_r_a[:, 3:, 3:] = Jinv @ RX.T
    J_r_b = np.zeros((m, 6, 6))
    J_r_b[:, :3, :3] = -RX
    J_r_b[:, 3:, 3:] = -Jinv @ Et
    return J_r_a, J_r_b
