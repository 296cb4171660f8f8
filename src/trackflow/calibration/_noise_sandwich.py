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


def _inner_products(streams, comp_groups, row_groups, lag, k):
    """Per stream and component group: the sample positions of residuals ``k`` and
    ``k + lag`` and the inner products ``sum_(r in row group, c) G_kq[r, c] G_(k+lag)p[r, c]``
    (m, Q, Q, row groups), which do not depend on ``rho``."""
    out = []
    for st in streams:
        x = st.position[st.index]
        for g in comp_groups:
            Ga, Gb = st.G[k][..., list(g)], st.G[k + lag][..., list(g)]  # (m, Q, B, c)
            ip = np.einsum("mqrc,mprc->mqpr", Ga, Gb)
            ip = np.stack([ip[..., list(rg)].sum(-1) for rg in row_groups], axis=-1)
            out.append((np.abs(x[k][:, :, None] - x[k + lag][:, None, :]), ip))
    return out


def _design(pre, rho, n_row_groups):
    """Expected products ``r_k . r_(k + lag)`` per row group and unit variance, from
    :func:`_inner_products`: (rows, streams * component groups)."""
    cols = []
    for dx, ip in pre:
        c = (dx == 0).astype(float) if rho == 0 else np.exp(dx * np.log(rho))
        e = np.einsum("mqp,mqpg->gm", c, ip)
        cols.append(e.reshape(-1))
    return np.stack(cols, axis=1)


def _products(r, row_groups, lag, k):
    return np.concatenate(
        [np.sum(r[k][:, list(g)] * r[k + lag][:, list(g)], 1) for g in row_groups]
    )


def fit_noise(r, streams, row_groups, comp_groups, lags=(0,), max_moments=2000) -> NoiseModel:
    """Fit the variances and ``rho`` to residuals ``r`` (M, B).

    Non-negative least squares on the products ``r_k . r_(k + lag)`` of each row group for
    every ``lag`` of ``lags`` (0: the squared norms; lags > 0 need the residuals in time order
    and tell ``rho`` where the samples of one residual are too far apart to), each group
    scaled by its mean square, for every ``rho`` of :data:`RHO_GRID`; the best fit wins.
    The moments start at evenly spread residuals, at most ``max_moments`` per lag.
    """
    ms = np.array([np.mean(np.sum(r[:, list(g)] ** 2, 1)) for g in row_groups])
    starts = {}
    for lag in lags:
        if lag < len(r):
            n = len(r) - lag
            starts[lag] = np.arange(0, n, max(1, n // max_moments))
    y = np.concatenate([_products(r, row_groups, lag, k) for lag, k in starts.items()])
    w = np.concatenate([np.repeat(1.0 / np.maximum(ms, 1e-30), len(k)) for k in starts.values()])
    pre = [_inner_products(streams, comp_groups, row_groups, lag, k) for lag, k in starts.items()]
    best = None
    for rho in RHO_GRID:
        D = np.concatenate([_design(p, rho, len(row_groups)) for p in pre]) * w[:, None]
        norm = np.linalg.norm(D, axis=0)
        norm[norm == 0] = 1.0
        theta, res = nnls(D / norm, y * w)
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
