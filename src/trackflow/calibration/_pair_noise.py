"""Covariance of the hand-eye estimate from motion pairs that share stations (internal).

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

which is exact to first order for the weighted least squares the solver ran.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

from ..math import quat_to_matrix, skew, so3_right_jacobian_inverse

__all__ = ["StationNoise", "pair_noise_jacobians", "relative_pose_jacobians", "sandwich_covariance"]

#: Correlation grid searched for ``rho`` (per station step).
RHO_GRID = np.concatenate([np.linspace(0.0, 0.9, 10), [0.95, 0.97, 0.98, 0.99, 0.995]])


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


@dataclass(frozen=True)
class StationNoise:
    """Fitted station noise: ``scales`` (4,) variances ``(a pos [m^2], a rot [rad^2], b pos,
    b rot)`` and the correlation ``rho`` between consecutive stations."""

    scales: np.ndarray
    rho: float

    def covariance(self, stream: int) -> np.ndarray:
        """6x6 covariance of one station's error of stream 0 (a) or 1 (b)."""
        s = self.scales[2 * stream : 2 * stream + 2]
        return np.diag(np.repeat(s, 3))


def _moment_design(G_i, G_j, lag, rho):
    """Expected squared norms of the position and rotation parts of each pair residual per
    unit noise variance: (2M, 4) for the four variances of :class:`StationNoise`."""
    cols = []
    for s in (0, 1):  # stream
        for part in (slice(0, 3), slice(3, 6)):  # noise component (pos, rot)
            gi, gj = G_i[s][:, :, part], G_j[s][:, :, part]
            cross = np.einsum("mrc,mrc->mr", gi, gj)
            own = np.einsum("mrc,mrc->mr", gi, gi) + np.einsum("mrc,mrc->mr", gj, gj)
            e = own + 2.0 * (rho**lag)[:, None] * cross  # (M, 6) per residual row
            cols.append(np.concatenate([e[:, :3].sum(1), e[:, 3:].sum(1)]))
    return np.stack(cols, axis=1)


def fit_station_noise(r, G_i, G_j, lag) -> StationNoise:
    """Fit :class:`StationNoise` to pair residuals ``r`` (M, 6).

    ``G_i``, ``G_j``: per stream (a, b) the Jacobians (M, 6, 6) of the residual with respect
    to the errors at the pair's first and second station; ``lag`` (M,) the span in stations.
    Non-negative least squares on the squared position and rotation residual norms (each
    group scaled by its mean), for every ``rho`` of a grid; the best fit wins.
    """
    m2 = np.concatenate([np.sum(r[:, :3] ** 2, 1), np.sum(r[:, 3:] ** 2, 1)])
    m = len(r)
    scale = np.concatenate(
        [np.full(m, 1.0 / max(m2[:m].mean(), 1e-30)), np.full(m, 1.0 / max(m2[m:].mean(), 1e-30))]
    )
    best = None
    for rho in RHO_GRID:
        D = _moment_design(G_i, G_j, lag.astype(float), rho) * scale[:, None]
        norm = np.linalg.norm(D, axis=0)
        norm[norm == 0] = 1.0
        theta, res = nnls(D / norm, m2 * scale)
        if best is None or res < best[0]:
            best = (res, theta / norm, rho)
    return StationNoise(best[1], float(best[2]))


def sandwich_covariance(J, w, G_i, G_j, i, j, noise: StationNoise) -> np.ndarray:
    """``H^-1 (J^T W C W J) H^-1`` for weighted least squares on correlated pair residuals.

    Parameters
    ----------
    J : ndarray, shape (M, 6, P)
        Jacobians of the pair residuals with respect to the unknowns.
    w : ndarray, shape (6,)
        The weights (inverse variances) the solver used per residual column.
    G_i, G_j : tuple of two ndarrays, shape (M, 6, 6)
        Per stream, the residual Jacobians for the errors at stations ``i`` and ``j``.
    i, j : ndarray, shape (M,)
        Station indices of each pair.
    noise : StationNoise

    Returns
    -------
    ndarray, shape (P, P)
    """
    n, p = int(max(i.max(), j.max())) + 1, J.shape[2]
    JW = J * w[None, :, None]
    H = np.einsum("mbi,mbj->ij", JW, J)
    V = np.zeros((p, p))
    for s in (0, 1):
        # U_k (P, 6): how the weighted score moves with the error at station k
        U = np.zeros((n, p, 6))
        np.add.at(U, i, np.einsum("mbi,mbc->mic", JW, G_i[s]))
        np.add.at(U, j, np.einsum("mbi,mbc->mic", JW, G_j[s]))
        Wk = U @ noise.covariance(s)
        # sum_{k,l} rho^|k-l| Wk U_l^T by a forward and a backward recursion
        F, B = U.copy(), U.copy()
        for k in range(1, n):
            F[k] += noise.rho * F[k - 1]
        for k in range(n - 2, -1, -1):
            B[k] += noise.rho * B[k + 1]
        V += np.einsum("kic,kjc->ij", Wk, F + B - U)
    Hi = np.linalg.pinv(H)
    cov = Hi @ (0.5 * (V + V.T)) @ Hi
    return 0.5 * (cov + cov.T)
