"""Scalar SO(3) and small linear-algebra kernels: the one source every compiled loop uses.

A kernel source for :mod:`trackflow.math._backend`: plain Python on NumPy arrays, kept
numba-compatible (explicit loops, contiguous float64 arrays, no Python objects). The filters and
the composition kernels call these functions by name, and their compiled copies call the
compiled copies of these. Each allocating function is a thin wrapper of its in-place ``*_into``
twin, so every formula is written once.

Quaternions are ``(x, y, z, w)``, Hamilton; rotation vectors in radians; ``Exp``/``Log`` map
between them with series near zero (docs/conventions.md).
"""

from __future__ import annotations

import math

import numpy as np

KERNELS = (
    "sym",
    "fact",
    "qmul_into",
    "qmul",
    "qexp_into",
    "qexp",
    "qlog_into",
    "qlog",
    "rotmat_into",
    "rotmat",
    "right_jac_into",
    "right_jac",
    "left_mult",
    "right_mult",
    "exp_jac",
    "sandwich_into",
    "sandwich",
    "chol_into",
    "chol",
    "chol_solve",
    "chol_solve_rows",
    "joseph_selection",
)
KERNEL_SOURCES = ()

SMALL = 1e-4  # below this angle (rad) the series expansions are used
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


# -- quaternions --------------------------------------------------------------------------------


def qmul_into(a, b, out):
    """``out = a * b`` (Hamilton); ``out`` must not alias ``a`` or ``b``."""
    out[0] = a[3] * b[0] + a[0] * b[3] + a[1] * b[2] - a[2] * b[1]
    out[1] = a[3] * b[1] - a[0] * b[2] + a[1] * b[3] + a[2] * b[0]
    out[2] = a[3] * b[2] + a[0] * b[1] - a[1] * b[0] + a[2] * b[3]
    out[3] = a[3] * b[3] - a[0] * b[0] - a[1] * b[1] - a[2] * b[2]


def qmul(a, b):
    """``a * b`` as a new array (see :func:`qmul_into`)."""
    out = np.empty(4)
    qmul_into(a, b, out)
    return out


def qexp_into(v, out):
    """``out = Exp(v)``: unit quaternion of the rotation vector ``v`` (rad)."""
    t2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    if t2 < SMALL * SMALL:
        k = 0.5 - t2 / 48.0
        out[3] = 1.0 - t2 / 8.0 + t2 * t2 / 384.0
    else:
        t = math.sqrt(t2)
        k = math.sin(0.5 * t) / t
        out[3] = math.cos(0.5 * t)
    out[0] = k * v[0]
    out[1] = k * v[1]
    out[2] = k * v[2]


def qexp(v):
    """``Exp(v)`` as a new array (see :func:`qexp_into`)."""
    out = np.empty(4)
    qexp_into(v, out)
    return out


def qlog_into(q, out):
    """``out`` (3) = ``Log(q)``: rotation vector (rad) of the shortest rotation, ``|Log| <= pi``."""
    s = -1.0 if q[3] < 0.0 else 1.0
    w = s * q[3]
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2])
    if n < 0.5 * SMALL:
        k = 2.0 / w * (1.0 - n * n / (3.0 * w * w))
    else:
        k = 2.0 * math.atan2(n, w) / n
    out[0] = s * k * q[0]
    out[1] = s * k * q[1]
    out[2] = s * k * q[2]


def qlog(q):
    """``Log(q)`` as a new array (see :func:`qlog_into`)."""
    out = np.empty(3)
    qlog_into(q, out)
    return out


