"""Covariance of a least-squares estimate whose residuals share the samples' noise (internal).

Residuals built from differences of poses (motion pairs, angular rates by central differences)
share samples, so they are correlated and ``(J^T W J)^-1`` is not the estimate's covariance.
The noise is modelled where it enters, at the samples of each stream:

    r_m = J_m dx + sum_q G_mq e_(s_q, n_q)      (first order, over the contributions q of r_m)

with ``e_(s, n)`` the error of stream ``s`` at its sample ``n`` (C components, each group of
components with one variance per stream) and errors of one stream correlated by
``rho^|x_n - x_l|`` for sample positions ``x`` (in the units ``rho`` is given per). The
variances and ``rho`` are fitted to the squared residuals (their expectations are linear in
the variances for each ``rho`` of a grid), and the covariance is the sandwich

    Cov(dx) = H^-1 (J^T W C W J) H^-1,   H = J^T W J,   C = Cov(sum_q G_mq e_q),

which is exact to first order for the weighted least squares the solver ran.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

__all__ = ["NoiseModel", "Stream", "fit_noise", "sandwich_covariance"]

#: Correlation grid searched for ``rho`` (per unit of sample position).
RHO_GRID = np.concatenate([np.linspace(0.0, 0.9, 10), [0.95, 0.97, 0.98, 0.99, 0.995]])


@dataclass(frozen=True)
class Stream:
    """How one stream's sample errors enter the residuals.

    ``G`` (M, Q, B, C): the Jacobians of the M residuals (B rows) with respect to the errors
    (C components) of their Q contributing samples, zero for padding; ``index`` (M, Q) the
    samples' indices into ``position`` (N,), the sample positions (increasing).
    """

    G: np.ndarray
    index: np.ndarray
    position: np.ndarray


@dataclass(frozen=True)
class NoiseModel:
    """Fitted variances ``scales`` (streams x component groups) and the correlation ``rho``."""

    scales: np.ndarray
    rho: float
    groups: tuple[tuple[int, ...], ...]

    def covariance(self, stream: int, n_components: int) -> np.ndarray:
        """Covariance (C, C) of one sample's error of ``stream``."""
        d = np.zeros(n_components)
        for g, v in zip(self.groups, self.scales[stream]):
            d[list(g)] = v
        return np.diag(d)


def _corr(st: Stream, rho: float) -> np.ndarray:
    """(M, Q, Q) correlation between the contributing samples of each residual."""
    x = st.position[st.index]
    lag = np.abs(x[:, :, None] - x[:, None, :])
    return np.where(lag == 0, 1.0, rho**lag if rho > 0 else 0.0)


def _design(streams, rho, row_groups, comp_groups):
    """Expected squared norms of each residual's row groups per unit variance:
    (M * len(row_groups), streams * len(comp_groups))."""
    cols = []
    for st in streams:
        c = _corr(st, rho)
        for g in comp_groups:
            Gg = st.G[..., list(g)]  # (M, Q, B, c)
            e = np.einsum("mqrc,mpq,mprc->mr", Gg, c, Gg)  # (M, B)
            cols.append(np.concatenate([e[:, list(rg)].sum(1) for rg in row_groups]))
    return np.stack(cols, axis=1)


def fit_noise(r, streams, row_groups, comp_groups) -> NoiseModel:
    """Fit the variances and ``rho`` to residuals ``r`` (M, B).

    Non-negative least squares on the squared norms of each row group of every residual (each
    group scaled by its mean) for every ``rho`` of :data:`RHO_GRID`; the best fit wins.
    """
    m2 = np.concatenate([np.sum(r[:, list(g)] ** 2, 1) for g in row_groups])
    m = len(r)
    means = m2.reshape(len(row_groups), m).mean(axis=1)
    scale = np.repeat(1.0 / np.maximum(means, 1e-30), m)
    best = None
    for rho in RHO_GRID:
        D = _design(streams, rho, row_groups, comp_groups) * scale[:, None]
        norm = np.linalg.norm(D, axis=0)
        norm[norm == 0] = 1.0
        theta, res = nnls(D / norm, m2 * scale)
        if best is None or res < best[0]:
            best = (res, theta / norm, rho)
    scales = best[1].reshape(len(streams), len(comp_groups))
    return NoiseModel(scales, float(best[2]), tuple(tuple(g) for g in comp_groups))


def sandwich_covariance(J, w, streams, noise: NoiseModel) -> np.ndarray:
    """``H^-1 (J^T W C W J) H^-1`` for weighted least squares on the residuals.

    ``J`` (M, B, P) the residuals' Jacobians for the unknowns, ``w`` (B,) the weights the
    solver used per residual row. Returns (P, P).
    """
    p = J.shape[2]
    JW = J * w[None, :, None]
    H = np.einsum("mbi,mbj->ij", JW, J)
    V = np.zeros((p, p))
    for s, st in enumerate(streams):
        n, c = len(st.position), st.G.shape[3]
        # U_n (P, C): how the weighted score moves with the error of sample n
        U = np.zeros((n, p, c))
        np.add.at(U, st.index.ravel(), np.einsum("mbi,mqbc->mqic", JW, st.G).reshape(-1, p, c))
        Wn = U @ noise.covariance(s, c)
        # sum_{n,l} rho^|x_n - x_l| W_n U_l^T by a forward and a backward recursion
        F, B = U.copy(), U.copy()
        if noise.rho > 0:
            decay = noise.rho ** np.diff(st.position)
            for k in range(1, n):
                F[k] += decay[k - 1] * F[k - 1]
            for k in range(n - 2, -1, -1):
                B[k] += decay[k] * B[k + 1]
        V += np.einsum("kic,kjc->ij", Wn, F + B - U)
    Hi = np.linalg.pinv(H)
    cov = Hi @ (0.5 * (V + V.T)) @ Hi
    return 0.5 * (cov + cov.T)
