"""Measurements and the Kalman update of the derivative pose filter, as kernels: residuals,
measurement Jacobians and covariances, gain and gating, state injection, the update step.

A kernel source for :mod:`trackflow.math._backend` (plain Python on NumPy arrays, kept
numba-compatible), called by :mod:`trackflow.filters.derivative.kernels` (whose docstring
gives the state layout and the two covariance formulations). Formulas: thesis chapter 6,
``docs/filters.md``.
"""

from __future__ import annotations

import math

import numpy as np

from trackflow.filters.derivative.motion_kernels import dims
from trackflow.filters.gating import (
    ACCEPTED,
    DIVERGED,
    GATED,
    is_gated,
)
from trackflow.math._lie import (
    left_mult,
    qrminus_into,
    qrplus_into,
)
from trackflow.math._scalar import (
    TINY,
    chol_into,
    chol_solve_rows,
    joseph_selection,
    sym,
)

KERNELS = (
    "residual_into",
    "innovation_into",
    "jacobian_into",
    "selection_of",
    "residual_size",
    "residual",
    "meas_cov",
    "gain_into",
    "inject",
    "state_is_valid",
    "update_scratch",
    "selection_rows",
    "update_into",
    "update",
    "update_with",
    "update_dense",
)
KERNEL_SOURCES = (
    "trackflow.math._scalar",
    "trackflow.math._lie",
    "trackflow.filters.gating",
    "trackflow.filters.derivative.motion_kernels",
)
# Glue of one filter's step and prediction, inlined into their compiled callers
# (``trackflow.math._backend``): each passes 15 to 35 arrays on, and every array argument
# of a call costs two atomic reference-count operations, more than the glue's own work.
KERNELS_INLINE = ("update_with", "update_into")


# -- measurements ----------------------------------------------------------------------------


def residual_into(x, n_dp, n_do, additive, lp, lo, zp, zo, y, h, qa, qb):
    """``y`` = innovation ``z - h(x)``, ``h`` = measurement Jacobian ``H`` (``y ~ H e + v``).

    ``lp``/``lo``: measured position / orientation derivative level (thesis 6.3.2), ``-1`` =
    not measured. Orientation (``lo = 0``) residual: error state ``Log(q^* z_q)`` with
    ``H = I``; additive ``z_q - q/|q|`` (``z_q`` sign-aligned to ``q``) with ``H_R`` of eq. 6.23.
    ``qa`` and ``qb`` (4) are scratch (unused since the residual is ``qrminus``; kept for the
    callers). :func:`innovation_into` and :func:`jacobian_into`.
    """
    innovation_into(x, n_dp, n_do, additive, lp, lo, zp, zo, y, qa, qb)
    jacobian_into(x, n_dp, n_do, additive, lp, lo, h)


def innovation_into(x, n_dp, n_do, additive, lp, lo, zp, zo, y, qa, qb):
    """The innovation ``y`` of :func:`residual_into` alone; ``qa`` and ``qb`` (4) unused."""
    npl = n_dp + 1 if n_dp >= 0 else 0
    for i in range(y.shape[0]):
        y[i] = 0.0
    r = 0
    if lp >= 0:
        for k in range(3):
            y[k] = zp[k] - x[3 * lp + k]
        r = 3
    if lo < 0:
        return
    qo = 3 * npl
    if lo >= 1:
        xo = qo + 4 + 3 * (lo - 1)
        for k in range(3):
            y[r + k] = zo[k] - x[xo + k]
        return
    if not additive:
        qrminus_into(zo, x[qo : qo + 4], y[r : r + 3])
        return
    q = x[qo : qo + 4]
    ll = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    s = 1.0
    if zo[0] * q[0] + zo[1] * q[1] + zo[2] * q[2] + zo[3] * q[3] < 0.0:
        s = -1.0
    for i in range(4):
        y[r + i] = s * zo[i] - q[i] / ll


