"""Small linear-algebra kernels: the one source every compiled loop uses.

A kernel source for :mod:`trackflow.math._backend`: plain Python on NumPy arrays, kept
numba-compatible (explicit loops, contiguous float64 arrays, no Python objects). The filters and
the composition kernels call these functions by name, and their compiled copies call the
compiled copies of these. Each allocating function is a thin wrapper of its in-place ``*_into``
twin, so every formula is written once.

The SO(3) kernels (``Exp``, ``Log``, ``Jr``, rplus, rminus, between) are in
:mod:`trackflow.math._lie`.
"""

from __future__ import annotations

import math

import numpy as np

KERNELS = (
    "sym",
    "fact",
    "sandwich_into",
    "sandwich",
    "chol_into",
    "chol",
    "chol_solve",
    "chol_solve_rows",
    "joseph_selection",
)
KERNEL_SOURCES = ()

# Covariance entries below this are flushed to zero: cross terms that are zero in theory
# otherwise decay into denormal numbers, which make every later operation ~10x slower.
TINY = 1e-150


def sym(a):
    """``(A + A^T) / 2`` as a new C-contiguous array."""
    n = a.shape[0]
    out = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            out[i, j] = 0.5 * (a[i, j] + a[j, i])
    return out


def fact(k):
    """``k!`` as a float."""
    r = 1.0
    for i in range(2, k + 1):
        r *= i
    return r


# -- small linear algebra -----------------------------------------------------------------------


def sandwich_into(a, p, q, tmp, vals, cols):
    """``p <- A P A^T + Q`` (symmetric) in place, over the nonzeros of the sparse ``A`` only.

    ``tmp`` and ``vals`` (n x n) and ``cols`` (n x (n + 1), int) are scratch: row ``i`` of
    ``A`` has ``cols[i, 0]`` nonzeros, in columns ``cols[i, 1:]`` with values ``vals[i]``. Each
    entry is the sum of its nonzero terms in ascending column order, starting from zero.
    """
    n = p.shape[0]
    for i in range(n):
        c = 0
        for k in range(n):
            v = a[i, k]
            if v != 0.0:  # the same zeros in every call of a filter: a predictable branch
                cols[i, 1 + c] = k
                vals[i, c] = v
                c += 1
        cols[i, 0] = c
    for i in range(n):
        nz = cols[i, 0]
        if nz == 0:
            for j in range(n):
                tmp[i, j] = 0.0
            continue
        k = cols[i, 1]
        v = vals[i, 0]
        for j in range(n):  # the first term added to zero, as the sum's definition says
            tmp[i, j] = 0.0 + v * p[k, j]
        for t in range(1, nz):
            k = cols[i, 1 + t]
            v = vals[i, t]
            for j in range(n):
                tmp[i, j] += v * p[k, j]
    for j in range(n):
        nz = cols[j, 0]
        for i in range(j + 1):
            s = 0.0
            for t in range(nz):
                s += tmp[i, cols[j, 1 + t]] * vals[j, t]
            w = s + 0.5 * (q[i, j] + q[j, i])
            if abs(w) < TINY:
                w = 0.0
            p[i, j] = w
            p[j, i] = w


def sandwich(a, p, q):
    """``A P A^T + Q`` (symmetric) as a new array; see :func:`sandwich_into`."""
    n = p.shape[0]
    out = p.copy()
    sandwich_into(a, out, q, np.empty((n, n)), np.empty((n, n)), np.empty((n, n + 1), np.int64))
    return out


def chol_into(s, lo):
    """Lower Cholesky factor of ``s`` into ``lo``; ``False`` if ``s`` is not positive definite."""
    n = s.shape[0]
    for i in range(n):
        for j in range(n):
            lo[i, j] = 0.0
    for j in range(n):
        d = s[j, j]
        for k in range(j):
            d -= lo[j, k] * lo[j, k]
        if not d > 0.0:
            return False
        lo[j, j] = math.sqrt(d)
        for i in range(j + 1, n):
            v = s[i, j]
            for k in range(j):
                v -= lo[i, k] * lo[j, k]
            lo[i, j] = v / lo[j, j]
    return True


def chol(s):
    """``(L, ok)``: lower Cholesky factor as a new array (see :func:`chol_into`)."""
    n = s.shape[0]
    lo = np.zeros((n, n))
    ok = chol_into(s, lo)
    return lo, ok


def chol_solve(lo, b):
    """Solve ``L L^T X = B`` for ``B`` of shape (n, k); returns a new array."""
    x = b.copy()
    chol_solve_rows(lo, x)
    return x


def chol_solve_rows(lo, b):
    """Solve ``L L^T X = B`` in place for ``B`` of shape (n, k), row operations (contiguous)."""
    n = lo.shape[0]
    k = b.shape[1]
    for i in range(n):
        for j in range(i):
            f = lo[i, j]
            for c in range(k):
                b[i, c] -= f * b[j, c]
        d = 1.0 / lo[i, i]
        for c in range(k):
            b[i, c] *= d
    for i in range(n - 1, -1, -1):
        for j in range(i + 1, n):
            f = lo[j, i]
            for c in range(k):
                b[i, c] -= f * b[j, c]
        d = 1.0 / lo[i, i]
        for c in range(k):
            b[i, c] *= d


def joseph_selection(p, kt, kr, hp, idx, mp, g, acc):
    """Joseph-form covariance update for a measurement that selects state rows ``idx``.

    ``(I - K H) P (I - K H)^T + K R K^T = MP + (K R - MP H^T) K^T`` with ``MP = P - K (H P)``:
    it keeps ``P`` symmetric positive definite even when ``K`` is not exactly optimal
    (rounding, gating, clipped angular velocity), which the short form ``P - K H P`` does not.
    ``kt`` is ``K^T``, ``kr`` is ``K R`` and ``hp`` is ``H P``; ``mp``, ``g`` and ``acc`` are
    scratch buffers. Writes ``P`` in place, upper triangle mirrored.
    """
    nc = p.shape[0]
    m = kt.shape[0]
    for i in range(nc):
        for j in range(nc):
            mp[i, j] = p[i, j]
    for i in range(nc):
        for a in range(m):
            ka = kt[a, i]
            for j in range(nc):
                mp[i, j] -= ka * hp[a, j]
    for i in range(nc):
        for a in range(m):
            g[a] = kr[i, a] - mp[i, idx[a]]
        # The whole row is summed (loops of one fixed length run faster than ones from i),
        # its upper triangle kept: the lower one is its mirror.
        for j in range(nc):
            acc[j] = mp[i, j]
        for a in range(m):
            ga = g[a]
            for j in range(nc):
                acc[j] += ga * kt[a, j]
        for j in range(i, nc):
            w = acc[j]
            if abs(w) < TINY:
                w = 0.0
            p[i, j] = w
            p[j, i] = w
