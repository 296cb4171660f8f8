"""Kernels of the autoregressive-twist Kalman filter (:mod:`trackflow.filters.twist_ar`).

A kernel source for :mod:`trackflow.math._backend`. State: pose (t, q) and the last L
body-frame increments h (6 L, newest first); error state (dt, dtheta, dh), size n = 6 + 6 L.
``a_cat`` is [A_0 ... A_{L-1}] (6 x 6 L).
"""

from __future__ import annotations

import math

import numpy as np

from trackflow.filters.gating import (
    ACCEPTED,
    GATED,
    INITIALIZED,
    RESET,
    is_gated,
    next_gated_run,
    reset_due,
)
from trackflow.math._lie import qexp, qrminus, qrplus, right_jac, rotmat
from trackflow.math._scalar import joseph_selection

KERNELS = ("twist_ar_top", "twist_ar_top_into", "twist_ar_run")
KERNEL_SOURCES = ("trackflow.math._scalar", "trackflow.math._lie", "trackflow.filters.gating")


def twist_ar_top(q, h, a_cat):
    """Next increment ``xi = a_cat h`` and rows 0..11 of the step Jacobians.

    Returns ``(xi (6,), top (12, n), jn (12, 6))`` with ``e' = F e + G n`` where ``F`` has
    ``top`` as rows 0..11 and shifts the history below, ``G`` has ``jn`` as rows 0..11.
    """
    n = 6 + a_cat.shape[1]
    top = np.empty((12, n))
    jn = np.empty((12, 6))
    xi = twist_ar_top_into(q, h, a_cat, top, jn)
    return xi, top, jn


def twist_ar_top_into(q, h, a_cat, top, jn):
    """:func:`twist_ar_top` writing into ``top`` (12, n) and ``jn`` (12, 6); returns ``xi``."""
    n = 6 + a_cat.shape[1]
    xi = np.dot(a_cat, h)
    r = rotmat(q)
    jr = right_jac(xi[3:])
    back = rotmat(qexp(-xi[3:]))
    u = xi[:3]
    for i in range(12):
        for c in range(6):
            top[i, c] = 0.0
            jn[i, c] = 0.0
    for i in range(3):
        top[i, i] = 1.0
        # -R [u]x, column by column: [u]x e_c = u x e_c
        for c in range(3):
            top[i, 3 + c] = -(
                r[i, (c + 1) % 3] * u[(c + 2) % 3] - r[i, (c + 2) % 3] * u[(c + 1) % 3]
            )
            top[3 + i, 3 + c] = back[i, c]
            jn[i, c] = r[i, c]
            jn[3 + i, 3 + c] = jr[i, c]
    for i in range(3):
        for c in range(n - 6):
            a0 = a_cat[0, c] * r[i, 0] + a_cat[1, c] * r[i, 1] + a_cat[2, c] * r[i, 2]
            a1 = a_cat[3, c] * jr[i, 0] + a_cat[4, c] * jr[i, 1] + a_cat[5, c] * jr[i, 2]
            top[i, 6 + c] = a0
            top[3 + i, 6 + c] = a1
    for i in range(6):
        jn[6 + i, i] = 1.0
        for c in range(n - 6):
            top[6 + i, 6 + c] = a_cat[i, c]
    return xi


