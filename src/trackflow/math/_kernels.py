"""Compiled kernels of the uncertain-pose algebra, with the NumPy formulas as reference path.

A kernel source for :mod:`trackflow.math._backend` (``KERNELS`` below), built on the scalar SO(3)
kernels of :mod:`trackflow.math._lie`. With the numba backend, uncertain composition runs
:func:`compose_one` (5-20x faster on single calls and large batches); with the NumPy backend it
runs the vectorised public formulas (:func:`~trackflow.math.jacobians_compose` and
:func:`~trackflow.math.propagate_covariance`), and ``tests/math/test_kernels.py`` checks the two
against each other.
"""

from __future__ import annotations

import sys

import numpy as np

from ._backend import get_backend, kernels
from ._jacobians import jacobians_compose, propagate_covariance
from ._lie import qmul_into, rotmat_into
from ._quaternion import quat_multiply, quat_rotate

__all__ = ["compose", "covariance_is_plainly_valid"]

KERNELS = ("compose_one", "compose_batch", "compose_single", "covariance_code")
KERNEL_SOURCES = ("trackflow.math._lie",)


# -- uncertain composition ----------------------------------------------------------------------


def compose_one(ta, qa, Ca, tb, qb, Cb, Cab, has_cross, t, q, C, Ja, Jb):
    """Scalar kernel: fill one composition result (see ``jacobians_compose`` for formulas)."""
    ra = np.empty((3, 3))
    rb = np.empty((3, 3))
    rotmat_into(qa, ra)
    rotmat_into(qb, rb)
    for i in range(3):
        t[i] = ta[i] + ra[i, 0] * tb[0] + ra[i, 1] * tb[1] + ra[i, 2] * tb[2]
    qmul_into(qa, qb, q)
    # J_c_a = [[I, -R_a [t_b]x], [0, R_b^T]], J_c_b = [[R_a, 0], [0, I]]
    for i in range(6):
        for j in range(6):
            Ja[i, j] = 0.0
            Jb[i, j] = 0.0
    for i in range(3):
        Ja[i, i] = 1.0
        Jb[3 + i, 3 + i] = 1.0
        # -R_a [t_b]x written out column by column
        Ja[i, 3] = -(ra[i, 1] * tb[2] - ra[i, 2] * tb[1])
        Ja[i, 4] = -(ra[i, 2] * tb[0] - ra[i, 0] * tb[2])
        Ja[i, 5] = -(ra[i, 0] * tb[1] - ra[i, 1] * tb[0])
        for j in range(3):
            Ja[3 + i, 3 + j] = rb[j, i]
            Jb[i, j] = ra[i, j]
    # C = Ja Ca Ja^T + Jb Cb Jb^T (+ Ja Cab Jb^T + its transpose)
    tmp = np.empty((6, 6))
    for i in range(6):
        for j in range(6):
            s = 0.0
            for k in range(6):
                s += Ja[i, k] * Ca[k, j]
            tmp[i, j] = s
    for i in range(6):
        for j in range(i, 6):
            s = 0.0
            for k in range(6):
                s += tmp[i, k] * Ja[j, k]
            C[i, j] = s
    for i in range(6):
        for j in range(6):
            s = 0.0
            for k in range(6):
                s += Jb[i, k] * Cb[k, j]
            tmp[i, j] = s
    for i in range(6):
        for j in range(i, 6):
            s = 0.0
            for k in range(6):
                s += tmp[i, k] * Jb[j, k]
            C[i, j] += s
    if has_cross:
        for i in range(6):
            for j in range(6):
                s = 0.0
                for k in range(6):
                    s += Ja[i, k] * Cab[k, j]
                tmp[i, j] = s
        for i in range(6):
            for j in range(i, 6):
                s1 = 0.0
                s2 = 0.0
                for k in range(6):
                    s1 += tmp[i, k] * Jb[j, k]
                    s2 += tmp[j, k] * Jb[i, k]
                C[i, j] += s1 + s2
    for i in range(6):
        for j in range(i + 1, 6):
            C[j, i] = C[i, j]


def compose_batch(ta, qa, Ca, tb, qb, Cb, Cab, has_cross, t, q, C, Ja, Jb):
    """:func:`compose_one` over a flat batch (``Cab`` is one unused matrix without cross terms)."""
    for n in range(ta.shape[0]):
        k = n if has_cross else 0
        compose_one(
            ta[n], qa[n], Ca[n], tb[n], qb[n], Cb[n], Cab[k], has_cross, t[n], q[n],
            C[n], Ja[n], Jb[n],
        )  # fmt: skip


def compose_single(ta, qa, Ca, tb, qb, Cb):
    """:func:`compose_one` for one pair, allocating the outputs."""
    t = np.empty(3)
    q = np.empty(4)
    C = np.empty((6, 6))
    Ja = np.empty((6, 6))
    Jb = np.empty((6, 6))
    compose_one(ta, qa, Ca, tb, qb, Cb, Ca, False, t, q, C, Ja, Jb)
    return t, q, C, Ja, Jb


