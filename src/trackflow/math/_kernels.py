"""Compiled kernels for hot paths, with a pure-NumPy reference path.

trackflow runs on NumPy alone; when numba is importable, hot operations (uncertain composition)
are compiled for a 5-20x speed-up on single calls and large batches. Both paths compute the
same formulas and ``tests/math/test_kernels.py`` checks them against each other.

The backend is chosen once at import (``TRACKFLOW_BACKEND=numpy`` forces NumPy) and can be
switched for a block of code with :func:`use_backend`, which always restores the previous one.
numba's compile cache goes to ``$NUMBA_CACHE_DIR`` if set, else to a per-user cache directory
(``$XDG_CACHE_HOME/trackflow/numba`` or ``~/.cache/trackflow/numba``), never into the source tree.
The choice is given to numba's configuration only (``numba.config.CACHE_DIR``); the process
environment is left alone, so other numba users in the process and child processes keep their
own settings.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

import numpy as np

from ._jacobians import jacobians_compose, propagate_covariance
from ._quaternion import quat_multiply, quat_rotate

__all__ = [
    "get_backend",
    "set_backend",
    "use_backend",
    "numba_available",
    "compose",
    "covariance_is_plainly_valid",
]


def _cache_dir() -> str:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    for root in (Path(base), Path(tempfile.gettempdir())):
        d = root / "trackflow" / "numba"
        try:
            d.mkdir(parents=True, exist_ok=True)
            if os.access(d, os.W_OK):
                return str(d)
        except OSError:
            continue
    return tempfile.mkdtemp(prefix="trackflow-numba-")


try:  # numba is optional: the library must keep working without it
    import numba as _nb
except ImportError:  # pragma: no cover - exercised only on installs without numba
    _nb = None
else:
    if not os.environ.get("NUMBA_CACHE_DIR"):
        _nb.config.CACHE_DIR = _cache_dir()

_backend = "numba" if _nb is not None else "numpy"
if os.environ.get("TRACKFLOW_BACKEND", "").lower() == "numpy":
    _backend = "numpy"


def numba_available() -> bool:
    """Whether the compiled backend can be used."""
    return _nb is not None


def get_backend() -> str:
    """The active backend name, ``"numba"`` or ``"numpy"``."""
    return _backend


def set_backend(name: str) -> None:
    """Select ``"numba"`` or ``"numpy"`` for all following calls (prefer :func:`use_backend`)."""
    global _backend
    if name not in ("numba", "numpy"):
        raise ValueError(f"unknown backend {name!r}; use 'numba' or 'numpy'")
    if name == "numba" and _nb is None:
        raise ValueError("numba backend requested but numba is not installed")
    _backend = name


@contextlib.contextmanager
def use_backend(name: str):
    """Context manager selecting a backend and restoring the previous one afterwards."""
    old = _backend
    set_backend(name)
    try:
        yield
    finally:
        set_backend(old)


# -- uncertain composition ----------------------------------------------------------------------


def _compose_numpy(ta, qa, Ca, tb, qb, Cb, Cab):
    J_c_a, J_c_b = jacobians_compose(ta, qa, tb, qb)
    c = propagate_covariance(J_c_a, Ca, J_c_b, Cb, Cab)
    return ta + quat_rotate(qa, tb), quat_multiply(qa, qb), c, J_c_a, J_c_b


def _rotation_matrix(x, y, z, w, r):
    r[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    r[0, 1] = 2.0 * (x * y - w * z)
    r[0, 2] = 2.0 * (x * z + w * y)
    r[1, 0] = 2.0 * (x * y + w * z)
    r[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    r[1, 2] = 2.0 * (y * z - w * x)
    r[2, 0] = 2.0 * (x * z - w * y)
    r[2, 1] = 2.0 * (y * z + w * x)
    r[2, 2] = 1.0 - 2.0 * (x * x + y * y)


def _compose_one(ta, qa, Ca, tb, qb, Cb, Cab, has_cross, t, q, C, Ja, Jb):
    """Scalar kernel: fill one composition result (see ``jacobians_compose`` for formulas)."""
    ax, ay, az, aw = qa[0], qa[1], qa[2], qa[3]
    bx, by, bz, bw = qb[0], qb[1], qb[2], qb[3]
    ra = np.empty((3, 3))
    rb = np.empty((3, 3))
    _rotation_matrix(ax, ay, az, aw, ra)
    _rotation_matrix(bx, by, bz, bw, rb)
    for i in range(3):
        t[i] = ta[i] + ra[i, 0] * tb[0] + ra[i, 1] * tb[1] + ra[i, 2] * tb[2]
    q[0] = aw * bx + ax * bw + ay * bz - az * by
    q[1] = aw * by - ax * bz + ay * bw + az * bx
    q[2] = aw * bz + ax * by - ay * bx + az * bw
    q[3] = aw * bw - ax * bx - ay * by - az * bz
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


if _nb is not None:
    _rotation_matrix = _nb.njit(cache=True, inline="always")(_rotation_matrix)
    _compose_one = _nb.njit(cache=True)(_compose_one)

    @_nb.njit(cache=True)
    def _compose_batch_jit(ta, qa, Ca, tb, qb, Cb, Cab, has_cross, t, q, C, Ja, Jb):
        for n in range(ta.shape[0]):
            k = n if has_cross else 0  # without cross terms Cab is one unused zero matrix
            _compose_one(
                ta[n], qa[n], Ca[n], tb[n], qb[n], Cb[n], Cab[k], has_cross, t[n], q[n],
                C[n], Ja[n], Jb[n],
            )  # fmt: skip

    @_nb.njit(cache=True)
    def _compose_single_jit(ta, qa, Ca, tb, qb, Cb):
        t = np.empty(3)
        q = np.empty(4)
        C = np.empty((6, 6))
        Ja = np.empty((6, 6))
        Jb = np.empty((6, 6))
        _compose_one(ta, qa, Ca, tb, qb, Cb, Ca, False, t, q, C, Ja, Jb)
        return t, q, C, Ja, Jb


def _covariance_code(c):
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


if _nb is not None:
    _covariance_code_jit = _nb.njit(cache=True)(_covariance_code)


def covariance_is_plainly_valid(c: np.ndarray) -> bool:
    """Fast check of one (n, n) float matrix: finite, exactly symmetric and PSD.

    ``False`` means "look closer" (the caller runs the detailed checks that name the problem).
    """
    if _backend == "numba" and c.ndim == 2:
        return _covariance_code_jit(c) == 0
    return False


_ZERO66 = np.zeros((1, 6, 6))


def compose(ta, qa, Ca, tb, qb, Cb, Cab=None):
    """Uncertain composition on raw arrays: ``(t_c, q_c, C_c, J_c_a, J_c_b)``.

    Inputs broadcast over leading dimensions; ``Cab`` is the optional cross-covariance.
    """
    if _backend == "numpy":
        return _compose_numpy(ta, qa, Ca, tb, qb, Cb, Cab)
    if Cab is None and ta.ndim == 1 and qa.ndim == 1 and tb.ndim == 1 and qb.ndim == 1:
        # Single poses skip all batching overhead. Arrays held by Pose/UncertainPose are
        # always C-contiguous writable float64, so this compiles one specialisation.
        if Ca.ndim == 2 and Cb.ndim == 2:
            return _compose_single_jit(ta, qa, Ca, tb, qb, Cb)
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
    _compose_batch_jit(
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