def jacobian_into(x, n_dp, n_do, additive, lp, lo, h):
    """The Jacobian ``H`` of :func:`residual_into` alone (``x`` is read by the additive
    orientation only): a selection of state rows (:func:`selection_of`) but for that one."""
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    for i in range(h.shape[0]):
        for j in range(nc):
            h[i, j] = 0.0
    r = 0
    if lp >= 0:
        for k in range(3):
            h[k, 3 * lp + k] = 1.0
        r = 3
    if lo < 0:
        return
    qo = 3 * npl
    if lo >= 1:
        xo = qo + 4 + 3 * (lo - 1)
        co = xo if additive else qo + 3 * lo
        for k in range(3):
            h[r + k, co + k] = 1.0
        return
    if not additive:
        for k in range(3):
            h[r + k, qo + k] = 1.0
        return
    q = x[qo : qo + 4]
    dd = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]
    ll = math.sqrt(dd)
    for i in range(4):
        for j in range(4):
            h[r + i, qo + j] = ((dd if i == j else 0.0) - q[i] * q[j]) / (ll * dd)


def selection_of(n_dp, n_do, additive, lp, lo, idx):
    """Whether :func:`jacobian_into` writes a selection (one ``1`` per row, zeros elsewhere),
    with its columns written to ``idx``: :func:`selection_rows` of that ``H``, known without
    writing it. Every measurement but the additive orientation is one; that one never is
    (the row of its largest ``|q_i|``, or a NaN row, holds no single ``1``)."""
    if additive and lo == 0:
        return False
    npl = n_dp + 1 if n_dp >= 0 else 0
    qo = 3 * npl
    r = 0
    if lp >= 0:
        for k in range(3):
            idx[k] = 3 * lp + k
        r = 3
    if lo >= 1:
        co = qo + 4 + 3 * (lo - 1) if additive else qo + 3 * lo
        for k in range(3):
            idx[r + k] = co + k
    elif lo == 0:
        for k in range(3):
            idx[r + k] = qo + k
    return True


def residual_size(additive, lp, lo):
    """Number of innovation rows of a measurement of levels ``lp`` / ``lo``."""
    m = 3 if lp >= 0 else 0
    if lo >= 0:
        m += 4 if (additive and lo == 0) else 3
    return m


def residual(x, n_dp, n_do, additive, lp, lo, zp, zo):
    """:func:`residual_into` into new arrays: returns ``(y, H)``."""
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    m = residual_size(additive, lp, lo)
    y = np.empty(m)
    h = np.empty((m, nc))
    residual_into(x, n_dp, n_do, additive, lp, lo, zp, zo, y, h, np.empty(4), np.empty(4))
    return y, h


def meas_cov(c, q, lp, lo, additive):
    """Measurement noise in residual coordinates from the caller's covariance ``c``.

    ``c`` is 3x3 (one part) or 6x6 (position and orientation, conventions.md order). For the
    additive orientation it becomes 4x4 / 7x7 via ``V [[C, 0], [0, 1]] V^T`` (eqs. 6.24-6.25),
    ``V`` mapping ``dtheta`` to ``dq = L(q)[:, :3] dtheta / 2`` and the unit scalar along ``q``.
    """
    if not (additive and lo == 0):
        return c.copy()
    m = c.shape[0] + 1
    v = np.zeros((m, c.shape[0] + 1))
    r = 0
    if lp >= 0:
        for k in range(3):
            v[k, k] = 1.0
        r = 3
    lq = left_mult(q)
    for i in range(4):
        for j in range(3):
            v[r + i, r + j] = 0.5 * lq[i, j]
        v[r + i, r + 3] = q[i]
    ce = np.zeros((m, m))
    ce[: c.shape[0], : c.shape[0]] = c
    ce[m - 1, m - 1] = 1.0
    return sym(v @ ce @ v.T)


