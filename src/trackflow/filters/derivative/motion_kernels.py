"""The motion model of the derivative pose filter, as kernels: state sizes, transition,
process noise and prediction.

A kernel source for :mod:`trackflow.math._backend` (plain Python on NumPy arrays, kept
numba-compatible), called by :mod:`trackflow.filters.derivative.kernels` (whose docstring
gives the state layout and the two covariance formulations) and by :mod:`.update_kernels`.
Formulas: thesis chapter 6, ``docs/filters.md``.
"""

from __future__ import annotations

import math

import numpy as np

from trackflow.math._lie import (
    exp_jac,
    left_mult,
    qexp_into,
    qmul_into,
    right_jac_into,
    right_mult,
    rotmat_into,
)
from trackflow.math._scalar import (
    fact,
    sandwich_into,
)

KERNELS = (
    "dims",
    "level_noise_into",
    "level_noise",
    "mean_transition_into",
    "transition_matrix_into",
    "transition",
    "process_noise_into",
    "process_noise",
    "process_noise_memo",
    "predict_scratch",
    "predict_into",
    "predict",
)
KERNEL_SOURCES = ("trackflow.math._scalar", "trackflow.math._lie")
# Glue of one filter's step and prediction, inlined into their compiled callers
# (``trackflow.math._backend``): each passes 15 to 35 arrays on, and every array argument
# of a call costs two atomic reference-count operations, more than the glue's own work.
KERNELS_INLINE = ("predict_into",)


def dims(n_dp, n_do, additive):
    """(position levels, orientation levels, nominal size, covariance size)."""
    npl = n_dp + 1 if n_dp >= 0 else 0
    nol = n_do + 1 if n_do >= 0 else 0
    nx = 3 * npl + (4 + 3 * n_do if n_do >= 0 else 0)
    nc = nx if additive else 3 * npl + 3 * nol
    return npl, nol, nx, nc


# -- noise of the derivative levels ------------------------------------------------------------


def level_noise_into(n, sig, dt, kind, m):
    """:func:`level_noise` written into ``m`` (at least ``n x n``)."""
    for i in range(n):
        for j in range(n):
            m[i, j] = 0.0
    if kind == 1:
        for i in range(n):
            m[i, i] = (sig[i] * dt) ** 2
        return
    for i in range(n):
        for j in range(n):
            s = 0.0
            for lvl in range(max(i, j), n):
                e = 2 * lvl - i - j + 1
                s += sig[lvl] ** 2 * dt**e / (fact(lvl - i) * fact(lvl - j) * e)
            m[i, j] = s


def level_noise(n, sig, dt, kind):
    """Process-noise matrix over derivative levels ``0..n-1`` for one axis.

    ``kind = 0``: continuous white noise of spectral density ``sig[l]^2`` driving level ``l``,
    integrated exactly over ``dt`` (Ude eq. 23 generalised). ``kind = 1``: thesis eq. 6.21,
    ``diag((sig[l] dt)^2)``.
    """
    m = np.empty((n, n))
    level_noise_into(n, sig, dt, kind, m)
    return m


# -- motion model -------------------------------------------------------------------------------


def mean_transition_into(x, dt, n_dp, n_do, out, cf, b, d):
    """``out`` = nominal part of :func:`transition` (both formulations); returns nothing.

    ``cf`` (>= max levels + 1), ``b`` (3) and ``d`` (4) are scratch; ``d`` holds ``Exp(b)``
    and ``b`` the rotation increment afterwards.
    """
    npl = n_dp + 1 if n_dp >= 0 else 0
    cf[0] = 1.0
    for i in range(1, cf.shape[0]):
        cf[i] = cf[i - 1] * dt / i
    for i in range(npl):
        for k in range(3):
            v = 0.0
            for j in range(i, npl):
                v += cf[j - i] * x[3 * j + k]
            out[3 * i + k] = v
    if n_do < 0:
        return
    qo = 3 * npl
    b[0] = 0.0
    b[1] = 0.0
    b[2] = 0.0
    for lv in range(1, n_do + 1):
        c = cf[lv]
        for k in range(3):
            b[k] += c * x[qo + 4 + 3 * (lv - 1) + k]
    qexp_into(b, d)
    qmul_into(x[qo : qo + 4], d, out[qo : qo + 4])
    for lv in range(1, n_do + 1):
        for k in range(3):
            v = 0.0
            for j in range(lv, n_do + 1):
                v += cf[j - lv] * x[qo + 4 + 3 * (j - 1) + k]
            out[qo + 4 + 3 * (lv - 1) + k] = v


