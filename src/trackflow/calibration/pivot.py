"""Tip (pivot) calibration of a pointer tool with uncertainty.

A tracked tool ``T_world_tool`` is rotated about its tip resting in a fixed divot:
``R_i p_tip + t_i = p_pivot`` for every sample. Linear least squares for the tip (tool frame)
and the pivot (world frame), robust to outliers, with the covariance from the residual level.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..io import PoseStream
from ..math import quat_rminus, quat_to_matrix
from ._geometry import rotation_axis_spread
from ._lsq import robust_solve

__all__ = ["PivotResult", "pivot_calibration"]

#: Smallest rotation range [deg] of a pivoting motion.
MIN_PIVOT_ANGLE_DEG = 10.0


@dataclass(frozen=True)
class PivotResult:
    """``tip`` (3,) in the tool frame and ``pivot`` (3,) in the world frame [m], their joint
    covariance (6, 6) ordered (tip, pivot), the RMS residual [mm] and the sample counts."""

    tip: np.ndarray
    pivot: np.ndarray
    covariance: np.ndarray
    residual_rms_mm: float
    n_used: int
    n_outliers: int
    residuals: np.ndarray | None = None  # (N, 3) metres, for plots
    inliers: np.ndarray | None = None

    def as_dict(self) -> dict:
        sig = np.sqrt(np.diag(self.covariance)) * 1e3
        return {
            "tip": [float(v) for v in self.tip],
            "pivot": [float(v) for v in self.pivot],
            "tip_sigma_mm": [float(v) for v in sig[:3]],
            "pivot_sigma_mm": [float(v) for v in sig[3:]],
            "covariance": [[float(v) for v in row] for row in self.covariance],
            "residual_rms_mm": self.residual_rms_mm,
            "n_used": self.n_used,
            "n_outliers": self.n_outliers,
        }


def pivot_calibration(stream: PoseStream) -> PivotResult:
    """Tip offset and pivot point from a pivoting recording of ``T_world_tool``.

    Raises ``ValueError`` when the tool rotates less than 10 degrees or about one axis only
    (the tip position along that axis is then unobservable).
    """
    q = np.asarray(stream.quaternion, float)
    p = np.asarray(stream.position, float)
    if len(q) < 10:
        raise InputError(f"pivot calibration needs at least 10 samples, got {len(q)}")
    rel = quat_rminus(q, q[0])
    angle = np.degrees(np.linalg.norm(rel, axis=1).max())
    if angle < MIN_PIVOT_ANGLE_DEG:
        raise InputError(
            f"too little rotation for pivot calibration: {angle:.1f} deg "
            f"(need {MIN_PIVOT_ANGLE_DEG:.0f}); tilt the tool about its tip"
        )
    if rotation_axis_spread(rel - rel.mean(axis=0)) < 0.05:
        raise InputError(
            "the tool rotated about one axis only: the tip position along it is "
            "unobservable; tilt in two directions"
        )
    R = quat_to_matrix(q)
    M = np.concatenate([R, np.broadcast_to(-np.eye(3), R.shape)], axis=2)  # (N, 3, 6)
    x0 = np.linalg.lstsq(M.reshape(-1, 6), -p.reshape(-1), rcond=None)[0]

    def fun(x):
        return np.einsum("nij,j->ni", M, x) + p, M

    sol = robust_solve(fun, x0, np.full(3, 1e-3), groups=((0, 1, 2),), correlated=True)
    r = sol.residuals[sol.inliers]
    return PivotResult(
        tip=sol.x[:3],
        pivot=sol.x[3:],
        covariance=sol.cov,
        residual_rms_mm=float(np.sqrt(np.mean(np.sum(r**2, axis=1))) * 1e3),
        n_used=int(sol.inliers.sum()),
        n_outliers=int((~sol.inliers).sum()),
        residuals=sol.residuals,
        inliers=sol.inliers,
    )