def gain_into(hp, s, y, r, gate, lo, sy, kt, kr, delta, krt):
    """Kalman gain from ``H P`` and ``S = H P H^T + R``: returns ``(status, nis)``.

    On ACCEPTED ``kt`` holds ``K^T = S^-1 H P``, ``kr`` holds ``K R`` and ``delta`` the
    correction ``K y``; GATED (``nis > gate``) and DIVERGED (``S`` not positive definite or a
    non-finite NIS) leave them undefined. ``lo``, ``sy`` and ``krt`` (at least m x nc) are
    scratch.
    """
    nc = hp.shape[1]
    m = y.shape[0]
    if not chol_into(s, lo):
        return DIVERGED, np.nan
    for i in range(m):
        sy[i, 0] = y[i]
    chol_solve_rows(lo, sy)
    nis = 0.0
    for i in range(m):
        nis += y[i] * sy[i, 0]
    if not np.isfinite(nis):
        return DIVERGED, nis
    if is_gated(nis, gate):
        return GATED, nis
    for a_ in range(m):
        for j in range(nc):
            kt[a_, j] = hp[a_, j]
    chol_solve_rows(lo, kt)
    for i in range(nc):
        delta[i] = 0.0
    for a_ in range(m):
        for i in range(nc):
            delta[i] += kt[a_, i] * y[a_]
    # K R summed as (K R)^T along the rows of K^T (contiguous, of length nc), then
    # transposed: each entry the same terms in the same order as kr[i, b] += kt[a, i] r[a, b]
    for b_ in range(m):
        for i in range(nc):
            krt[b_, i] = 0.0
        for a_ in range(m):
            rv = r[a_, b_]
            for i in range(nc):
                krt[b_, i] += kt[a_, i] * rv
    for i in range(nc):
        for b_ in range(m):
            kr[i, b_] = krt[b_, i]
    return ACCEPTED, nis


def inject(x, delta, n_dp, n_do, additive, wmax, d4, q4):
    """Apply a correction in the covariance coordinates (``x <- x [+] delta``) in place.

    Error state: ``q <- q Exp(dtheta)``; additive: ``q <- q + dq``; then ``q`` is normalised and
    the angular velocity clipped to ``|w| <= wmax`` (if ``wmax > 0``), which changes the mean
    only: the covariance stays symmetric positive definite. ``q4`` is scratch (4,), ``d4`` unused.
    """
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    qo = 3 * npl
    for i in range(qo):
        x[i] += delta[i]
    if n_do < 0:
        return
    if additive:
        for i in range(qo, nx):
            x[i] += delta[i]
    else:
        for k in range(4):
            q4[k] = x[qo + k]
        qrplus_into(q4, delta[qo : qo + 3], x[qo : qo + 4])
        for i in range(qo + 4, nx):
            x[i] += delta[i - 1]
    n = math.sqrt(x[qo] ** 2 + x[qo + 1] ** 2 + x[qo + 2] ** 2 + x[qo + 3] ** 2)
    for i in range(4):
        x[qo + i] /= n
    if n_do >= 1 and wmax > 0.0:
        wn = math.sqrt(x[qo + 4] ** 2 + x[qo + 5] ** 2 + x[qo + 6] ** 2)
        if wn > wmax:
            for i in range(3):
                x[qo + 4 + i] *= wmax / wn


def state_is_valid(x, p):
    """Whether the state is finite and every variance positive."""
    for i in range(p.shape[0]):
        if not (p[i, i] > 0.0 and np.isfinite(p[i, i])):
            return False
    for i in range(x.shape[0]):
        if not np.isfinite(x[i]):
            return False
    return True


def update_scratch(m, nc):
    """Scratch arrays for :func:`update_into` (``m`` measured rows, ``nc`` error size)."""
    return (
        np.empty((m, nc)), np.empty((m, m)), np.empty((m, m)), np.empty((m, 1)),
        np.empty((m, nc)), np.empty((nc, m)), np.empty(nc), np.empty(m), np.empty(nc),
        np.empty((nc, nc)), np.empty(4), np.empty(4),
    )  # fmt: skip