def transition_matrix_into(x, n_dp, n_do, additive, cf, b, d, a, m3):
    """``a`` = Jacobian ``A`` of :func:`transition` in the covariance coordinates.

    Needs ``cf``, ``b`` and ``d`` as left by :func:`mean_transition_into` for the same state and
    ``dt``. Error state: ``dtheta_new = Exp(b)^T dtheta + Jr(b) db``; additive: the thesis's
    ``A_R`` with ``M(d)`` and ``B = L(q) dExp/db``. ``m3`` (3x3) is scratch.
    """
    npl = n_dp + 1 if n_dp >= 0 else 0
    nc = a.shape[0]
    for i in range(nc):
        for j in range(nc):
            a[i, j] = 0.0
    for i in range(npl):
        for j in range(i, npl):
            c = cf[j - i]
            for k in range(3):
                a[3 * i + k, 3 * j + k] = c
    if n_do < 0:
        return
    qo = 3 * npl
    if additive:
        a[qo : qo + 4, qo : qo + 4] = right_mult(d)
        bm = left_mult(x[qo : qo + 4]) @ exp_jac(b)
        for lv in range(1, n_do + 1):
            c = cf[lv]
            a[qo : qo + 4, qo + 4 + 3 * (lv - 1) : qo + 4 + 3 * lv] = c * bm
        base = qo + 4 - 3  # angular level lv sits at base + 3 lv
    else:
        rotmat_into(d, m3)
        for i in range(3):
            for j in range(3):
                a[qo + i, qo + j] = m3[j, i]
        right_jac_into(b, m3)
        for lv in range(1, n_do + 1):
            c = cf[lv]
            for i in range(3):
                for j in range(3):
                    a[qo + i, qo + 3 * lv + j] = c * m3[i, j]
        base = qo
    for lv in range(1, n_do + 1):
        for j in range(lv, n_do + 1):
            c = cf[j - lv]
            for k in range(3):
                a[base + 3 * lv + k, base + 3 * j + k] = c


def transition(x, dt, n_dp, n_do, additive):
    """Motion-model prediction over ``dt``: returns ``(x_new, A)`` as new arrays.

    Position: Taylor series (thesis eq. 6.18). Orientation: ``q_new = q * Exp(b)`` with
    ``b = sum_l w^(l-1) dt^l / l!`` (eq. 6.19). ``A``: see :func:`transition_matrix_into`.
    """
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    xn = np.empty(nx)
    a = np.empty((nc, nc))
    cf = np.empty(max(npl, nol) + 1)
    b = np.empty(3)
    d = np.empty(4)
    mean_transition_into(x, dt, n_dp, n_do, xn, cf, b, d)
    transition_matrix_into(x, n_dp, n_do, additive, cf, b, d, a, np.empty((3, 3)))
    return xn, a