def covariance_code(c):
    """0: finite, exactly symmetric and PSD; 1: not finite; 2: not symmetric; 3: maybe not PSD.

    The PSD test is a Cholesky factorisation that treats pivots below a relative tolerance as
    zero (allowed when the rest of their column vanishes too), so singular PSD matrices pass.
    Code 3 is confirmed by the caller with an eigenvalue computation.
    """
    n = c.shape[0]
    scale = 0.0
    for i in range(n):
        for j in range(n):
            v = c[i, j]
            if not np.isfinite(v):
                return 1
            if v != c[j, i]:
                return 2
            if abs(v) > scale:
                scale = abs(v)
    tol = 1e-12 * scale
    low = np.zeros((n, n))
    for j in range(n):
        d = c[j, j]
        for k in range(j):
            d -= low[j, k] * low[j, k]
        if d < -tol:
            return 3
        if d <= tol:
            for i in range(j + 1, n):
                s = c[i, j]
                for k in range(j):
                    s -= low[i, k] * low[j, k]
                if abs(s) > 1e-6 * scale:
                    return 3
            continue
        r = np.sqrt(d)
        low[j, j] = r
        for i in range(j + 1, n):
            s = c[i, j]
            for k in range(j):
                s -= low[i, k] * low[j, k]
            low[i, j] = s / r
    return 0


def covariance_is_plainly_valid(c: np.ndarray) -> bool:
    """Fast check of one (n, n) float matrix: finite, exactly symmetric and PSD.

    ``False`` means "look closer" (the caller runs the detailed checks that name the problem).
    Both backends answer ``True`` for finite, exactly symmetric positive-definite matrices; the
    compiled one also for singular PSD ones, which the NumPy path leaves to the closer look.
    """
    if c.ndim != 2:
        return False
    if get_backend() == "numba":
        return kernels(_self()).covariance_code(c) == 0
    if not (np.isfinite(c).all() and np.array_equal(c, c.T)):
        return False
    try:
        np.linalg.cholesky(c)
    except np.linalg.LinAlgError:
        return False
    return True


def _self():
    return sys.modules[__name__]


_ZERO66 = np.zeros((1, 6, 6))


def compose(ta, qa, Ca, tb, qb, Cb, Cab=None):
    """Uncertain composition on raw arrays: ``(t_c, q_c, C_c, J_c_a, J_c_b)``.

    Inputs broadcast over leading dimensions; ``Cab`` is the optional cross-covariance.
    """
    if get_backend() == "numpy":
        J_c_a, J_c_b = jacobians_compose(ta, qa, tb, qb)
        c = propagate_covariance(J_c_a, Ca, J_c_b, Cb, Cab)
        return ta + quat_rotate(qa, tb), quat_multiply(qa, qb), c, J_c_a, J_c_b
    k = kernels(_self())
    if Cab is None and ta.ndim == 1 and qa.ndim == 1 and tb.ndim == 1 and qb.ndim == 1:
        # Single poses skip all batching overhead. Arrays held by Pose/UncertainPose are
        # always C-contiguous writable float64, so this compiles one specialisation.
        if Ca.ndim == 2 and Cb.ndim == 2:
            return k.compose_single(ta, qa, Ca, tb, qb, Cb)
    shape = np.broadcast_shapes(
        ta.shape[:-1], qa.shape[:-1], Ca.shape[:-2], tb.shape[:-1], qb.shape[:-1], Cb.shape[:-2]
    )
    if Cab is not None:
        shape = np.broadcast_shapes(shape, Cab.shape[:-2])
    n = int(np.prod(shape))

    def flat(x, tail):
        # One array type for numba (C-contiguous, writable float64): every distinct layout or
        # read-only flag would otherwise compile (and cache) another specialisation.
        x = np.broadcast_to(x, shape + tail) if x.shape != shape + tail else x
        return np.require(x, dtype=float, requirements=("C", "W")).reshape((n,) + tail)

    t = np.empty((n, 3))
    q = np.empty((n, 4))
    C = np.empty((n, 6, 6))
    Ja = np.empty((n, 6, 6))
    Jb = np.empty((n, 6, 6))
    cab = flat(Cab, (6, 6)) if Cab is not None else _ZERO66
    k.compose_batch(
        flat(ta, (3,)), flat(qa, (4,)), flat(Ca, (6, 6)), flat(tb, (3,)), flat(qb, (4,)),
        flat(Cb, (6, 6)), cab, Cab is not None, t, q, C, Ja, Jb,
    )  # fmt: skip
    return (
        t.reshape(shape + (3,)),
        q.reshape(shape + (4,)),
        C.reshape(shape + (6, 6)),
        Ja.reshape(shape + (6, 6)),
        Jb.reshape(shape + (6, 6)),
    )
