"""Triangulation of marker images seen by several cameras, with a 3x3 covariance per point.

Linear (DLT on undistorted normalised coordinates) for the start, then Gauss-Newton on the
reprojection error in distorted pixels. With isotropic pixel noise ``sigma`` the covariance of
the refined point is the inverse Fisher information ``(sum_c J_c^T J_c / sigma_c^2)^-1`` with
``J_c = d uv_c / d X`` (:meth:`Camera.project`), the Cramer-Rao bound the estimate reaches to
first order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .camera import CameraRig

__all__ = ["Triangulation", "triangulate", "triangulate_linear"]


@dataclass
class Triangulation:
    """Triangulated points.

    Attributes
    ----------
    X : ndarray (N, 3)
        World points [m] (NaN where fewer than two views or a degenerate geometry).
    covariance : ndarray (N, 3, 3)
        Covariance of ``X`` [m^2] from the pixel noise.
    chi2 : ndarray (N,)
        Sum of squared reprojection residuals over sigma^2 (chi-square with ``2 n - 3`` dof).
    n_views : ndarray (N,) of int
    """

    X: np.ndarray
    covariance: np.ndarray
    chi2: np.ndarray
    n_views: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """(N,) points with at least two views and a finite estimate."""
        return (self.n_views >= 2) & np.all(np.isfinite(self.X), axis=1)


def _check(rig: CameraRig, uv, mask):
    uv = np.asarray(uv, dtype=float)
    C = len(rig)
    if uv.ndim != 3 or uv.shape[0] != C or uv.shape[2] != 2:
        raise InputError(f"pixels must have shape ({C}, N, 2) for {C} cameras, got {uv.shape}")
    if mask is None:
        mask = np.all(np.isfinite(uv), axis=2)
    else:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != uv.shape[:2]:
            raise InputError(f"mask must have shape {uv.shape[:2]}, got {mask.shape}")
        mask = mask & np.all(np.isfinite(uv), axis=2)
    return uv, mask


def triangulate_linear(rig: CameraRig, uv, mask=None) -> np.ndarray:
    """Linear (DLT) triangulation.

    Parameters
    ----------
    rig : CameraRig
    uv : array_like (C, N, 2)
        Pixel of point ``n`` in camera ``c`` (NaN where not seen).
    mask : array_like (C, N) of bool, optional
        Observations to use (default: the finite ones).

    Returns
    -------
    ndarray (N, 3)
        World points [m]; NaN where fewer than two views.
    """
    uv, mask = _check(rig, uv, mask)
    xn = np.stack(
        [
            cam.normalize(np.where(mask[c, :, None], uv[c], cam.K[:2, 2]))
            for c, cam in enumerate(rig)
        ]
    )
    return triangulate_normalized(rig, xn, mask)


def triangulate_normalized(rig: CameraRig, xn, mask) -> np.ndarray:
    """:func:`triangulate_linear` on undistorted normalised coordinates ``xn`` (C, N, 2)
    (``X_cam ~ (x, y, 1)``, :meth:`Camera.normalize`) with the observation mask (C, N)."""
    C, N = mask.shape
    A = np.zeros((N, 2 * C, 4))
    for c, cam in enumerate(rig):
        Rt = np.hstack([cam.R_cam_world, cam.t_cam_world[:, None]])
        m = mask[c][:, None] & np.all(np.isfinite(xn[c]), axis=1)[:, None]
        A[:, 2 * c] = np.where(m, xn[c, :, :1] * Rt[2] - Rt[0], 0.0)
        A[:, 2 * c + 1] = np.where(m, xn[c, :, 1:] * Rt[2] - Rt[1], 0.0)
    X = np.full((N, 3), np.nan)
    ok = mask.sum(axis=0) >= 2
    if ok.any():
        _, _, vt = np.linalg.svd(A[ok])
        h = vt[:, -1]
        with np.errstate(divide="ignore", invalid="ignore"):
            X[ok] = h[:, :3] / h[:, 3:]
    return X


def _sigma2(sigma_px, shape) -> np.ndarray:
    s = np.broadcast_to(np.asarray(sigma_px, dtype=float), shape)
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise InputError("sigma_px must be finite and > 0")
    return s * s


def refine_points(rig: CameraRig, X0, uv, mask, sigma_px, iterations: int = 3) -> Triangulation:
    """Gauss-Newton refinement of points on the pixel reprojection error.

    Parameters
    ----------
    X0 : array_like (N, 3)
        Start points [m] (e.g. from :func:`triangulate_linear`).
    uv : array_like (C, N, 2); mask : (C, N) bool
    sigma_px : float or array_like (C, N)
        Standard deviation of each pixel coordinate [px].
    """
    uv, mask = _check(rig, uv, mask)
    X = np.array(X0, dtype=float)
    w = np.where(mask, 1.0 / _sigma2(sigma_px, mask.shape), 0.0)  # (C, N)
    n_views = mask.sum(axis=0)
    good = np.all(np.isfinite(X), axis=1) & (n_views >= 2)
    H = np.zeros((len(X), 3, 3))
    r = np.zeros(uv.shape)
    for it in range(iterations + 1):
        proj, J = rig.project(X, jacobian=True)  # (C, N, 2), (C, N, 2, 3)
        r = np.where(mask[..., None], uv - proj, 0.0)
        finite = np.all(np.isfinite(r), axis=(0, 2)) & np.all(np.isfinite(J), axis=(0, 2, 3))
        good &= finite | ~mask.any(axis=0)
        r = np.where(np.isfinite(r), r, 0.0)
        J = np.where(np.isfinite(J) & mask[..., None, None], J, 0.0)
        Jw = J * w[..., None, None]
        H = np.einsum("cnki,cnkj->nij", Jw, J)
        if it == iterations:
            break
        g = np.einsum("cnki,cnk->ni", Jw, r)
        Hs = np.where(good[:, None, None], H, np.eye(3))
        dx = np.linalg.solve(Hs, np.where(good[:, None], g, 0.0)[..., None])[..., 0]
        X = X + dx
    chi2 = np.einsum("cnk,cn->n", r * r, w)
    cov = np.full((len(X), 3, 3), np.nan)
    if good.any():
        cov[good] = np.linalg.inv(H[good])
    X[~good] = np.nan
    chi2[~good] = np.nan
    return Triangulation(X, cov, chi2, n_views)


def triangulate(rig: CameraRig, uv, mask=None, sigma_px=0.1, iterations: int = 3) -> Triangulation:
    """Linear triangulation refined by Gauss-Newton, with covariances.

    Parameters
    ----------
    rig : CameraRig
    uv : array_like (C, N, 2)
        Pixel of point ``n`` in camera ``c`` (NaN where not seen) [px].
    mask : array_like (C, N) of bool, optional
    sigma_px : float or array_like (C, N)
        Pixel noise (one sigma per coordinate) [px].

    Returns
    -------
    Triangulation
    """
    uv, mask = _check(rig, uv, mask)
    X0 = triangulate_linear(rig, uv, mask)
    return refine_points(rig, X0, uv, mask, sigma_px, iterations)
