"""Kernel source of the distributed package (:mod:`trackflow.math._backend`): the numeric
checks of a received filter state, in one pass, so a consumer's per-message work stays small.

Plain Python on NumPy arrays, numba-compatible (explicit loops, float64 arrays).
"""

from __future__ import annotations

import math

from trackflow.math._scalar import chol_into

KERNELS = ("unpack_state",)
KERNEL_SOURCES = ("trackflow.math._scalar",)

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
