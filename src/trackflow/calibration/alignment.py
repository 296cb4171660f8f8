"""Alignment of two trajectories of the same point (absolute orientation) with covariance.

``p_a(t) = s R p_b(t - offset) + t``: ``T_a_b = (t, R)`` maps trajectory b's world frame into
a's (as ``evo --align`` / Umeyama do), optionally with a scale ``s`` and jointly with the clock
offset (``t_a = t_b + offset``). A closed-form Umeyama start is refined by robust Gauss-Newton
with analytic Jacobians; the covariance follows the conventions (translation error in frame a,
rotation error on the right) and is inflated by the residual autocorrelation.

With a lever arm the tracked point sits at a known offset ``l`` in a's body frame
(``p_a = t_a + R_a l``, e.g. a hand-eye ``X`` held fixed while only the world is refitted); its
covariance is carried into the result's to first order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..io import PoseStream
from ..math import (
    Pose,
    UmeyamaFit,
    UncertainPose,
    quat_exp,
    quat_multiply,
    quat_rotate,
    quat_to_matrix,
    skew,
    umeyama,
)
from ._geometry import matrix_quaternion
from ._lsq import robust_solve
from ._sampling import common_epoch_ns, trajectory, velocities
from .clock_offset import estimate_clock_offset

__all__ = ["AlignmentResult", "align_trajectories", "fit_alignment"]


@dataclass(frozen=True)
class AlignmentResult:
    """``T_a_b`` with covariance, scale (1 unless estimated), offset and residuals.

    ``residual_rmse_mm`` is the RMS position error after alignment over the inliers (evo's
    APE RMSE); ``times_s`` (M,), ``residuals`` (M, 3) [m] and ``inliers`` (M,) for plots.

    ``covariance`` (P, P) is the joint covariance over the tangent step ``(dt (3) [m] in frame
    a, dtheta (3) [rad] on the right, dlog(s) if the scale is estimated, doffset [s] if the
    offset is estimated)``; ``T.covariance`` is its top-left 6x6 block. With a lever arm it
    includes the lever arm's covariance, and ``lever_arm_gain`` (P, 3) is the first-order
    sensitivity of those parameters to the lever arm (``d params / d l``, l in a's body frame
    [m]), so ``lever_arm_gain @ C_l`` is their cross-covariance with it; None without one.
    """

    T: UncertainPose
    scale: float
    scale_sigma: float
    offset_s: float
    offset_sigma_s: float
    residual_rmse_mm: float
    n_used: int
    n_outliers: int
    times_s: np.ndarray
    residuals: np.ndarray
    inliers: np.ndarray
    covariance: np.ndarray | None = None
    lever_arm_gain: np.ndarray | None = None

    def as_dict(self) -> dict:
        return {
            "position": [float(v) for v in self.T.position],
            "quaternion": [float(v) for v in self.T.quaternion],
            "covariance": [[float(v) for v in row] for row in self.T.covariance],
            "scale": self.scale,
            "scale_sigma": self.scale_sigma,
            "offset_s": self.offset_s,
            "offset_sigma_s": self.offset_sigma_s,
            "residual_rmse_mm": self.residual_rmse_mm,
            "n_used": self.n_used,
            "n_outliers": self.n_outliers,
        }


def fit_alignment(pa: np.ndarray, pb: np.ndarray, with_scale: bool = False) -> UmeyamaFit:
    """Closed-form ``T_a_b`` (and scale) with ``pa ~ s R_a_b pb + t_a_b`` for (M, 3) positions.

    :func:`trackflow.math.umeyama` with the refusals of trajectory alignment: positions (nearly)
    on a line (second spread below 1 % of the first), and trajectories of opposite handedness
    (only a reflection fits, e.g. one in Unity's left-handed frame).

    Raises
    ------
    ValueError
        Collinear positions or opposite handedness.
    """
    pb = np.asarray(pb, dtype=float)
    sv = np.linalg.svd(pb - pb.mean(axis=0), compute_uv=False)
    if sv[1] < 0.01 * sv[0]:
        raise InputError(
            "degenerate trajectory for alignment: the positions lie on a line (spread "
            f"{sv[1] / max(sv[0], 1e-300):.4f} of the main direction); rotation about it is "
            "unobservable"
        )
    fit = umeyama(pa, pb, with_scale=with_scale)
    d = fit.singular_values
    if fit.reflected and d[2] > 0.2 * d[1]:
        raise InputError(
            "the trajectories have opposite handedness: only a reflection aligns them (is "
            "one in a left-handed frame such as Unity's? mirror it first, docs/formats.md)"
        )
    return fit


def align_trajectories(
    a: PoseStream,
    b: PoseStream,
    *,
    with_scale: bool = False,
    offset_s: float | None = None,
    estimate_offset: bool = True,
    max_offset_s: float = 1.0,
    lever_arm: np.ndarray | None = None,
    lever_arm_covariance: np.ndarray | None = None,
) -> AlignmentResult:
    """Align trajectory ``b`` to ``a`` (positions of the same point) with covariance.

    Parameters
    ----------
    a, b : PoseStream
        Reference and aligned trajectory (only positions are used for the fit; orientations
        help find the offset).
    with_scale : bool
        Estimate a scale too (monocular SLAM, unknown units).
    offset_s : float, optional
        Known clock offset ``t_a = t_b + offset``; else found from the speed profiles
        (:func:`~trackflow.calibration.estimate_clock_offset`, coarse search).
    estimate_offset : bool
        Refine the offset jointly with the alignment.
    max_offset_s : float
        Search range of the coarse offset [s].
    lever_arm : ndarray, shape (3,), optional
        Position [m] in a's body frame (``a.target``) of the point whose trajectory b tracks,
        held fixed: a's positions become ``t_a + R_a lever_arm`` (for a hand-eye ``X =
        T_tool_body`` held fixed, its translation; b's origin is then the point). Default: a's
        origin.
    lever_arm_covariance : ndarray, shape (3, 3), optional
        Covariance [m^2] of ``lever_arm`` in a's body frame (the position block of ``X``'s
        covariance); added to the result's covariance to first order,
        ``K C_l K^T`` with ``K = -(J^T W J)^-1 J^T W R_a`` over the inliers (``lever_arm_gain``).

    Raises
    ------
    ValueError
        No overlap, no motion, collinear positions, opposite handedness, a lever arm or its
        covariance of the wrong shape.
    """
    epoch = common_epoch_ns(a, b)
    ta, tb = trajectory(a, epoch, "a"), trajectory(b, epoch, "b")
    if offset_s is None:
        offset_s = estimate_clock_offset(a, b, max_offset_s=max_offset_s, refine=False).offset_s
    margin = 3 * max(ta.period_s, tb.period_s) + (0.05 if estimate_offset else 0.0)
    lo = max(ta.t[0], tb.t[0] + offset_s) + margin
    hi = min(ta.t[-1], tb.t[-1] + offset_s) - margin
    t = ta.t if ta.period_s >= tb.period_s else tb.t + offset_s
    grid = t[(t >= lo) & (t <= hi)]
    if len(grid) < 10:
        raise InputError(f"the trajectories overlap for {max(hi - lo, 0):.2f} s only")
    A = ta.sample(grid)
    lever, C_lever = _lever_arm(lever_arm, lever_arm_covariance)
    pa = A.p if lever is None else A.p + quat_rotate(A.q, lever)
    B0 = tb.sample(grid - offset_s)
    ok = A.valid & B0.valid
    start = fit_alignment(pa[ok], B0.p[ok], with_scale)
    s0, R0, t0 = start.scale, start.rotation, start.translation

    def fun(x):
        R = quat_to_matrix(x[3:7])
        k = 7
        s = np.exp(x[k]) if with_scale else 1.0
        k += int(with_scale)
        off = x[k] if estimate_offset else offset_s
        B = tb.sample(grid - off)
        Rp = B.p @ R.T
        r = pa - (s * Rp + x[:3])
        J = [np.broadcast_to(-np.eye(3), (len(r), 3, 3)), s * R @ skew(B.p)]
        if with_scale:
            J.append(-s * Rp[:, :, None])
        if estimate_offset:
            v, _ = velocities(tb, grid - off, 2.0 * tb.period_s)
            J.append(s * (v @ R.T)[:, :, None])
        r = np.where((A.valid & B.valid)[:, None], r, np.nan)
        return r, np.concatenate(J, axis=2)

    def update(x, dx):
        x = x.copy()
        x[:3] += dx[:3]
        q = quat_multiply(x[3:7], quat_exp(dx[3:6]))
        x[3:7] = q / np.linalg.norm(q)
        x[7:] += dx[6:]
        return x

    x0 = np.concatenate(
        [t0, matrix_quaternion(R0)]
        + ([[np.log(s0)]] if with_scale else [])
        + ([[offset_s]] if estimate_offset else [])
    )
    sol = robust_solve(fun, x0, np.full(3, 1e-3), update=update, groups=((0, 1, 2),))
    cov, gain = sol.cov, None
    if lever is not None:
        # The fit's sensitivity to the lever arm, d r / d l = R_a (one isotropic residual
        # scale, so the weights cancel): K = -(J^T J)^-1 J^T R_a over the inliers.
        _, J = fun(sol.x)
        Jk, Rk = J[sol.inliers], quat_to_matrix(A.q[sol.inliers])
        H = np.einsum("mbi,mbj->ij", Jk, Jk)
        gain = -np.linalg.solve(H, np.einsum("mbi,mbj->ij", Jk, Rk))
        cov = cov + gain @ C_lever @ gain.T
    k = 6
    scale, scale_sigma = 1.0, 0.0
    if with_scale:
        scale = float(np.exp(sol.x[7]))
        scale_sigma = float(scale * np.sqrt(cov[k, k]))
        k += 1
    off, off_sigma = (float(sol.x[-1]), float(np.sqrt(cov[k, k]))) if estimate_offset else (
        float(offset_s), 0.0)  # fmt: skip
    r = sol.residuals[sol.inliers]
    return AlignmentResult(
        T=UncertainPose(Pose(sol.x[:3], sol.x[3:7], normalize=True), cov[:6, :6]),
        scale=scale,
        scale_sigma=scale_sigma,
        offset_s=off,
        offset_sigma_s=off_sigma,
        residual_rmse_mm=float(np.sqrt(np.mean(np.sum(r**2, axis=1))) * 1e3),
        n_used=int(sol.inliers.sum()),
        n_outliers=int((~sol.inliers).sum()),
        times_s=grid,
        residuals=sol.residuals,
        inliers=sol.inliers,
        covariance=cov,
        lever_arm_gain=gain,
    )


def _lever_arm(lever_arm, covariance) -> tuple[np.ndarray | None, np.ndarray]:
    """The lever arm (3,) [m] or None, and its covariance (3, 3) [m^2] (zeros if not given)."""
    if lever_arm is None:
        if covariance is not None:
            raise InputError("lever_arm_covariance needs a lever_arm")
        return None, np.zeros((3, 3))
    lever = np.asarray(lever_arm, dtype=float)
    C = np.zeros((3, 3)) if covariance is None else np.asarray(covariance, dtype=float)
    if lever.shape != (3,) or C.shape != (3, 3):
        raise InputError(
            f"lever arm must have shape (3,) and its covariance (3, 3); got {lever.shape} "
            f"and {C.shape}"
        )
    if not (np.all(np.isfinite(lever)) and np.all(np.isfinite(C))):
        raise InputError("lever arm and its covariance must be finite")
    return lever, C
