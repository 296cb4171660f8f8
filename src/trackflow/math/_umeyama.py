"""The one closed-form point-set fit of trackflow: weighted Umeyama / Kabsch / Wahba.

:func:`umeyama` finds the rigid motion (optionally with a scale) that maps one set of points
onto corresponding points, in least squares with per-point weights. Trajectory alignment
(``trackflow.evaluation``, ``trackflow.calibration``), absolute orientation of a marker body
(``trackflow.optical``), the rotation of the hand-eye and clock-offset calibrations and the
IMU-to-body rotation all call it; callers add their own refusals (too little spread, opposite
handedness) on top of what it reports.

The fit itself is a kernel (:func:`umeyama_into`, this module is a kernel source for
:mod:`trackflow.math._backend`): :func:`umeyama` drives it, and compiled loops (the optical
tracker's pose fit) call it directly.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ._backend import frozen
from ._backend import kernels as _kernels

__all__ = ["UmeyamaFit", "umeyama"]

KERNELS = ("det3", "umeyama_into", "umeyama_batch")
KERNELS_INLINE = ("det3",)
KERNEL_SOURCES = ()
INFO = 6  # umeyama_into's info: scale, residual, three singular values, reflected (0 or 1)

# The cross-covariance has rank < 2 (collinear points, rotation about their line unknown)
# when its second singular value is below this fraction of the first.
_RANK_TOLERANCE = 1e-12


@dataclass(frozen=True)
class UmeyamaFit:
    """Result of :func:`umeyama`: ``a ~ scale R_a_b b + t_a_b``.

    Every field has the leading (batch) dimensions of the input points, written ``...`` below;
    for a single fit the scalars are plain ``float`` / ``bool``.

    Attributes
    ----------
    rotation : ndarray (..., 3, 3)
        ``R_a_b``, a proper rotation (det +1) taking b's coordinates into a's.
    translation : ndarray (..., 3)
        ``t_a_b``: position of b's origin in a, in a's units (after scaling).
    scale : float or ndarray (...)
        ``s`` (1 unless fitted): a length of b times ``s`` is a length of a.
    residual : float or ndarray (...)
        Weighted RMS distance ``sqrt(sum w_i |a_i - (s R b_i + t)|^2 / sum w_i)``, in a's units.
    singular_values : ndarray (..., 3)
        Singular values (descending) of the weighted cross-covariance
        ``sum w_i (a_i - a_c)(b_i - b_c)^T / sum w_i``: its spread (collinear points give one
        nonzero value).
    reflected : bool or ndarray (...) of bool
        Whether the best orthogonal map was a reflection, so that ``rotation`` is the best
        proper rotation instead (the point sets have opposite handedness when
        ``singular_values[2]`` is not small too).
    """

    rotation: np.ndarray
    translation: np.ndarray
    scale: np.ndarray
    residual: np.ndarray
    singular_values: np.ndarray
    reflected: np.ndarray

    def apply(self, points_b: np.ndarray) -> np.ndarray:
        """``s R_a_b p + t_a_b`` of points (..., M, 3) given in b: the same points in a."""
        p = np.asarray(points_b, dtype=float)
        s = np.asarray(self.scale)[..., None, None]
        return (
            s * np.einsum("...ij,...mj->...mi", self.rotation, p) + self.translation[..., None, :]
        )


def umeyama(
    points_a,
    points_b,
    weights=None,
    *,
    with_scale: bool = False,
    with_translation: bool = True,
    allow_collinear: bool = False,
) -> UmeyamaFit:
    """Weighted least-squares ``T_a_b`` (and scale) mapping ``points_b`` onto ``points_a``.

    Minimises ``sum_i w_i |a_i - (s R_a_b b_i + t_a_b)|^2`` in closed form (Umeyama 1991; Kabsch
    / Wahba for the rotation): the weighted centroids and cross-covariance, its SVD, and the
    determinant's sign so that the rotation is proper. The convention is trackflow's
    (``docs/conventions.md``): ``T_a_b`` maps b into a, so with ``points_b`` a body's markers in
    its own frame and ``points_a`` the same markers measured in the world, the result is
    ``T_world_body``.

    Parameters
    ----------
    points_a, points_b : array_like (..., M, 3)
        Corresponding points in frames a and b, ``M >= 3`` (``M >= 2`` without translation);
        leading dimensions are independent fits.
    weights : array_like (..., M) or (M,), optional
        Non-negative weights with a positive sum (default equal). Only their ratios matter.
    with_scale : bool
        Fit the scale ``s`` (a similarity, Sim(3)); else ``s = 1`` (SE(3)).
    with_translation : bool
        Fit ``t_a_b``; ``False`` fits a rotation (and scale) about the origins only: the
        vectors are not centred (Wahba's problem for directions).
    allow_collinear : bool
        Return a fit of points on a line (or of fewer than two independent directions) instead
        of raising; the rotation about that line is then arbitrary.

    Returns
    -------
    UmeyamaFit

    Raises
    ------
    ValueError
        Shapes that do not match, too few points, bad weights, or (unless ``allow_collinear``)
        collinear points.
    """
    a = np.asarray(points_a, dtype=float)
    b = np.asarray(points_b, dtype=float)
    need = 3 if with_translation else 2
    if a.shape != b.shape or a.ndim < 2 or a.shape[-1] != 3 or a.shape[-2] < need:
        raise InputError(
            f"need two (M, 3) point sets of the same shape with M >= {need}, got {a.shape} "
            f"and {b.shape}"
        )
    batch, m = a.shape[:-2], a.shape[-2]
    if weights is None:
        w = np.ones(a.shape[:-1])
    else:
        w = np.broadcast_to(np.asarray(weights, dtype=float), a.shape[:-1])
        total = w.sum(axis=-1)
        if np.any(w < 0) or not np.all(total > 0) or not np.all(np.isfinite(w)):
            raise InputError("weights must be (M,) non-negative and finite, with a positive sum")
    n = int(np.prod(batch))
    rotation = np.empty((n, 3, 3))
    translation = np.empty((n, 3))
    info = np.empty((n, INFO))
    _kernels(sys.modules[__name__]).umeyama_batch(
        frozen(a.reshape(n, m, 3)),
        frozen(b.reshape(n, m, 3)),
        frozen(w.reshape(n, m)),
        int(with_scale),
        int(with_translation),
        rotation,
        translation,
        info,
    )
    sv = info[:, 2:5]
    if not allow_collinear and np.any(sv[:, 1] <= _RANK_TOLERANCE * sv[:, 0]):
        raise InputError(
            "the points are collinear (or all equal): the rotation about their line is unknown"
        )
    if not batch:  # one fit: plain numbers
        s, r, f = float(info[0, 0]), float(info[0, 1]), bool(info[0, 5])
        return UmeyamaFit(rotation[0], translation[0], s, r, sv[0].copy(), f)
    return UmeyamaFit(
        rotation.reshape(batch + (3, 3)),
        translation.reshape(batch + (3,)),
        info[:, 0].reshape(batch),
        info[:, 1].reshape(batch),
        sv.reshape(batch + (3,)),
        info[:, 5].reshape(batch) > 0.5,
    )


def det3(m):
    """Determinant of a 3x3 matrix."""
    return (
        m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
        - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
        + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0])
    )


def umeyama_into(a, b, w, with_scale, with_translation, rot, trans, info):
    """Kernel of :func:`umeyama` for one fit: ``a ~ s R b + t`` for points ``a, b`` (M, 3).

    ``w`` (M,) non-negative weights with a positive sum; ``with_scale`` and ``with_translation``
    are 0 or 1. Writes ``rot`` (3, 3), ``trans`` (3,) and ``info`` (6,): scale, weighted RMS
    residual, the cross-covariance's singular values (descending), 1.0 if the best
    orthogonal map was a reflection (else 0.0). Does not check for collinear points.
    """
    m = a.shape[0]
    total = 0.0
    for i in range(m):
        total += w[i]
    ca = np.zeros(3)
    cb = np.zeros(3)
    if with_translation:
        for i in range(m):
            wi = w[i] / total
            for k in range(3):
                ca[k] += wi * a[i, k]
                cb[k] += wi * b[i, k]
    cross = np.zeros((3, 3))
    var_b = 0.0
    for i in range(m):
        wi = w[i] / total
        for r in range(3):
            da = wi * (a[i, r] - ca[r])
            for c in range(3):
                cross[r, c] += da * (b[i, c] - cb[c])
        for c in range(3):
            db = b[i, c] - cb[c]
            var_b += wi * db * db
    u, sv, vt = np.linalg.svd(cross)
    sign = -1.0 if det3(u) * det3(vt) < 0.0 else 1.0
    for r in range(3):
        for c in range(3):
            rot[r, c] = u[r, 0] * vt[0, c] + u[r, 1] * vt[1, c] + sign * u[r, 2] * vt[2, c]
    s = (sv[0] + sv[1] + sign * sv[2]) / var_b if with_scale else 1.0
    for r in range(3):
        trans[r] = ca[r] - s * (rot[r, 0] * cb[0] + rot[r, 1] * cb[1] + rot[r, 2] * cb[2])
    e2 = 0.0
    for i in range(m):
        wi = w[i] / total
        for r in range(3):
            fit = rot[r, 0] * b[i, 0] + rot[r, 1] * b[i, 1] + rot[r, 2] * b[i, 2]
            d = a[i, r] - s * fit - trans[r]
            e2 += wi * d * d
    info[0] = s
    info[1] = np.sqrt(e2)
    info[2] = sv[0]
    info[3] = sv[1]
    info[4] = sv[2]
    info[5] = 1.0 if sign < 0.0 else 0.0


def umeyama_batch(a, b, w, with_scale, with_translation, rot, trans, info):
    """:func:`umeyama_into` for each of ``T`` fits: ``a, b`` (T, M, 3), ``w`` (T, M), outputs
    ``rot`` (T, 3, 3), ``trans`` (T, 3), ``info`` (T, 6)."""
    for k in range(a.shape[0]):
        umeyama_into(a[k], b[k], w[k], with_scale, with_translation, rot[k], trans[k], info[k])