def selection_rows(h, idx):
    """Whether ``H`` selects one state entry per row (writing them to ``idx``)."""
    m, nc = h.shape
    selection = True
    for row in range(m):
        idx[row] = -1
        for c in range(nc):
            if h[row, c] != 0.0:
                if h[row, c] == 1.0 and idx[row] < 0:
                    idx[row] = c
                else:
                    selection = False
        if idx[row] < 0:
            selection = False
    return selection


def update_into(x, p, y, r, idx, gate, n_dp, n_do, additive, wmax, ws):
    """EKF update (thesis eqs. 5.61-5.63) for a selection ``H`` (rows ``idx``), in place.

    Returns ``(status, nis)``: ACCEPTED, GATED (state untouched) or DIVERGED (the caller
    re-initialises). ``ws`` is a tuple of scratch arrays from :func:`update_scratch`.
    """
    hp, s, lo, sy, kt, kr, delta, g, acc, mp, d4, q4 = ws
    nc = p.shape[0]
    m = y.shape[0]
    for a_ in range(m):
        for j in range(nc):
            hp[a_, j] = p[idx[a_], j]
    for a_ in range(m):
        for b_ in range(m):
            s[a_, b_] = 0.5 * (hp[a_, idx[b_]] + hp[b_, idx[a_]]) + 0.5 * (r[a_, b_] + r[b_, a_])
    status, nis = gain_into(hp, s, y, r, gate, lo, sy, kt, kr, delta, mp)
    if status != ACCEPTED:
        return status, nis
    joseph_selection(p, kt, kr, hp, idx, mp, g, acc)
    inject(x, delta, n_dp, n_do, additive, wmax, d4, q4)
    if not state_is_valid(x, p):
        return DIVERGED, nis
    return ACCEPTED, nis


def update(x, p, y, h, r, gate, n_dp, n_do, additive, wmax):
    """EKF update in place for any ``H``; returns ``(status, nis)`` as :func:`update_into`.

    A selection ``H`` (error state, additive non-quaternion parts) runs :func:`update_into`;
    otherwise (the additive quaternion normalisation, user measurements) dense products.
    """
    nc = p.shape[0]
    m = y.shape[0]
    return update_with(
        x, p, y, h, r, gate, n_dp, n_do, additive, wmax, update_scratch(m, nc),
        np.empty(m, np.int64),
    )  # fmt: skip


def update_with(x, p, y, h, r, gate, n_dp, n_do, additive, wmax, ws, idx):
    """:func:`update` with its scratch arrays given (:func:`update_scratch` and ``idx``
    (m,) int), so that a loop over many filters allocates them once."""
    if selection_rows(h, idx):
        return update_into(x, p, y, r, idx, gate, n_dp, n_do, additive, wmax, ws)
    return update_dense(x, p, y, h, r, gate, n_dp, n_do, additive, wmax, ws)


def update_dense(x, p, y, h, r, gate, n_dp, n_do, additive, wmax, ws):
    """:func:`update_with` of an ``H`` that is not a selection: dense products."""
    nc = p.shape[0]
    m = y.shape[0]
    hp, s, lo, sy, kt, kr, delta, g, acc, mp, d4, q4 = ws
    hp[:, :] = h @ p
    s[:, :] = sym(hp @ h.T + r)
    status, nis = gain_into(hp, s, y, r, gate, lo, sy, kt, kr, delta, mp)
    if status != ACCEPTED:
        return status, nis
    # Joseph form (I - K H) P (I - K H)^T + K R K^T: keeps P symmetric positive definite even
    # when K is not exactly optimal (rounding, gating, clipped angular velocity).
    mm = np.eye(nc) - kt.T @ h
    pn = mm @ p @ mm.T
    for i in range(nc):
        for j in range(i, nc):
            w = 0.5 * (pn[i, j] + pn[j, i])
            for b_ in range(m):
                w += kr[i, b_] * kt[b_, j]
            if abs(w) < TINY:
                w = 0.0
            p[i, j] = w
            p[j, i] = w
    inject(x, delta, n_dp, n_do, additive, wmax, d4, q4)
    if not state_is_valid(x, p):
        return DIVERGED, nis
    return ACCEPTED, nis
