"""Input validation at the library boundary.

Every check raises ``ValueError`` with a message that names what is wrong (which argument,
which item of a batch, and the offending value), so that bad data never travels further.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from ._kernels import covariance_is_plainly_valid

__all__ = [
    "check_trajectory",
    "check_position",
    "check_quaternion",
    "check_covariance",
    "UNIT_TOLERANCE",
]

#: Largest accepted deviation of ``|q|`` from 1 when normalisation was not requested.
UNIT_TOLERANCE = 1e-6


def _where(bad: np.ndarray) -> str:
    """Describe the first offending batch index (empty for a single item)."""
    if bad.ndim == 0:
        return ""
    idx = tuple(int(i) for i in np.argwhere(bad)[0])
    return f" at index {idx[0] if len(idx) == 1 else idx}"


def _as_float_array(x, name: str, last: tuple[int, ...]) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be numeric, got {type(x).__name__}") from exc
    if a.shape[a.ndim - len(last) :] != last or a.ndim < len(last):
        want = "(..., " + ", ".join(str(n) for n in last) + ")"
        raise InputError(f"{name} must have shape {want}, got {a.shape}")
    if not np.isfinite(a.sum()):  # one reduction decides the common, all-finite case
        finite = np.isfinite(a).all(axis=tuple(range(-len(last), 0)))
        if not np.all(finite):
            raise InputError(f"{name} contains NaN or inf{_where(~finite)}")
    return a


def check_position(position, name: str = "position") -> np.ndarray:
    """Return ``position`` as a float array of shape (..., 3), all finite."""
    return _as_float_array(position, name, (3,))


def check_quaternion(quaternion, normalize: bool = False, name: str = "quaternion") -> np.ndarray:
    """Return a unit quaternion array (..., 4) in ``(x, y, z, w)`` order.

    Parameters
    ----------
    quaternion : array_like, shape (..., 4)
    normalize : bool
        If true, any non-zero finite quaternion is scaled to unit length. Otherwise a norm
        farther than ``UNIT_TOLERANCE`` from 1 is an error (it usually means a wrong order,
        such as ``(w, x, y, z)``, or corrupted data); smaller deviations are renormalised.
    """
    q = _as_float_array(quaternion, name, (4,))
    if q.ndim == 1:  # single quaternion: scalar arithmetic is much cheaper than ufuncs
        n1 = math.sqrt(float(q @ q))
        if n1 != 0.0 and (normalize or abs(n1 - 1.0) <= UNIT_TOLERANCE):
            return q / n1
    n = np.linalg.norm(q, axis=-1)
    if np.any(n == 0.0):
        raise InputError(f"{name} is zero{_where(n == 0.0)}")
    off = np.abs(n - 1.0) > UNIT_TOLERANCE
    if not normalize and np.any(off):
        bad = np.abs(n - 1.0)
        where = _where(off)
        worst = float(np.max(bad))
        raise InputError(
            f"{name} is not unit length{where}: |q| - 1 = {worst:.3g} "
            f"(tolerance {UNIT_TOLERANCE:g}; pass normalize=True to accept it)"
        )
    return q / n[..., None]


def check_covariance(covariance, name: str = "covariance", size: int = 6) -> np.ndarray:
    """Return ``covariance`` as a float array (..., size, size): symmetric and PSD.

    Symmetry is required to a relative tolerance of ``1e-9`` of the largest entry and the
    smallest eigenvalue may not be below ``-1e-12`` times the largest; the returned matrix is
    exactly symmetrised.
    """
    if type(covariance) is np.ndarray and covariance.dtype == np.float64:
        if covariance.shape == (size, size) and covariance_is_plainly_valid(covariance):
            return covariance
    c = _as_float_array(covariance, name, (size, size))
    ct = np.swapaxes(c, -1, -2)
    if not np.array_equal(c, ct):
        scale = np.max(np.abs(c), axis=(-2, -1))
        asym = np.max(np.abs(c - ct), axis=(-2, -1))
        bad = asym > 1e-9 * np.maximum(scale, 1e-300)
        if np.any(bad):
            raise InputError(
                f"{name} is not symmetric{_where(bad)}: max |C - C^T| = {float(np.max(asym)):.3g}"
            )
        c = 0.5 * (c + ct)
    ok = True
    try:
        np.linalg.cholesky(c)
    except np.linalg.LinAlgError:
        ok = False
    if not ok:  # positive semi-definite but singular matrices are allowed
        eig = np.linalg.eigvalsh(c)
        low = eig[..., 0] < -1e-12 * np.maximum(eig[..., -1], 1e-300)
        if np.any(low):
            raise InputError(
                f"{name} is not positive semi-definite{_where(low)}: smallest eigenvalue "
                f"{float(np.min(eig[..., 0])):.3g}"
            )
    return c


def check_trajectory(t, position, quaternion, min_samples: int = 1, what: str = "the input"):
    """Validate a sampled trajectory: ``(t (N,), p (N, 3), q (N, 4))`` as contiguous floats.

    Raises ``ValueError`` naming the problem: wrong shapes, fewer than ``min_samples`` samples,
    non-finite values, or times not strictly increasing (naming the sample and both times).
    ``what`` names the data in the hint ("clean ...").
    """
    t = np.ascontiguousarray(t, dtype=float).reshape(-1)
    p = np.ascontiguousarray(position, dtype=float)
    q = np.ascontiguousarray(quaternion, dtype=float)
    if p.shape != (t.shape[0], 3) or q.shape != (t.shape[0], 4):
        raise InputError(
            f"need times (N,), positions (N, 3), quaternions (N, 4); got {t.shape}, "
            f"{p.shape}, {q.shape}"
        )
    if t.shape[0] < min_samples:
        raise InputError(f"need at least {min_samples} samples, got {t.shape[0]}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
        raise InputError(f"times, positions and quaternions must be finite (clean {what})")
    if t.shape[0] > 1 and np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise InputError(f"times must increase strictly (sample {k}): {t[k]} after {t[k - 1]}")
    return t, p, q