def rotmat_into(q, r):
    """``r`` (3x3) = rotation matrix of the unit quaternion ``q``."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    r[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    r[0, 1] = 2.0 * (x * y - w * z)
    r[0, 2] = 2.0 * (x * z + w * y)
    r[1, 0] = 2.0 * (x * y + w * z)
    r[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    r[1, 2] = 2.0 * (y * z - w * x)
    r[2, 0] = 2.0 * (x * z - w * y)
    r[2, 1] = 2.0 * (y * z + w * x)
    r[2, 2] = 1.0 - 2.0 * (x * x + y * y)


def rotmat(q):
    """Rotation matrix of ``q`` as a new array (see :func:`rotmat_into`)."""
    r = np.empty((3, 3))
    rotmat_into(q, r)
    return r


def right_jac_into(v, j):
    """``j`` (3x3) = SO(3) right Jacobian ``Jr(v)``: ``Exp(v + d) ~ Exp(v) Exp(Jr(v) d)``."""
    t2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    if t2 < SMALL * SMALL:
        a = 0.5 - t2 / 24.0
        b = 1.0 / 6.0 - t2 / 120.0
    else:
        t = math.sqrt(t2)
        a = (1.0 - math.cos(t)) / t2
        b = (t - math.sin(t)) / (t2 * t)
    # Jr = I - a [v]x + b [v]x^2 with [v]x^2 = v v^T - |v|^2 I
    for r in range(3):
        for c in range(3):
            j[r, c] = b * v[r] * v[c]
        j[r, r] += 1.0 - b * t2
    j[0, 1] += a * v[2]
    j[0, 2] -= a * v[1]
    j[1, 0] -= a * v[2]
    j[1, 2] += a * v[0]
    j[2, 0] += a * v[1]
    j[2, 1] -= a * v[0]


def right_jac(v):
    """``Jr(v)`` as a new array (see :func:`right_jac_into`)."""
    j = np.empty((3, 3))
    right_jac_into(v, j)
    return j


def left_mult(q):
    """``L(q)`` (4x4) with ``q * p = L(q) p``."""
    m = np.empty((4, 4))
    x, y, z, w = q[0], q[1], q[2], q[3]
    m[0, 0], m[0, 1], m[0, 2], m[0, 3] = w, -z, y, x
    m[1, 0], m[1, 1], m[1, 2], m[1, 3] = z, w, -x, y
    m[2, 0], m[2, 1], m[2, 2], m[2, 3] = -y, x, w, z
    m[3, 0], m[3, 1], m[3, 2], m[3, 3] = -x, -y, -z, w
    return m


def right_mult(d):
    """``M(d)`` (4x4) with ``q * d = M(d) q`` (the upper-left block of the thesis's ``A_R``)."""
    m = np.empty((4, 4))
    x, y, z, w = d[0], d[1], d[2], d[3]
    m[0, 0], m[0, 1], m[0, 2], m[0, 3] = w, z, -y, x
    m[1, 0], m[1, 1], m[1, 2], m[1, 3] = -z, w, x, y
    m[2, 0], m[2, 1], m[2, 2], m[2, 3] = y, -x, w, z
    m[3, 0], m[3, 1], m[3, 2], m[3, 3] = -x, -y, -z, w
    return m


def exp_jac(b):
    """``d Exp(b) / d b`` (4x3); at ``b = 0`` the limit ``[I/2; 0]`` (thesis's B-tilde)."""
    t2 = b[0] * b[0] + b[1] * b[1] + b[2] * b[2]
    j = np.zeros((4, 3))
    if t2 < SMALL * SMALL:
        s = 0.5 - t2 / 48.0  # sin(t/2)/t
        ds = -1.0 / 24.0 + t2 / 960.0  # (d s / d t) / t
        dw = -0.25 + t2 / 96.0  # (d cos(t/2) / d t) / t
    else:
        t = math.sqrt(t2)
        sn = math.sin(0.5 * t)
        cs = math.cos(0.5 * t)
        s = sn / t
        ds = (0.5 * cs * t - sn) / (t2 * t)
        dw = -0.5 * sn / t
    for i in range(3):
        for k in range(3):
            j[i, k] = ds * b[i] * b[k]
        j[i, i] += s
        j[3, i] = dw * b[i]
    return j


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
