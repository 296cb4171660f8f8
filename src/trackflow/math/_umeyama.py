"""The one closed-form point-set fit of trackflow: weighted Umeyama / Kabsch / Wahba.

:func:`umeyama` finds the rigid motion (optionally with a scale) that maps one set of points
onto corresponding points, in least squares with per-point weights. Trajectory alignment
(``trackflow.evaluation``, ``trackflow.calibration``), absolute orientation of a marker body
(``trackflow.optical``), the rotation of the hand-eye and clock-offset calibrations and the
IMU-to-body rotation all call it; callers add their own refusals (too little spread, opposite
handedness) on top of what it reports.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["UmeyamaFit", "umeyama"]

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
        raise ValueError(
            f"need two (M, 3) point sets of the same shape with M >= {need}, got {a.shape} "
            f"and {b.shape}"
        )
    m = a.shape[-2]
    if weights is None:
        w = np.full(a.shape[:-1], 1.0 / m)
    else:
        w = np.broadcast_to(np.asarray(weights, dtype=float), a.shape[:-1])
        total = w.sum(axis=-1, keepdims=True)
        if np.any(w < 0) or not np.all(total > 0) or not np.all(np.isfinite(w)):
            raise ValueError("weights must be (M,) non-negative and finite, with a positive sum")
        w = w / total
    if with_translation:
        ca = np.einsum("...m,...mi->...i", w, a)
        cb = np.einsum("...m,...mi->...i", w, b)
        da = a - ca[..., None, :]
        db = b - cb[..., None, :]
    else:
        ca = cb = np.zeros(a.shape[:-2] + (3,))
        da, db = a, b
    cross = np.einsum("...m,...mi,...mj->...ij", w, da, db)
    u, sv, vt = np.linalg.svd(cross)
    if not allow_collinear and np.any(sv[..., 1] <= _RANK_TOLERANCE * sv[..., 0]):
        raise ValueError(
            "the points are collinear (or all equal): the rotation about their line is unknown"
        )
    sign = np.sign(np.linalg.det(u) * np.linalg.det(vt))
    sign = np.where(sign == 0.0, 1.0, sign)
    d = np.ones(sv.shape)
    d[..., 2] = sign
    rotation = np.einsum("...ij,...j,...jk->...ik", u, d, vt)
    if with_scale:
        var_b = np.einsum("...m,...mi,...mi->...", w, db, db)
        scale = np.sum(sv * d, axis=-1) / var_b
    else:
        scale = np.ones(a.shape[:-2])
    translation = ca - scale[..., None] * np.einsum("...ij,...j->...i", rotation, cb)
    fit = np.einsum("...ij,...mj->...mi", rotation, b) * scale[..., None, None]
    r = a - fit - translation[..., None, :]
    residual = np.sqrt(np.einsum("...m,...mi,...mi->...", w, r, r))
    reflected = sign < 0
    if a.ndim == 2:  # one fit: plain numbers
        scale, residual, reflected = float(scale), float(residual), bool(reflected)
    return UmeyamaFit(rotation, translation, scale, residual, sv, reflected)
