"""Clock offset between two recordings of one signal, by cross-correlation.

Two recordings sample the same scalar signal (an angular speed, a linear speed, ...): the host
recording on the host clock, the remote one on the remote clock. With the convention of
:mod:`trackflow.timesync` (``offset = host - remote``), a value the remote recording stamps
``tau`` was taken at host time ``tau + offset``::

    s_host(t) = alpha + beta s_remote(t - offset) + noise

:func:`correlation_offset` resamples the host recording on a grid of ``step_s``, correlates it
with the remote recording shifted by every lag of ``[-max_offset_s, max_offset_s]`` (the
normalised correlation over the samples valid in both), takes the peak (a parabola through it
and its neighbours refines it below one step), then fits ``(alpha, beta, offset)`` by
Gauss-Newton on the model above (its Jacobian from central differences over three sample
intervals, which keep the recordings' noise out of it). The standard error of the offset is
the sandwich of that fit with the residuals' autocorrelation up to four ``correlation_time_s``
(Bartlett weights), because neighbouring grid points share samples and the signals are often
smoothed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["CorrelationOffset", "correlation_offset"]

#: Fewest grid points valid in both recordings for a lag to count.
MIN_COMMON = 20
#: Half width of the central differences of the fit's Jacobian, in the slower recording's
#: sample intervals: sample-to-sample differences of a noisy recording would inflate ``J^T J``
#: by their noise and make the standard error too small (seeded Monte Carlo: 1.5 x).
SLOPE_SAMPLES = 3.0
#: Residual autocorrelation kept by the sandwich, in correlation times (Bartlett weights).
HAC_WIDTH = 4.0


@dataclass(frozen=True)
class CorrelationOffset:
    """Result of :func:`correlation_offset`.

    Attributes
    ----------
    offset_s : float
        ``host - remote`` [s]: a remote stamp ``tau`` is host time ``tau + offset_s``.
    sigma_s : float
        Standard error of ``offset_s`` [s].
    coarse_offset_s : float
        The correlation peak refined by a parabola [s], before the fit.
    peak : float
        Normalised correlation at the peak (1: identical profiles).
    lags_s, correlation : ndarray (L,)
        The correlation curve over the searched lags [s] (nan where too few samples).
    """

    offset_s: float
    sigma_s: float
    coarse_offset_s: float
    peak: float
    lags_s: np.ndarray
    correlation: np.ndarray


def _sampled(t, s):
    t = np.asarray(t, dtype=float).reshape(-1)
    s = np.asarray(s, dtype=float).reshape(-1)
    if t.shape != s.shape or t.shape[0] < 2:
        raise InputError("a recording needs matching times and values, at least two")
    if not np.all(np.diff(t) > 0):
        raise InputError("a recording's times must increase")
    return t, s


def _at(t, s, q):
    """``s`` linearly interpolated at ``q`` (nan outside ``t`` or next to an invalid sample)."""
    return np.interp(q, t, s, left=np.nan, right=np.nan)


def correlation_offset(
    t_host,
    s_host,
    t_remote,
    s_remote,
    *,
    max_offset_s: float = 1.0,
    step_s: float | None = None,
    correlation_time_s: float | None = None,
    min_peak: float = 0.3,
    refine: bool = True,
) -> CorrelationOffset:
    """Offset ``host - remote`` [s] of two recordings of one signal, with its standard error.

    Parameters
    ----------
    t_host, s_host : array_like (N,)
        Host recording: increasing times on the host clock [s] and values (nan: invalid).
    t_remote, s_remote : array_like (M,)
        Remote recording on the remote clock, likewise.
    max_offset_s : float
        Lags searched: ``[-max_offset_s, max_offset_s]`` [s].
    step_s : float, optional
        Grid and lag step [s]; default half the slower recording's median sample interval.
    correlation_time_s : float, optional
        Time over which the residuals are correlated [s] (the width of any smoothing of the
        signals); default the slower recording's median sample interval.
    min_peak : float
        A smaller correlation peak is an error (the recordings do not show one signal).
    refine : bool
        Fit the offset (False: the parabola's peak, with the standard deviation of a uniform
        error over one step as its sigma).

    Raises
    ------
    ValueError
        Too little overlap, no correlation above ``min_peak``, or the peak at the edge of the
        search range.
    """
    th, sh = _sampled(t_host, s_host)
    tr, sr = _sampled(t_remote, s_remote)
    slow = max(float(np.median(np.diff(th))), float(np.median(np.diff(tr))))
    step = 0.5 * slow if step_s is None else float(step_s)
    tau = slow if correlation_time_s is None else max(float(correlation_time_s), step)
    m = float(max_offset_s)
    lo, hi = max(th[0], tr[0] - m), min(th[-1], tr[-1] + m)
    grid = np.arange(lo, hi, step) if hi > lo else np.empty(0)
    if grid.shape[0] < MIN_COMMON:
        raise InputError(
            f"the recordings overlap too little to find a clock offset (host {th[0]:.3f}.."
            f"{th[-1]:.3f} s, remote {tr[0]:.3f}..{tr[-1]:.3f} s, offsets up to {m} s)"
        )
    a = _at(th, sh, grid)
    lags = np.arange(-m, m + step / 2, step)
    corr = np.full(lags.shape[0], np.nan)
    for k, lag in enumerate(lags):
        b = _at(tr, sr, grid - lag)
        ok = np.isfinite(a) & np.isfinite(b)
        if ok.sum() < MIN_COMMON:
            continue
        x, y = a[ok] - a[ok].mean(), b[ok] - b[ok].mean()
        d = math.sqrt(float(x @ x) * float(y @ y))
        corr[k] = float(x @ y) / d if d > 0 else np.nan
    if not np.any(np.isfinite(corr)):
        raise InputError("the recordings share too few valid samples at every lag")
    k = int(np.nanargmax(corr))
    peak = float(corr[k])
    coarse = float(lags[k])
    if 0 < k < lags.shape[0] - 1 and np.all(np.isfinite(corr[k - 1 : k + 2])):
        c0, c1, c2 = corr[k - 1 : k + 2]
        den = c0 - 2 * c1 + c2
        if den < 0:
            coarse += float(0.5 * (c0 - c2) / den * step)
    if peak < min_peak:
        raise InputError(
            f"the recordings do not correlate (peak {peak:.2f} within +-{m} s): do they show "
            "one signal, is the offset larger?"
        )
    if k in (0, lags.shape[0] - 1):
        raise InputError(
            f"correlation peak at the edge of the search range +-{m} s: increase max_offset_s"
        )
    if not refine:
        return CorrelationOffset(coarse, step / math.sqrt(12.0), coarse, peak, lags, corr)
    offset, sigma = _fit(a, grid, tr, sr, coarse, step, tau, slow)
    return CorrelationOffset(offset, sigma, coarse, peak, lags, corr)


def _fit(a, grid, tr, sr, offset, step, tau, slow) -> tuple[float, float]:
    """Gauss-Newton fit of ``a = alpha + beta s_r(grid - offset)``: ``(offset, sigma)``."""
    h = SLOPE_SAMPLES * slow

    def slope(q):
        return (_at(tr, sr, q + h) - _at(tr, sr, q - h)) / (2.0 * h)

    x = np.array([0.0, 1.0, offset])
    for it in range(20):
        b = _at(tr, sr, grid - x[2])
        ok = np.isfinite(a) & np.isfinite(b)
        if ok.sum() < MIN_COMMON:
            raise InputError("the recordings share too few valid samples at the offset")
        if it == 0:  # the linear parameters at the peak
            x[1], x[0] = np.polyfit(b[ok], a[ok], 1)
        db = slope(grid - x[2])
        ok &= np.isfinite(db)
        r = a[ok] - x[0] - x[1] * b[ok]
        J = np.stack([np.ones(r.shape[0]), b[ok], -x[1] * db[ok]], axis=1)
        dx = np.linalg.lstsq(J, r, rcond=None)[0]
        dx[2] = float(np.clip(dx[2], -step, step))
        x += dx
        if abs(dx[2]) < 1e-6 * step:
            break
    b = _at(tr, sr, grid - x[2])
    db = slope(grid - x[2])
    ok = np.isfinite(a) & np.isfinite(b) & np.isfinite(db)
    r = np.where(ok, a - x[0] - x[1] * b, 0.0)
    J = np.stack([np.ones(grid.shape[0]), b, -x[1] * db], axis=1)
    J[~ok] = 0.0
    g = J * r[:, None]  # per-point scores; invalid points contribute nothing
    lag = max(1, int(math.ceil(HAC_WIDTH * tau / step)))
    meat = g.T @ g
    for ell in range(1, min(lag, g.shape[0] - 1) + 1):
        c = g[ell:].T @ g[:-ell]
        meat += (1.0 - ell / (lag + 1.0)) * (c + c.T)
    bread = np.linalg.inv(J.T @ J)
    cov = bread @ meat @ bread
    return float(x[2]), float(math.sqrt(max(cov[2, 2], 0.0)))
