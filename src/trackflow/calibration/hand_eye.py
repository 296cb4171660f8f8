"""Hand-eye ``A X = X B`` and robot-world-hand-eye ``A X = Z B`` calibration with covariance.

``A`` is a robot's (or any tracker's) pose ``T_base_tool``, ``B`` the other tracker's pose
``T_world_body`` of the rigidly attached body; ``X = T_tool_body`` and ``Z = T_base_world``, so
``T_base_tool(t) X = Z T_world_body(t - offset)``. A closed-form start (Park-Martin's axis fit,
the translation by linear least squares, ``Z`` by averaging) is refined by robust Gauss-Newton on
the manifold with analytic Jacobians, jointly with the clock offset when asked; outliers are
rejected by a chi-square test.

Three estimators (``form``): ``hand-eye`` solves ``A_ij X = X B_ij`` on short motion pairs, with
a covariance that accounts for the station errors the pairs share (:mod:`._pair_noise`);
``robot-world`` (the default for streams with different base frames) takes X and the clock
from those motion pairs, which a slowly drifting world frame does not bias, and then Z from the
absolute poses, with the covariance it inherits from X; ``robot-world-joint`` solves
``A X = Z B`` for X, Z and the clock jointly on absolute poses (most precise when the world
frame is static, biased when it drifts), its covariance inflated by the residual
autocorrelation.
Offset convention as in :mod:`trackflow.calibration.clock_offset`: ``t_a = t_b + offset``.

Every result also carries a residual that no world frame enters (``pair_residual_pos_mm``,
``pair_residual_ori_deg``): that of ``A_ij X = X B_ij`` on the motion pairs the hand-eye
estimator uses (:func:`pair_residual_rms`), so a calibration can be compared between sessions
whose sensor world differs.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import InputError, NumericalError
from ..io import PoseStream
from ..math import (
    Pose,
    UncertainPose,
    quat_conjugate,
    quat_exp,
    quat_log,
    quat_multiply,
    quat_rminus,
    quat_rotate,
    quat_to_matrix,
    skew,
    so3_right_jacobian_inverse,
    umeyama,
)
from ._geometry import matrix_quaternion, mean_rotation, rotation_axis_spread
from ._lsq import chi2_inliers, robust_solve
from ._noise_sandwich import Stream, fit_noise, sandwich_covariance
from ._pair_noise import pair_noise_jacobians, relative_pose_jacobians
from ._sampling import Trajectory, common_epoch_ns, trajectory, velocities
from .clock_offset import estimate_clock_offset

__all__ = [
    "HandEyeResult",
    "evaluate_hand_eye",
    "evaluate_with_world_fit",
    "hand_eye_residuals",
    "pair_residual_rms",
    "solve_hand_eye",
]

#: Smallest rotation between the two poses of a motion pair [deg].
MIN_PAIR_ANGLE_DEG = 5.0
#: Longest time between the two poses of a motion pair [s]: short pairs are insensitive to a
#: slowly drifting world frame (inside-out headsets), see docs/calibration.md.
MAX_PAIR_SPAN_S = 2.0
#: Smallest ratio of the second to the first singular value of the pairs' rotation axes.
MIN_AXIS_SPREAD = 0.05
#: The estimators of :func:`solve_hand_eye` (see its ``form``).
FORMS = ("robot-world", "robot-world-joint", "hand-eye")
#: Prior residual scales (position [m], rotation [rad]) and their groups for the solver.
_SIGMA0 = np.array([1e-3] * 3 + [np.radians(0.5)] * 3)
_GROUPS = ((0, 1, 2), (3, 4, 5))


@dataclass(frozen=True)
class HandEyeResult:
    """Result of :func:`solve_hand_eye`.

    Attributes
    ----------
    X : UncertainPose
        ``T_tool_body`` with its 6x6 covariance (conventions of ``docs/conventions.md``).
    Z : UncertainPose or None
        ``T_base_world`` for the robot-world form, else None.
    offset_s, offset_sigma_s : float
        Clock offset ``t_a = t_b + offset_s`` [s] and its standard error (0 when fixed); with
        drift, the offset at ``reference_time_s``.
    drift, drift_sigma : float or None
        Clock drift [s/s] (``t_a = t_b + offset + drift (t_a - reference)``) when estimated.
    reference_time_s : float
        a-clock time [s from the streams' common epoch] where the drift term is zero.
    covariance : ndarray, shape (P, P)
        Joint covariance over ``(X (6), Z (6) if present, offset (1) and drift (1) if
        estimated)``.
    form : str
        ``"robot-world"``, ``"robot-world-joint"`` or ``"hand-eye"``; ``"refit-world"`` for
        a stored X with Z and the clock refitted
        (:func:`~trackflow.calibration.refit_calibration`).
    residual_pos_mm, residual_ori_deg : float
        RMS position [mm] and rotation [deg] residual over the inliers of the form's own
        residual blocks (absolute poses ``A X = Z B`` or motion pairs).
    pair_residual_pos_mm, pair_residual_ori_deg : float or None
        World-independent residual [mm, deg]: RMS of ``A_ij X = X B_ij`` on the motion pairs
        of the hand-eye selection with the final X and clock, over the pairs that pass the
        solver's outlier test (:func:`pair_residual_rms`); None when no pair qualifies.
    n_pairs, n_pair_outliers : int
        Motion pairs in ``pair_residual_*`` and pairs rejected.
    n_used, n_outliers : int
        Residual blocks (samples or motion pairs) used and rejected.
    times_s, residuals, inliers : ndarray
        Residual blocks for plots: a-clock time (M,), residual (M, 6) ``(dp [m], dtheta
        [rad])`` and the inlier mask (M,).
    """

    X: UncertainPose
    Z: UncertainPose | None
    offset_s: float
    offset_sigma_s: float
    covariance: np.ndarray
    form: str
    residual_pos_mm: float
    residual_ori_deg: float
    n_used: int
    n_outliers: int
    times_s: np.ndarray
    residuals: np.ndarray
    inliers: np.ndarray
    drift: float | None = None
    drift_sigma: float | None = None
    reference_time_s: float = 0.0
    pair_residual_pos_mm: float | None = None
    pair_residual_ori_deg: float | None = None
    n_pairs: int = 0
    n_pair_outliers: int = 0

    @property
    def X_sigma_mm(self) -> float:
        """Root of the trace of X's position covariance, millimetres."""
        return float(np.sqrt(np.trace(self.X.covariance[:3, :3])) * 1e3)

    @property
    def X_sigma_deg(self) -> float:
        """Root of the trace of X's rotation covariance, degrees."""
        return float(np.degrees(np.sqrt(np.trace(self.X.covariance[3:, 3:]))))

    def to_json(self) -> dict:
        """The keys of ``trackflow calibrate hand-eye --json`` (see ``docs/calibration.md``)."""
        return {
            "X": pose_to_json(self.X),
            "Z": None if self.Z is None else pose_to_json(self.Z),
            "offset_s": self.offset_s,
            "offset_sigma_s": self.offset_sigma_s,
            "residual_pos_mm": self.residual_pos_mm,
            "residual_ori_deg": self.residual_ori_deg,
            "pair_residual_pos_mm": self.pair_residual_pos_mm,
            "pair_residual_ori_deg": self.pair_residual_ori_deg,
            "X_sigma_mm": self.X_sigma_mm,
            "X_sigma_deg": self.X_sigma_deg,
        }


def pose_to_json(p: UncertainPose) -> dict:
    """``{"position": [m], "quaternion": [x, y, z, w], "covariance": 6x6}``."""
    return {
        "position": [float(v) for v in p.position],
        "quaternion": [float(v) for v in p.quaternion],
        "covariance": [[float(v) for v in row] for row in p.covariance],
    }


def pose_from_json(d, what: str) -> UncertainPose:
    """Inverse of :func:`pose_to_json`; ``ValueError`` naming ``what`` on malformed input."""
    if not isinstance(d, dict) or "position" not in d or "quaternion" not in d:
        raise InputError(f"{what}: expected a mapping with 'position' and 'quaternion'")
    cov = np.asarray(d.get("covariance", np.zeros((6, 6))), float)
    if cov.shape != (6, 6):
        raise InputError(f"{what}: covariance must be 6x6, got shape {cov.shape}")
    return UncertainPose(Pose(d["position"], d["quaternion"], normalize=True), cov)


# ---------------------------------------------------------------------------------------------
# residuals and their Jacobians


def _compose(pa, qa, pb, qb):
    return pa + quat_rotate(qa, pb), quat_multiply(qa, qb)


def hand_eye_residuals(A_p, A_q, B_p, B_q, X, Z, B_v=None, B_w=None, jacobians=False):
    """Residuals of ``A X = Z B`` per sample and their Jacobians.

    Parameters
    ----------
    A_p, A_q, B_p, B_q : ndarray, shapes (M, 3), (M, 4)
        ``T_base_tool`` and ``T_world_body`` at the same instants.
    X, Z : tuple (p (3,), q (4,))
        ``T_tool_body`` and ``T_base_world``.
    B_v, B_w : ndarray, shape (M, 3), optional
        Velocity of B (world frame, m/s) and its body angular velocity (rad/s), for the
        derivative with respect to the clock offset.

    Returns
    -------
    r : ndarray, shape (M, 6)
        ``(t_P - t_Q, Log(R_Q^T R_P))`` with ``P = A X`` and ``Q = Z B`` (metres in the base
        frame, radians in the body frame).
    J_r_X, J_r_Z : ndarray, shape (M, 6, 6)
        With respect to X's and Z's errors ``(dt, dtheta)`` (conventions.md); when jacobians.
    J_r_offset : ndarray, shape (M, 6)
        With respect to the offset (needs ``B_v``, ``B_w``); when jacobians.
    """
    r, rR, qE = _difference(_compose(A_p, A_q, X[0], X[1]), _compose(Z[0], Z[1], B_p, B_q))
    if not jacobians:
        return r
    m = len(r)
    Jinv = so3_right_jacobian_inverse(rR)
    RA = quat_to_matrix(A_q)
    RZ = quat_to_matrix(Z[1])
    RB = quat_to_matrix(B_q)
    RE = quat_to_matrix(qE)
    J_X = np.zeros((m, 6, 6))
    J_X[:, :3, :3] = RA
    J_X[:, 3:, 3:] = Jinv
    J_Z = np.zeros((m, 6, 6))
    J_Z[:, :3, :3] = -np.eye(3)
    J_Z[:, :3, 3:] = RZ @ skew(B_p)
    EtBt = np.einsum("nji,nkj->nik", RE, RB)  # R_E^T R_B^T
    J_Z[:, 3:, 3:] = -np.einsum("nij,njk->nik", Jinv, EtBt)
    J_off = None
    if B_v is not None:
        J_off = np.zeros((m, 6))
        J_off[:, :3] = B_v @ RZ.T
        J_off[:, 3:] = np.einsum("nij,nkj,nk->ni", Jinv, RE, B_w)
    return r, J_X, J_Z, J_off


def _difference(P, Q):
    """``r = (t_P - t_Q, Log(q_Q^* q_P))`` (M, 6) of two pose batches ``(t, q)``, with the
    rotation part ``rR`` and the error quaternion ``qE = q_Q^* q_P``."""
    qE = quat_multiply(quat_conjugate(Q[1]), P[1])
    rR = quat_log(qE)
    return np.concatenate([P[0] - Q[0], rR], axis=1), rR, qE


def _relative(p, q, i, j):
    qi_inv = quat_conjugate(q[i])
    return quat_rotate(qi_inv, p[j] - p[i]), quat_multiply(qi_inv, q[j])


def pair_residuals(Ap, Aq, Bp, Bq, X, jacobians=False):
    """Residuals of ``A_ij X = X B_ij`` for relative motions (M, 3)/(M, 4); see above.

    Returns ``r`` (M, 6) with ``P = A_ij X`` and ``Q = X B_ij`` and, with jacobians,
    ``J_r_X`` (M, 6, 6).
    """
    r, rR, qE = _difference(_compose(Ap, Aq, X[0], X[1]), _compose(X[0], X[1], Bp, Bq))
    if not jacobians:
        return r
    m = len(r)
    Jinv = so3_right_jacobian_inverse(rR)
    RA, RX, RB, RE = (quat_to_matrix(v) for v in (Aq, X[1], Bq, qE))
    J = np.zeros((m, 6, 6))
    J[:, :3, :3] = RA - np.eye(3)
    J[:, :3, 3:] = RX @ skew(Bp)
    EtBt = np.einsum("nji,nkj->nik", RE, RB)
    J[:, 3:, 3:] = Jinv @ (np.eye(3) - EtBt)
    return r, J


def pair_station_jacobians(A_p, A_q, B_p, B_q, i, j, X):
    """Jacobians of the pair residuals of ``A_ij X = X B_ij`` with respect to the errors of
    the station poses (conventions: translation error in the source frame, rotation on the
    right).

    Parameters
    ----------
    A_p, A_q, B_p, B_q : ndarray, shapes (N, 3), (N, 4)
        ``T_base_tool`` and ``T_world_body`` at the stations.
    i, j : ndarray, shape (M,)
        Station indices of the pairs.
    X : tuple (p (3,), q (4,))

    Returns
    -------
    G_i, G_j : tuple of two ndarrays, shape (M, 6, 6)
        ``(J_r_Ai, J_r_Bi)`` and ``(J_r_Aj, J_r_Bj)``.
    """
    a_p, a_q = _relative(A_p, A_q, i, j)
    b_p, b_q = _relative(B_p, B_q, i, j)
    _, rR, qE = _difference(_compose(a_p, a_q, X[0], X[1]), _compose(X[0], X[1], b_p, b_q))
    J_r_a, J_r_b = pair_noise_jacobians(a_q, rR, qE, X)
    J_a_i, J_a_j = relative_pose_jacobians(A_q[i], a_p, a_q)
    J_b_i, J_b_j = relative_pose_jacobians(B_q[i], b_p, b_q)
    return (J_r_a @ J_a_i, J_r_b @ J_b_i), (J_r_a @ J_a_j, J_r_b @ J_b_j)


# ---------------------------------------------------------------------------------------------
# closed-form start


def _pairs(q: np.ndarray, min_angle: float, max_lag: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j), i < j <= i + max_lag, whose relative rotation exceeds ``min_angle``."""
    ii, jj = [], []
    n = len(q)
    for lag in range(1, max_lag + 1):
        i = np.arange(n - lag)
        ang = np.linalg.norm(quat_rminus(q[i + lag], q[i]), axis=1)
        ok = ang >= min_angle
        ii.append(i[ok])
        jj.append(i[ok] + lag)
    return np.concatenate(ii), np.concatenate(jj)


def closed_form_X(Ap, Aq, Bp, Bq, min_pair_angle_deg=10.0, max_lag: int = 20):
    """Park-Martin: ``R_X`` from the rotation axes of motion pairs, ``t_X`` by least squares.

    Inputs are poses at common instants, (M, 3)/(M, 4), spread over the recording (stations).
    Raises ``ValueError`` when the motion does not determine X.
    """
    i, j = _pairs(Aq, np.radians(min_pair_angle_deg), max_lag)
    if len(i) < 3:
        raise InputError(
            f"too little rotation for hand-eye: {len(i)} motion pairs rotate by at least "
            f"{min_pair_angle_deg} deg (need 3 or more)"
        )
    a_p, a_q = _relative(Ap, Aq, i, j)
    b_p, b_q = _relative(Bp, Bq, i, j)
    alpha, beta = quat_log(a_q), quat_log(b_q)
    spread = rotation_axis_spread(alpha)
    if spread < MIN_AXIS_SPREAD:
        raise NumericalError(
            "degenerate motion for hand-eye: the robot rotated about a single axis only "
            f"(axis spread {spread:.3f} < {MIN_AXIS_SPREAD}); X's translation along that axis "
            "is unobservable - rotate about at least two different axes"
        )
    RX = umeyama(alpha, beta, with_translation=False, allow_collinear=True).rotation
    qX = matrix_quaternion(RX)
    RA = quat_to_matrix(a_q)
    M = (RA - np.eye(3)).reshape(-1, 3)
    rhs = (b_p @ RX.T - a_p).reshape(-1)
    tX = np.linalg.lstsq(M, rhs, rcond=None)[0]
    return (tX, qX), (i, j)


def closed_form_Z(Ap, Aq, Bp, Bq, X):
    """``Z = mean(A_k X B_k^-1)``: rotation by the chordal mean, translation by the mean."""
    pP, qP = _compose(Ap, Aq, X[0], X[1])
    qBi = quat_conjugate(Bq)
    qZ = quat_multiply(qP, qBi)
    qZm = mean_rotation(qZ)
    pZ = pP - quat_rotate(qZm, Bp)
    return np.mean(pZ, axis=0), qZm


# ---------------------------------------------------------------------------------------------
# the estimator


def _manifold_step(n_poses: int):
    def update(x, dx):
        x = x.copy()
        for k in range(n_poses):
            o, d = 7 * k, 6 * k
            x[o : o + 3] += dx[d : d + 3]
            q = quat_multiply(x[o + 3 : o + 7], quat_exp(dx[d + 3 : d + 6]))
            x[o + 3 : o + 7] = q / np.linalg.norm(q)
        x[7 * n_poses :] += dx[6 * n_poses :]
        return x

    return update


def _grid(ta: Trajectory, tb: Trajectory, offset: float, margin: float) -> np.ndarray:
    """a-clock instants: the slower stream's samples inside the overlap, ``margin`` inside."""
    lo = max(ta.t[0], tb.t[0] + offset) + margin
    hi = min(ta.t[-1], tb.t[-1] + offset) - margin
    t = ta.t if ta.period_s >= tb.period_s else tb.t + offset
    t = t[(t >= lo) & (t <= hi)]
    if len(t) < 10:
        raise InputError(
            f"the streams overlap for {max(hi - lo, 0):.2f} s only (offset {offset:.3f} s): "
            "too few samples for hand-eye"
        )
    return t


def solve_hand_eye(
    robot: PoseStream,
    sensor: PoseStream,
    *,
    form: str = "auto",
    offset_s: float | None = None,
    estimate_offset: bool = True,
    estimate_drift: bool = False,
    max_offset_s: float = 1.0,
    min_pair_angle_deg: float = MIN_PAIR_ANGLE_DEG,
    max_pair_span_s: float = MAX_PAIR_SPAN_S,
    station_spacing_s: float = 0.25,
) -> HandEyeResult:
    """Calibrate ``X = T_tool_body`` (and ``Z = T_base_world``) with covariance.

    Parameters
    ----------
    robot : PoseStream
        ``T_base_tool`` (stream a).
    sensor : PoseStream
        ``T_world_body`` of the body rigidly attached to the tool (stream b).
    form : {"auto", "robot-world", "robot-world-joint", "hand-eye"}
        ``hand-eye``: ``A X = X B`` on motion pairs. ``robot-world``: X (and the clock) from
        motion pairs, then Z from the absolute poses (slow drift of the sensor's world frame
        within a run, as of inside-out headsets, does not bias X). ``robot-world-joint``:
        ``A X = Z B`` jointly on absolute poses (more precise for a static world frame).
        ``auto`` picks ``robot-world`` when the streams have different source (base) frames,
        else ``hand-eye``.
    offset_s : float, optional
        Known clock offset (``t_a = t_b + offset``); found by
        :func:`~trackflow.calibration.estimate_clock_offset` when None.
    estimate_offset : bool
        Refine the offset jointly with X (and Z).
    estimate_drift : bool
        Also estimate a linear clock drift (needs ``estimate_offset``).
    max_offset_s : float
        Search range of the coarse offset.
    min_pair_angle_deg, max_pair_span_s : float
        Motion-pair selection (hand-eye form): smallest relative rotation [deg] and longest
        time between the two poses of a pair [s].
    station_spacing_s : float
        Spacing of the poses used for the closed-form start and for hand-eye motion pairs.

    Returns
    -------
    HandEyeResult
        With ``pair_residual_*`` over the motion pairs of these stations (every form, the
        same pairs as the hand-eye and robot-world forms solve on; :func:`pair_residual_rms`).

    Raises
    ------
    ValueError
        Too little or single-axis rotation, too short an overlap, no motion for the offset.
    """
    if form == "auto":
        form = "robot-world" if robot.source != sensor.source else "hand-eye"
    if form not in FORMS:
        raise InputError(f"form must be 'auto' or one of {', '.join(FORMS)}; got {form!r}")
    if estimate_drift and not estimate_offset:
        raise InputError("estimate_drift needs estimate_offset")
    epoch = common_epoch_ns(robot, sensor)
    ta = trajectory(robot, epoch, f"robot {robot.source}->{robot.target}")
    tb = trajectory(sensor, epoch, f"sensor {sensor.source}->{sensor.target}")
    if offset_s is None:
        # The coarse search suffices as a start: the refinement below re-estimates the offset.
        refine = not estimate_offset
        offset_s = estimate_clock_offset(
            robot, sensor, max_offset_s=max_offset_s, refine=refine
        ).offset_s
    margin = 3 * max(ta.period_s, tb.period_s) + (0.05 if estimate_offset else 0.0)
    grid = _grid(ta, tb, offset_s, margin)
    A = ta.sample(grid)
    stations = np.unique(np.round((grid - grid[0]) / station_spacing_s), return_index=True)[1]
    B0 = tb.sample(grid[stations] - offset_s)
    As = (A.p[stations], A.q[stations])
    X0, _ = closed_form_X(*As, B0.p, B0.q, max_lag=int(round(10.0 / station_spacing_s)))
    clock = _Clock(offset_s, estimate_offset, estimate_drift, 0.5 * (grid[0] + grid[-1]))
    lag = max(1, int(round(max_pair_span_s / station_spacing_s)))
    if form == "robot-world-joint":
        Z0 = closed_form_Z(*As, B0.p, B0.q, X0)
        res = _refine_robot_world(A, tb, grid, X0, Z0, clock)
    else:
        sol, times = _refine_hand_eye(ta, tb, grid[stations], X0, clock, min_pair_angle_deg, lag)
        if form == "hand-eye":
            res = _result("hand-eye", sol, 1, clock, times, False)
        else:
            res = _world_after_pairs(A, tb, grid, sol, clock)
    return with_pair_residual(res, ta, tb, grid[stations], min_pair_angle_deg, lag)


@dataclass(frozen=True)
class _Clock:
    """The clock unknowns: offset (and drift about ``t_ref``, a-clock seconds)."""

    offset: float
    estimate: bool
    drift: bool
    t_ref: float

    @property
    def n(self) -> int:
        return int(self.estimate) + int(self.drift)

    def x0(self) -> list[float]:
        return ([self.offset] if self.estimate else []) + ([0.0] if self.drift else [])

    def b_times(self, t: np.ndarray, xc: np.ndarray) -> np.ndarray:
        """b-clock times of the a-clock instants ``t`` for clock unknowns ``xc``."""
        off = xc[0] if self.estimate else self.offset
        d = xc[1] if self.drift else 0.0
        return t - off - d * (t - self.t_ref)


def _result(form, sol, n_poses, clock: _Clock, times, has_z):
    x, cov = sol.x, sol.cov
    X = UncertainPose(Pose(x[:3], x[3:7], normalize=True), cov[:6, :6])
    Z = UncertainPose(Pose(x[7:10], x[10:14], normalize=True), cov[6:12, 6:12]) if has_z else None
    k, c = 7 * n_poses, 6 * n_poses
    off = float(x[k]) if clock.estimate else float(clock.offset)
    off_sigma = float(np.sqrt(cov[c, c])) if clock.estimate else 0.0
    drift = float(x[k + 1]) if clock.drift else None
    drift_sigma = float(np.sqrt(cov[c + 1, c + 1])) if clock.drift else None
    r = sol.residuals[sol.inliers]
    return HandEyeResult(
        X=X,
        Z=Z,
        offset_s=off,
        offset_sigma_s=off_sigma,
        covariance=cov,
        form=form,
        residual_pos_mm=float(np.sqrt(np.mean(np.sum(r[:, :3] ** 2, axis=1))) * 1e3),
        residual_ori_deg=float(np.degrees(np.sqrt(np.mean(np.sum(r[:, 3:] ** 2, axis=1))))),
        n_used=int(sol.inliers.sum()),
        n_outliers=int((~sol.inliers).sum()),
        times_s=times,
        residuals=sol.residuals,
        inliers=sol.inliers,
        drift=drift,
        drift_sigma=drift_sigma,
        reference_time_s=clock.t_ref,
    )


def _refine_robot_world(A, tb, grid, X0, Z0, clock: _Clock):
    def fun(x):
        X, Z = (x[:3], x[3:7]), (x[7:10], x[10:14])
        s = clock.b_times(grid, x[14:])
        B = tb.sample(s)
        v, w = velocities(tb, s, 2.0 * tb.period_s) if clock.estimate else (B.v, B.w)
        r, J_X, J_Z, J_off = hand_eye_residuals(A.p, A.q, B.p, B.q, X, Z, v, w, True)
        J = [J_X, J_Z] + ([J_off[:, :, None]] if clock.estimate else [])
        if clock.drift:  # ds/d(drift) = -(t - t_ref) = (t - t_ref) ds/d(offset)
            J.append(J_off[:, :, None] * (grid - clock.t_ref)[:, None, None])
        r = np.where((A.valid & B.valid)[:, None], r, np.nan)
        return r, np.concatenate(J, axis=2)

    x0 = np.concatenate([X0[0], X0[1], Z0[0], Z0[1], clock.x0()])
    sol = robust_solve(fun, x0, _SIGMA0, update=_manifold_step(2), groups=_GROUPS)
    return _result("robot-world-joint", sol, 2, clock, grid, True)


def _refine_hand_eye(ta, tb, stations, X0, clock: _Clock, min_pair_angle_deg, max_lag):
    A = ta.sample(stations)
    i, j = _pairs(A.q, np.radians(min_pair_angle_deg), max_lag)
    if len(i) < 3:
        raise InputError(
            f"too little rotation for hand-eye: {len(i)} motion pairs rotate by at least "
            f"{min_pair_angle_deg} deg within {max_lag} stations (need 3 or more)"
        )
    order = np.lexsort((j, i))
    i, j = i[order], j[order]
    a_p, a_q = _relative(A.p, A.q, i, j)

    def rel_b(xc):
        B = tb.sample(clock.b_times(stations, xc))
        bp, bq = _relative(B.p, B.q, i, j)
        return bp, bq, B.valid[i] & B.valid[j] & A.valid[i] & A.valid[j]

    def fun(x):
        X = (x[:3], x[3:7])
        xc = x[7:]
        bp, bq, ok = rel_b(xc)
        r, J = pair_residuals(a_p, a_q, bp, bq, X, True)
        cols = [J]
        # Clock columns by central differences of the interpolated motion over +-2 sample
        # intervals of b (the drift's step shifts the farthest station as much): the slope of
        # the expected motion, not of one noisy interpolation segment, whose noise would
        # inflate J^T J and make the offset's covariance overconfident.
        for c, h in enumerate(clock_steps[: clock.n]):
            d = np.zeros(clock.n)
            d[c] = h
            rp = pair_residuals(a_p, a_q, *rel_b(xc + d)[:2], X)
            rm = pair_residuals(a_p, a_q, *rel_b(xc - d)[:2], X)
            cols.append(((rp - rm) / (2 * h))[:, :, None])
        return np.where(ok[:, None], r, np.nan), np.concatenate(cols, axis=2)

    h_off = 2.0 * tb.period_s
    clock_steps = (h_off, h_off / max(float(np.max(np.abs(stations - clock.t_ref))), 1.0))
    x0 = np.concatenate([X0[0], X0[1], clock.x0()])
    sol = robust_solve(fun, x0, _SIGMA0, update=_manifold_step(1), groups=_GROUPS)
    # The pairs are not independent (a station serves up to 2 max_lag pairs): the covariance
    # is the sandwich over the station errors they share (see _pair_noise).
    k = sol.inliers
    B = tb.sample(clock.b_times(stations, sol.x[7:]))
    r, J = fun(sol.x)
    G_i, G_j = pair_station_jacobians(A.p, A.q, B.p, B.q, i[k], j[k], (sol.x[:3], sol.x[3:7]))
    index, position = np.stack([i[k], j[k]], axis=1), np.arange(len(stations), dtype=float)
    streams = [Stream(np.stack([G_i[s], G_j[s]], axis=1), index, position) for s in (0, 1)]
    noise = fit_noise(r[k], streams, _GROUPS, _GROUPS)
    cov = sandwich_covariance(J[k], sol.sigma**-2, streams, noise)
    return replace(sol, cov=cov, tau=1.0), stations[j]


def _fit_world(Ap, Aq, Bp, Bq, X):
    """``Z = T_base_world`` with X fixed from poses at common instants (M, 3)/(M, 4): the
    closed form, then robust Gauss-Newton on Z alone; the :class:`Solution`."""
    Z0 = closed_form_Z(Ap, Aq, Bp, Bq, X)

    def fun(x):
        r, _, J_Z, _ = hand_eye_residuals(Ap, Aq, Bp, Bq, X, (x[:3], x[3:7]), jacobians=True)
        return r, J_Z

    return robust_solve(fun, np.concatenate(Z0), _SIGMA0, update=_manifold_step(1), groups=_GROUPS)


def _world_after_pairs(A, tb, grid, pairs, clock: _Clock) -> HandEyeResult:
    """The robot-world form: X and the clock from motion pairs (``pairs``), then Z from the
    absolute poses at ``grid`` with them fixed.

    Z's covariance adds what it inherits from X and the clock, ``K S K^T`` with
    ``K = dZ/d(X, clock) = -(J_Z^T W J_Z)^-1 J_Z^T W J_(X, clock)``, to its own; the joint
    covariance over ``(X, Z, clock)`` holds the cross terms ``K S``.
    """
    X, xc = (pairs.x[:3], pairs.x[3:7]), pairs.x[7:]
    s = clock.b_times(grid, xc)
    B = tb.sample(s)
    ok = A.valid & B.valid
    Ap, Aq, Bp, Bq = A.p[ok], A.q[ok], B.p[ok], B.q[ok]
    sol = _fit_world(Ap, Aq, Bp, Bq, X)
    Z = (sol.x[:3], sol.x[3:7])
    v, w = velocities(tb, s[ok], 2.0 * tb.period_s)
    _, J_X, J_Z, J_off = hand_eye_residuals(Ap, Aq, Bp, Bq, X, Z, v, w, jacobians=True)
    cols = [J_X] + ([J_off[:, :, None]] if clock.estimate else [])
    if clock.drift:
        cols.append(J_off[:, :, None] * (grid[ok] - clock.t_ref)[:, None, None])
    J_t = np.concatenate(cols, axis=2)[sol.inliers]
    J_Zk = J_Z[sol.inliers]
    W = sol.sigma**-2
    H_Z = np.einsum("mbi,b,mbj->ij", J_Zk, W, J_Zk)
    K = -np.linalg.solve(H_Z, np.einsum("mbi,b,mbj->ij", J_Zk, W, J_t))
    S = pairs.cov
    n = 12 + clock.n
    th = np.r_[0:6, 12:n]
    cov = np.zeros((n, n))
    cov[np.ix_(th, th)] = S
    cov[6:12, th] = K @ S
    cov[th, 6:12] = (K @ S).T
    cov[6:12, 6:12] = K @ S @ K.T + sol.cov
    x = np.concatenate([pairs.x[:7], sol.x, xc])
    return _result("robot-world", replace(sol, x=x, cov=cov), 2, clock, grid[ok], True)


def station_times(grid: np.ndarray, spacing_s: float) -> np.ndarray:
    """The stations of the motion pairs: the first instant of ``grid`` (M,) [s] in every
    ``spacing_s`` [s] bin."""
    return grid[np.unique(np.round((grid - grid[0]) / spacing_s), return_index=True)[1]]


def pair_residual_rms(
    ta: Trajectory,
    tb: Trajectory,
    stations: np.ndarray,
    stations_b: np.ndarray,
    X,
    min_pair_angle_deg: float = MIN_PAIR_ANGLE_DEG,
    max_lag: int = int(round(MAX_PAIR_SPAN_S / 0.25)),
) -> tuple[float | None, float | None, int, int]:
    """World-independent residual of ``A_ij X = X B_ij`` on motion pairs.

    The pairs are those of the hand-eye estimator: stations ``i < j <= i + max_lag`` (by
    default 2 s at the 0.25 s spacing of :func:`solve_hand_eye`) whose robot rotation
    ``A_i^-1 A_j`` is at least ``min_pair_angle_deg``, both stations valid in both streams;
    ``A_ij = A_i^-1 A_j`` (robot, base frame cancels) and ``B_ij = B_i^-1 B_j`` (sensor, its
    world frame cancels), so neither world transform enters. Pairs failing the solver's outlier
    test (:func:`._lsq.chi2_inliers`: chi-square at 0.1 % after rescaling by the median, the
    position and rotation scales from the inliers) are left out, so a few pose jumps of the
    sensor do not decide the figure; the same rule for solves, ``--use`` and ``--refit``.

    Parameters
    ----------
    ta, tb : Trajectory
        Robot ``T_base_tool`` and sensor ``T_world_body``.
    stations, stations_b : ndarray, shape (N,)
        Station instants on the robot's clock and the same instants on the sensor's clock [s]
        (``stations - offset`` without drift).
    X : tuple (p (3,) [m], q (4,) (x, y, z, w))
        ``T_tool_body``.
    min_pair_angle_deg : float
        Smallest relative robot rotation of a pair [deg].
    max_lag : int
        Most stations between the two poses of a pair.

    Returns
    -------
    pos_mm, ori_deg : float or None
        RMS position [mm] (tool frame) and rotation [deg] residual over the inlier pairs; None
        without valid pairs.
    n, n_rejected : int
        Inlier pairs and rejected pairs.
    """
    r = _valid_pair_residuals(ta, tb, stations, stations_b, X, min_pair_angle_deg, max_lag)
    if len(r) == 0:
        return None, None, 0, 0
    k = residual_inliers(r)
    d = _rms(r[k])
    return d["residual_pos_mm"], d["residual_ori_deg"], int(k.sum()), int((~k).sum())


def residual_inliers(r: np.ndarray) -> np.ndarray:
    """The hand-eye solvers' outlier test applied to given residual blocks ``r`` (M, 6)
    ``(dp [m], dtheta [rad])``: the inlier mask (M,) (:func:`._lsq.chi2_inliers` with the
    solvers' prior scales and their position and rotation groups)."""
    return chi2_inliers(r, _SIGMA0, groups=_GROUPS)


def _valid_pair_residuals(ta, tb, stations, stations_b, X, min_pair_angle_deg, max_lag):
    """Residuals (M, 6) of :func:`pair_residual_rms`'s valid pairs."""
    A, B = ta.sample(stations), tb.sample(stations_b)
    i, j = _pairs(A.q, np.radians(min_pair_angle_deg), max_lag)
    ok = A.valid[i] & A.valid[j] & B.valid[i] & B.valid[j]
    i, j = i[ok], j[ok]
    return pair_residuals(*_relative(A.p, A.q, i, j), *_relative(B.p, B.q, i, j), X)


def with_pair_residual(
    res: HandEyeResult, ta: Trajectory, tb: Trajectory, stations, min_pair_angle_deg, max_lag
) -> HandEyeResult:
    """``res`` with ``pair_residual_*`` and ``n_pairs`` from :func:`pair_residual_rms` at
    ``stations`` (a-clock [s]) with its X and clock (offset and drift)."""
    d = res.drift or 0.0
    sb = stations - res.offset_s - d * (stations - res.reference_time_s)
    Xt = (np.asarray(res.X.position, float), np.asarray(res.X.quaternion, float))
    pos, ori, n, out = pair_residual_rms(ta, tb, stations, sb, Xt, min_pair_angle_deg, max_lag)
    return replace(
        res, pair_residual_pos_mm=pos, pair_residual_ori_deg=ori, n_pairs=n, n_pair_outliers=out
    )


def _rms(r: np.ndarray) -> dict:
    """RMS and median of the position [mm] and rotation [deg] norms of residuals (M, 6)."""
    dp = np.linalg.norm(r[:, :3], axis=1) * 1e3
    da = np.degrees(np.linalg.norm(r[:, 3:], axis=1))
    return {
        "residual_pos_mm": float(np.sqrt(np.mean(dp**2))),
        "residual_ori_deg": float(np.sqrt(np.mean(da**2))),
        "median_pos_mm": float(np.median(dp)),
        "median_ori_deg": float(np.median(da)),
        "n": len(r),
    }


def evaluate_hand_eye(
    robot: PoseStream,
    sensor: PoseStream,
    X: Pose,
    Z: Pose | None,
    offset_s: float,
    station_spacing_s: float = 0.25,
    min_pair_angle_deg: float = MIN_PAIR_ANGLE_DEG,
    max_pair_span_s: float = MAX_PAIR_SPAN_S,
) -> dict:
    """Residual of a stored calibration on other recordings; nothing is re-estimated.

    With ``Z`` the residual of ``A X = Z B`` at every sample of the slower stream, else that
    of ``A_ij X = X B_ij`` on motion pairs. Returns ``{"residual_pos_mm", "residual_ori_deg",
    "median_pos_mm", "median_ori_deg", "n"}`` (RMS [mm, deg] and median over all valid blocks,
    nothing rejected) and the world-independent ``"pair_residual_pos_mm"``,
    ``"pair_residual_ori_deg"`` and ``"n_pairs"`` (:func:`pair_residual_rms`: the motion pairs
    of the solver, RMS over those passing its outlier test; None without valid pairs).
    """
    epoch = common_epoch_ns(robot, sensor)
    ta, tb = trajectory(robot, epoch), trajectory(sensor, epoch)
    grid = _grid(ta, tb, offset_s, 3 * max(ta.period_s, tb.period_s))
    Xt = (np.asarray(X.position, float), np.asarray(X.quaternion, float))
    st = station_times(grid, station_spacing_s)
    lag = max(1, int(round(max_pair_span_s / station_spacing_s)))
    if Z is not None:
        A, B = ta.sample(grid), tb.sample(grid - offset_s)
        Zt = (np.asarray(Z.position, float), np.asarray(Z.quaternion, float))
        r = hand_eye_residuals(A.p, A.q, B.p, B.q, Xt, Zt)[A.valid & B.valid]
    else:
        r = _valid_pair_residuals(ta, tb, st, st - offset_s, Xt, min_pair_angle_deg, lag)
    if len(r) == 0:
        raise InputError("no valid residuals: the recordings do not overlap or do not rotate")
    pos, ori, n, _ = pair_residual_rms(ta, tb, st, st - offset_s, Xt, min_pair_angle_deg, lag)
    return _rms(r) | {"pair_residual_pos_mm": pos, "pair_residual_ori_deg": ori, "n_pairs": n}


def evaluate_with_world_fit(
    robot: PoseStream, sensor: PoseStream, X: Pose, offset_s: float
) -> dict:
    """Residual of ``A X = Z B`` with X and the offset fixed and only Z fitted to this run.

    For trackers whose world frame changes between runs (a headset re-establishes its origin
    each session) the stored Z does not carry over but X does; this fits Z alone (closed form,
    then Gauss-Newton on Z) and reports the residual like :func:`evaluate_hand_eye`, plus
    ``"Z"`` (position, quaternion).
    """
    epoch = common_epoch_ns(robot, sensor)
    ta, tb = trajectory(robot, epoch), trajectory(sensor, epoch)
    grid = _grid(ta, tb, offset_s, 3 * max(ta.period_s, tb.period_s))
    A, B = ta.sample(grid), tb.sample(grid - offset_s)
    ok = A.valid & B.valid
    Ap, Aq, Bp, Bq = A.p[ok], A.q[ok], B.p[ok], B.q[ok]
    Xt = (np.asarray(X.position, float), np.asarray(X.quaternion, float))
    sol = _fit_world(Ap, Aq, Bp, Bq, Xt)
    return _rms(sol.residuals) | {
        "Z": {"position": [float(v) for v in sol.x[:3]],
              "quaternion": [float(v) for v in sol.x[3:7]]},
    }  # fmt: skip
