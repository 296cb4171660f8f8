"""Robust least squares with a consistent covariance (internal, shared by every estimator).

Every estimator here minimises whitened residuals with ``scipy.optimize.least_squares``,
rejects outliers by a chi-square test on each sample's residual block, re-solves on the inliers
and returns the Gauss-Newton covariance ``(J^T J)^-1`` of the whitened problem, scaled by the
residual variance factor and by the residuals' integrated autocorrelation time (so time-
correlated residuals, as from interpolated or smoothed real data, do not make the covariance
overconfident).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import stats

from ..errors import InputError

__all__ = ["Solution", "autocorrelation_time", "chi2_inliers", "robust_solve"]


@dataclass(frozen=True)
class Solution:
    """A solved problem.

    ``x`` the estimate, ``cov`` (P, P) over the tangent step, ``inliers`` (M,) mask over
    residual blocks, ``residuals`` (M, B) unwhitened at ``x``, ``variance_factor`` and ``tau``
    the inflation, ``sigma`` (B,) the final residual scales.
    """

    x: np.ndarray
    cov: np.ndarray
    inliers: np.ndarray
    residuals: np.ndarray
    variance_factor: float
    tau: float
    cost: float
    sigma: np.ndarray


def autocorrelation_time(r: np.ndarray, max_lag: int = 200) -> float:
    """Integrated autocorrelation time of residual series ``r`` (M, B), averaged over columns.

    ``tau = 1 + 2 sum_k rho_k`` summed until the first non-positive ``rho_k`` (Geyer's initial
    positive sequence, simplified); 1 for white residuals.
    """
    r = np.asarray(r, float)
    if r.ndim == 1:
        r = r[:, None]
    taus = []
    for col in r.T:
        c = col - col.mean()
        var = float(c @ c)
        if var <= 0 or len(c) < 10:
            continue
        tau = 1.0
        for k in range(1, min(max_lag, len(c) // 4)):
            rho = float(c[:-k] @ c[k:]) / var
            if rho <= 0:
                break
            tau += 2.0 * rho
        taus.append(tau)
    return float(np.mean(taus)) if taus else 1.0


def _gauss_newton(fun, x, sigma, mask, step, huber=None, max_iter=30, tol=1e-8):
    """Levenberg-damped Gauss-Newton on the blocks in ``mask``; Huber weights if ``huber``."""
    lam = 1e-6

    def cost_of(r):
        z = (r[mask] / sigma).ravel()
        if huber is None:
            return float(z @ z)
        a = np.abs(z)
        return float(np.sum(np.where(a <= huber, z * z, 2 * huber * a - huber * huber)))

    r, J = fun(x)
    cost = cost_of(r)
    for _ in range(max_iter):
        z = (r[mask] / sigma).ravel()
        Jw = (J[mask] / sigma[None, :, None]).reshape(len(z), -1)
        w = (
            np.ones_like(z)
            if huber is None
            else np.minimum(1.0, huber / np.maximum(np.abs(z), 1e-12))
        )
        H = Jw.T @ (Jw * w[:, None])
        g = Jw.T @ (w * z)
        for _ in range(10):
            dx = -np.linalg.solve(H + lam * np.diag(np.diag(H) + 1e-12), g)
            x_new = step(x, dx)
            r_new, J_new = fun(x_new)
            c_new = cost_of(r_new)
            if np.isfinite(c_new) and c_new <= cost:
                lam = max(lam / 10, 1e-9)
                break
            lam *= 10
        else:
            return x
        # Converged when the step no longer changes the cost noticeably (relative to the
        # expected decrease of a whitened problem, the number of unknowns).
        done = cost - c_new <= max(tol * cost, 1e-3 * len(dx))
        x, r, J, cost = x_new, r_new, J_new, c_new
        if done:
            break
    return x


def _rejection_round(r, sigma, inl, outlier_p, groups):
    """One round of the outlier test: the blocks of ``r`` (M, B) whose squared whitened norm,
    rescaled by the median over the current inliers ``inl``, passes the chi-square test at
    level ``outlier_p``; then each group's scale from the new inliers. Returns
    ``(new inliers, old sigma, new sigma)``."""
    nb = len(sigma)
    m2 = np.sum((r / sigma) ** 2, axis=1)
    # Rescale by the robust residual level before the chi-square test.
    scale = np.nanmedian(m2[inl]) / stats.chi2.ppf(0.5, nb)
    new = np.isfinite(m2) & (m2 <= stats.chi2.ppf(1 - outlier_p, nb) * max(scale, 1e-12))
    old = sigma
    if groups is not None and np.any(new):
        sigma = sigma.copy()
        for g in groups:
            rms = float(np.sqrt(np.mean(r[new][:, list(g)] ** 2)))
            sigma[list(g)] = max(rms, 1e-12)
    return new, old, sigma


def chi2_inliers(
    r: np.ndarray,
    sigma: np.ndarray,
    *,
    outlier_p: float = 1e-3,
    groups: tuple[tuple[int, ...], ...] | None = None,
    max_rounds: int = 5,
) -> np.ndarray:
    """The inliers (M,) of fixed residual blocks ``r`` (M, B) under :func:`robust_solve`'s
    outlier test (median-rescaled chi-square at level ``outlier_p``, the scales of ``groups``
    re-estimated from the inliers each round, from the prior scales ``sigma`` (B,)), without
    refitting anything: the residual measure of a solve applied to given residuals. Non-finite
    blocks are outliers."""
    r = np.asarray(r, float)
    sigma = np.asarray(sigma, float).copy()
    inl = np.all(np.isfinite(r), axis=1)
    if not inl.any():
        return inl
    for _ in range(max_rounds):
        new, old, sigma = _rejection_round(r, sigma, inl, outlier_p, groups)
        settled = np.all(np.abs(sigma / old - 1.0) < 0.05)
        if np.array_equal(new, inl) and settled:
            break
        inl = new
    return new


def robust_solve(
    fun: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    x0: np.ndarray,
    sigma: np.ndarray,
    *,
    outlier_p: float = 1e-3,
    correlated: bool = True,
    update: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
    max_rounds: int = 5,
    groups: tuple[tuple[int, ...], ...] | None = None,
) -> Solution:
    """Minimise ``sum |r_i / sigma|^2`` with outlier rejection.

    ``fun(x) -> (r (M, B), J (M, B, P))`` gives residual blocks and their Jacobians.

    ``sigma`` (B,) is the prior residual scale of each block column (re-estimated per group of
    columns; with ``groups`` (tuples of column indices) each group's scale is re-estimated from
    the inlier residuals after every round, so the weights between groups are data-driven).
    ``update(x, dx)`` applies a step on the manifold (default
    ``x + dx``); the Jacobian ``J`` is with respect to that step at ``x``. A Huber loss at 2
    sigma guards the first round; later rounds are plain least squares on the blocks whose
    squared Mahalanobis norm passes the chi-square test at level ``outlier_p``.
    """
    x = np.asarray(x0, float).copy()
    sigma = np.asarray(sigma, float).copy()
    step = update or (lambda a, d: a + d)
    nb = len(sigma)
    raw = fun

    def fun(z):
        # Blocks that become undefined (a sample shifted into a gap) weigh nothing.
        r, J = raw(z)
        bad = ~np.all(np.isfinite(r), axis=1)
        if bad.any():
            r, J = r.copy(), J.copy()
            r[bad], J[bad] = 0.0, 0.0
        return r, J

    r0, J0 = raw(x)
    ndim = J0.shape[2]
    inl = np.all(np.isfinite(r0), axis=1)
    for rnd in range(max_rounds):
        x = _gauss_newton(fun, x, sigma, inl, step, huber=2.0 if rnd == 0 else None)
        r, _ = raw(x)
        new, old, sigma = _rejection_round(r, sigma, inl, outlier_p, groups)
        if new.sum() * nb <= 2 * ndim:
            raise InputError(
                f"only {int(new.sum())} usable residuals for {ndim} unknowns: the data do not "
                "determine the calibration"
            )
        settled = np.all(np.abs(sigma / old - 1.0) < 0.05)
        if rnd > 0 and np.array_equal(new, inl) and settled:
            break
        inl = new
    r, J = fun(x)
    Jw = (J[inl] / sigma[None, :, None]).reshape(-1, ndim)
    rw = (r[inl] / sigma).ravel()
    dof = max(len(rw) - ndim, 1)
    factor = float(rw @ rw) / dof
    tau = autocorrelation_time(r[inl] / sigma) if correlated else 1.0
    cov = np.linalg.pinv(Jw.T @ Jw) * factor * tau
    return Solution(x, cov, inl, r, factor, tau, float(rw @ rw), sigma)