def twist_ar_run(t, pm, qm, a_cat, qn, prior, r_diag, dt, gap, gate, reset_after, status):
    """The autoregressive-twist Kalman filter over a whole recording.

    ``pm`` (N, 3), ``qm`` (N, 4): measured poses; ``qn`` (6, 6): increment noise; ``prior``
    (6, 6): covariance of each history entry after a (re)start; ``r_diag`` (6,): measurement
    variances; ``dt``: model step; ``gap``: restart after longer intervals; ``gate``: NIS
    threshold and ``reset_after`` consecutive gated measurements before a reset (the policy of
    :mod:`trackflow.filters.gating`); ``status`` (N,) receives each measurement's status.
    Returns filtered ``(t (N, 3), q (N, 4), h (N, 6 L), pose covariance (N, 6, 6), nis (N,),
    restarts)``, ``restarts`` counting the starts at the first sample and after gaps.
    """
    ns = t.shape[0]
    nh = a_cat.shape[1]
    n = 6 + nh
    out_p = np.empty((ns, 3))
    out_q = np.empty((ns, 4))
    out_h = np.empty((ns, nh))
    out_c = np.empty((ns, 6, 6))
    nis = np.full(ns, np.nan)
    p = np.zeros(3)
    q = np.zeros(4)
    h = np.zeros(nh)
    cov = np.zeros((n, n))
    fp = np.empty((12, n))
    top = np.empty((12, n))
    jn = np.empty((12, 6))
    idx = np.arange(6)
    mp = np.empty((n, n))
    g = np.empty(6)
    acc = np.empty(n)
    restarts = 0
    gated_run = 0
    for k in range(ns):
        dtk = t[k] - t[k - 1] if k > 0 else np.inf
        fresh = k == 0 or dtk > gap
        if fresh or reset_due(True, gated_run, reset_after):
            for i in range(3):
                p[i] = pm[k, i]
            nq = math.sqrt(qm[k, 0] ** 2 + qm[k, 1] ** 2 + qm[k, 2] ** 2 + qm[k, 3] ** 2)
            for i in range(4):
                q[i] = qm[k, i] / nq
            h[:] = 0.0
            cov[:, :] = 0.0
            for i in range(6):
                cov[i, i] = r_diag[i]
            for j in range(nh // 6):
                for a in range(6):
                    for b in range(6):
                        cov[6 + 6 * j + a, 6 + 6 * j + b] = prior[a, b]
            if fresh:
                restarts += 1
                status[k] = INITIALIZED
            else:
                status[k] = RESET
            gated_run = 0
        else:
            steps = max(1, int(round(dtk / dt)))
            for _ in range(steps):
                xi = twist_ar_top_into(q, h, a_cat, top, jn)
                # covariance, rows 0..11 of F P: the history rows are A_cat P_h (6 L x n), the
                # pose rows add the pose block; F's other rows shift P's rows by one entry
                ac = np.dot(a_cat, np.ascontiguousarray(cov[6:, :]))
                fpose = np.dot(np.ascontiguousarray(top[:6, :6]), np.ascontiguousarray(cov[:6, :]))
                for i in range(3):
                    for j in range(n):
                        fp[6 + i, j] = ac[i, j]
                        fp[9 + i, j] = ac[3 + i, j]
                        fp[i, j] = fpose[i, j]
                        fp[3 + i, j] = fpose[3 + i, j]
                        for c in range(3):
                            fp[i, j] += jn[i, c] * ac[c, j]
                            fp[3 + i, j] += jn[3 + i, 3 + c] * ac[3 + c, j]
                tt = np.dot(fp, top.T) + np.dot(np.dot(jn, qn), jn.T)
                for i in range(n - 1, 11, -1):  # descending: sources are not yet overwritten
                    for j in range(n - 1, 11, -1):
                        cov[i, j] = cov[i - 6, j - 6]
                for i in range(12):
                    for j in range(12):
                        cov[i, j] = tt[i, j]
                    for j in range(12, n):
                        cov[i, j] = fp[i, j - 6]
                        cov[j, i] = fp[i, j - 6]
                # mean: t += R u, q = q Exp(w), the history shifts in xi
                u = np.dot(rotmat(q), xi[:3])
                for i in range(3):
                    p[i] += u[i]
                q = qrplus(q, xi[3:])
                for i in range(nh - 1, 5, -1):
                    h[i] = h[i - 6]
                for i in range(6):
                    h[i] = xi[i]
            zq = qm[k].copy()
            if q[0] * zq[0] + q[1] * zq[1] + q[2] * zq[2] + q[3] * zq[3] < 0.0:
                zq = -zq
            dth = qrminus(zq, q)
            y = np.empty(6)
            for i in range(3):
                y[i] = pm[k, i] - p[i]
                y[3 + i] = dth[i]
            s = np.empty((6, 6))
            for i in range(6):
                for j in range(6):
                    s[i, j] = cov[i, j]
                s[i, i] += r_diag[i]
            s_inv = np.linalg.inv(s)
            sy = np.dot(s_inv, y)
            nis[k] = np.dot(y, sy)
            if is_gated(nis[k], gate):
                status[k] = GATED
            else:
                status[k] = ACCEPTED
            gated_run = next_gated_run(status[k], gated_run)
            if status[k] == ACCEPTED:
                hp = np.ascontiguousarray(cov[:6, :])  # H P with H = [I_6 0]
                kt = np.dot(s_inv, hp)  # K^T (S and P symmetric)
                dx = np.dot(sy, hp)  # K y
                for i in range(3):
                    p[i] += dx[i]
                q = qrplus(q, dx[3:6])
                for i in range(nh):
                    h[i] += dx[6 + i]
                kr = np.empty((n, 6))
                for i in range(n):
                    for a in range(6):
                        kr[i, a] = kt[a, i] * r_diag[a]
                # Joseph form (shared with the derivative filter): stays symmetric positive
                # semi-definite under rounding, unlike P - K H P
                joseph_selection(cov, kt, kr, hp, idx, mp, g, acc)
        for i in range(3):
            out_p[k, i] = p[i]
        for i in range(4):
            out_q[k, i] = q[i]
        for i in range(nh):
            out_h[k, i] = h[i]
        for i in range(6):
            for j in range(6):
                out_c[k, i, j] = cov[i, j]
    return out_p, out_q, out_h, out_c, nis, restarts
