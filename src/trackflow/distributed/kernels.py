"""Kernel source of the distributed package (:mod:`trackflow.math._backend`): the numeric
checks of a received filter state, in one pass, so a consumer's per-message work stays small;
the innovation statistic of two consecutive states (:mod:`.innovations`).

Plain Python on NumPy arrays, numba-compatible (explicit loops, float64 arrays).
"""

from __future__ import annotations

import math

import numpy as np

from trackflow.filters.derivative.kernels import local
from trackflow.filters.derivative.motion_kernels import predict_into
from trackflow.math._scalar import chol_into

KERNELS = ("unpack_state", "correction_chol")
KERNEL_SOURCES = (
    "trackflow.math._scalar",
    "trackflow.filters.derivative.motion_kernels",
    "trackflow.filters.derivative.kernels",
)

STATE_OK, STATE_NON_FINITE, STATE_NON_UNIT, STATE_NOT_PD = 0, 1, 2, 3


def unpack_state(values, nx, nc, qo, x, p, lo):
    """Check a received state and unpack it.

    Parameters
    ----------
    values : ndarray (nx + nc (nc + 1) / 2,)
        The message's numbers: the state, then the covariance's upper triangle row by row.
    nx, nc : int
        State and covariance sizes.
    qo : int
        Offset of the unit quaternion in the state, ``-1`` if the model has none.
    x : ndarray (nx,), p : ndarray (nc, nc), lo : ndarray (nc, nc)
        Outputs: the state, the symmetric covariance; scratch for its Cholesky factor.

    Returns
    -------
    int
        ``STATE_OK``; ``STATE_NON_FINITE`` (a NaN or infinity), ``STATE_NON_UNIT`` (the
        quaternion's squared norm is more than 1e-6 from 1) or ``STATE_NOT_PD`` (the
        covariance is not positive definite).
    """
    for i in range(values.shape[0]):
        if not math.isfinite(values[i]):
            return STATE_NON_FINITE
    for i in range(nx):
        x[i] = values[i]
    if qo >= 0:
        n2 = 0.0
        for i in range(4):
            n2 += x[qo + i] * x[qo + i]
        if not abs(n2 - 1.0) <= 1e-6:
            return STATE_NON_UNIT
    k = nx
    for i in range(nc):
        for j in range(i, nc):
            p[i, j] = values[k]
            p[j, i] = values[k]
            k += 1
    if not chol_into(p, lo):
        return STATE_NOT_PD
    return STATE_OK


def correction_chol(x0, p0, dt, x1, p1, n_dp, n_do, additive, kind, sig_p, sig_o, idx, ws, out):
    """The correction of state ``(x1, p1)`` against ``(x0, p0)`` predicted by ``dt`` [s] on
    the pose block ``idx`` (k,), normalised by ``sqrt(diag P_pred)``, and its statistic when
    ``S = P_pred - P_new`` is well positive definite.

    ``ws`` is :func:`~trackflow.filters.derivative.motion_kernels.predict_scratch` of the
    model; ``out`` (k + 1 + k * k + k,) receives ``d`` (normalised), the statistic and the
    normalised ``S`` (row by row), then the scale. Returns ``True`` if the statistic is
    set (``S``'s Cholesky pivots all above 1e-6), ``False`` if the caller must decompose
    ``S`` itself (or a number is not finite: ``out[k]`` is then NaN).
    """
    x = x0.copy()
    p = p0.copy()
    predict_into(x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o, ws)
    d = local(x1, x, n_dp, n_do, additive)
    k = idx.shape[0]
    s = np.empty((k, k))
    lo = np.empty((k, k))
    for a in range(k):
        out[k + 1 + k * k + a] = math.sqrt(max(p[idx[a], idx[a]], 1e-300))
    finite = True
    for a in range(k):
        sa = out[k + 1 + k * k + a]
        out[a] = d[idx[a]] / sa
        finite = finite and math.isfinite(out[a])
        for b in range(k):
            v = (p[idx[a], idx[b]] - p1[idx[a], idx[b]]) / (sa * out[k + 1 + k * k + b])
            s[a, b] = v
            out[k + 1 + a * k + b] = v
            finite = finite and math.isfinite(v)
    if not finite:
        out[k] = math.nan
        return False
    out[k] = 0.0
    if not chol_into(s, lo):
        return False
    for a in range(k):
        if not lo[a, a] * lo[a, a] > 1e-6:
            return False
    # forward substitution: y = L^-1 d, statistic = y'y
    stat = 0.0
    y = np.empty(k)
    for a in range(k):
        v = out[a]
        for b in range(a):
            v -= lo[a, b] * y[b]
        y[a] = v / lo[a, a]
        stat += y[a] * y[a]
    out[k] = stat
    return True