def process_noise_into(x, dt, n_dp, n_do, additive, kind, sig_p, sig_o, qm, lv):
    """``qm`` = process-noise covariance ``Q`` in the covariance coordinates (:func:`level_noise`).

    The additive formulation maps the rotation-vector noise onto the quaternion with
    ``dq = L(q)[:, :3] dtheta / 2`` and adds the same variance along ``q`` itself, which makes the
    quaternion block isotropic (``(sig dt / 2)^2 I_4`` for the thesis's diagonal model).
    ``lv`` (levels x levels) is scratch.
    """
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    for i in range(nc):
        for j in range(nc):
            qm[i, j] = 0.0
    if npl > 0:
        level_noise_into(npl, sig_p, dt, kind, lv)
        for i in range(npl):
            for j in range(npl):
                for k in range(3):
                    qm[3 * i + k, 3 * j + k] = lv[i, j]
    if nol == 0:
        return
    mo = lv
    level_noise_into(nol, sig_o, dt, kind, mo)
    eo = 3 * npl
    if not additive:
        for i in range(nol):
            for j in range(nol):
                for k in range(3):
                    qm[eo + 3 * i + k, eo + 3 * j + k] = mo[i, j]
        return
    g = 0.5 * left_mult(x[eo : eo + 4])[:, :3]
    q = x[eo : eo + 4]
    qq = g @ g.T * mo[0, 0]
    for r in range(4):
        for c in range(4):
            qq[r, c] += 0.25 * mo[0, 0] * q[r] * q[c]
    qm[eo : eo + 4, eo : eo + 4] = qq
    for j in range(1, nol):
        col = eo + 4 + 3 * (j - 1)
        blk = g * mo[0, j]
        qm[eo : eo + 4, col : col + 3] = blk
        qm[col : col + 3, eo : eo + 4] = blk.T
        for i in range(1, nol):
            row = eo + 4 + 3 * (i - 1)
            for k in range(3):
                qm[row + k, col + k] = mo[i, j]


def process_noise(x, dt, n_dp, n_do, additive, kind, sig_p, sig_o):
    """:func:`process_noise_into` as a new array."""
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    qm = np.empty((nc, nc))
    nlev = max(npl, nol, 1)
    process_noise_into(x, dt, n_dp, n_do, additive, kind, sig_p, sig_o, qm, np.empty((nlev, nlev)))
    return qm


def process_noise_memo(x, dt, n_dp, n_do, additive, kind, sig_p, sig_o, qm, lv, memo):
    """:func:`process_noise_into` unless ``qm`` already holds the noise of this ``dt``.

    The error-state noise depends on ``dt`` and the filter's constants only, so the filters
    of a bank stepped over one packet's ``dt`` compute it once. ``memo`` (2,) records it:
    ``memo[0] = 1`` once ``qm`` holds the noise of the step ``memo[1]`` (the same bits:
    equal and of the same sign). The additive noise depends on ``x``: always computed.
    """
    if (
        not additive
        and memo[0] == 1.0
        and memo[1] == dt
        and math.copysign(1.0, memo[1]) == math.copysign(1.0, dt)
    ):
        return
    process_noise_into(x, dt, n_dp, n_do, additive, kind, sig_p, sig_o, qm, lv)
    memo[0] = 0.0 if additive else 1.0
    memo[1] = dt


def predict_scratch(n_dp, n_do, additive):
    """Scratch arrays for :func:`predict_into` (and :func:`predict_pose_with`), for one filter
    kind: its process noise is kept between calls (:func:`process_noise_memo`)."""
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    nlev = max(npl, nol, 1)
    return (
        np.empty(nlev + 1), np.empty(3), np.empty(4), np.empty(nx), np.empty((nc, nc)),
        np.empty((nc, nc)), np.empty((nlev, nlev)), np.empty((nc, nc)), np.empty((nc, nc)),
        np.empty((3, 3)), np.empty((nc, nc + 1), np.int64), np.zeros(2),
    )  # fmt: skip


def predict_into(x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o, ws):
    """Time update in place: ``x = f(x)``, ``P = A P A^T + Q`` (thesis eqs. 5.59-5.60).

    ``ws`` is a tuple of scratch arrays from :func:`predict_scratch`.
    """
    cf, b, d, xn, a, qm, lv, tmp, vals, m3, cols, memo = ws
    mean_transition_into(x, dt, n_dp, n_do, xn, cf, b, d)
    transition_matrix_into(x, n_dp, n_do, additive, cf, b, d, a, m3)
    process_noise_memo(x, dt, n_dp, n_do, additive, kind, sig_p, sig_o, qm, lv, memo)
    sandwich_into(a, p, qm, tmp, vals, cols)
    for i in range(x.shape[0]):
        x[i] = xn[i]


def predict(x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o):
    """:func:`predict_into` on copies: returns the new ``(x, P)``."""
    xn = x.copy()
    pn = p.copy()
    predict_into(
        xn, pn, dt, n_dp, n_do, additive, kind, sig_p, sig_o, predict_scratch(n_dp, n_do, additive)
    )
    return xn, pn
