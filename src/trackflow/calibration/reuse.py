"""Reuse a hand-eye calibration in a new session: keep X, refit the world and the clock.

A tracker that re-establishes its world frame at every start (an inside-out headset) and a
clock that is re-synchronised per session make a stored ``Z = T_base_world`` and offset wrong
for the next session, while ``X = T_tool_body`` (the rigid mount) still holds. Refitting the
world with X held fixed is a trajectory alignment of the body's origin as the robot carries it,
``t_A + R_A t_X``, to the sensor's positions (:func:`~.alignment.align_trajectories` with a
lever arm, jointly with the offset found by :func:`~.clock_offset.estimate_clock_offset`); X's
covariance is carried into Z's. Conventions: ``docs/conventions.md``; method and figures:
``docs/calibration.md`` ("Reusing a calibration in another session").
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..io import PoseStream
from ..math import Pose, UncertainPose
from ._sampling import common_epoch_ns, trajectory
from .alignment import align_trajectories
from .hand_eye import (
    MAX_PAIR_SPAN_S,
    MIN_PAIR_ANGLE_DEG,
    HandEyeResult,
    hand_eye_residuals,
    residual_inliers,
    station_times,
    with_pair_residual,
)

__all__ = ["REFIT_CHOICES", "check_refit", "refit_calibration"]

#: What :func:`refit_calibration` can re-estimate (the rest of the calibration is kept).
REFIT_CHOICES = ("world",)


def check_refit(refit: str) -> str:
    """``refit`` if it is one of :data:`REFIT_CHOICES`, else an ``InputError`` listing them."""
    if refit not in REFIT_CHOICES:
        raise InputError(
            f"cannot refit {refit!r}: allowed: {', '.join(repr(c) for c in REFIT_CHOICES)} "
            "('world' refits the world transform Z and the clock offset, X is kept from the "
            "calibration)"
        )
    return refit


def refit_calibration(
    robot: PoseStream,
    sensor: PoseStream,
    X: UncertainPose,
    *,
    refit: str = "world",
    offset_s: float | None = None,
    estimate_offset: bool = True,
    max_offset_s: float = 1.0,
    station_spacing_s: float = 0.25,
    min_pair_angle_deg: float = MIN_PAIR_ANGLE_DEG,
    max_pair_span_s: float = MAX_PAIR_SPAN_S,
) -> HandEyeResult:
    """Keep a stored ``X = T_tool_body`` and refit ``Z = T_base_world`` and the clock offset.

    Z and the offset come from :func:`~trackflow.calibration.align_trajectories` of the body
    origin's robot-side trajectory ``p_A(t) = t_A + R_A t_X`` (base frame) to the sensor's
    positions ``p_B`` (world frame), ``p_A(t) = t_Z + R_Z p_B(t - offset)``, with ``t_X`` as the
    lever arm: a robust Gauss-Newton fit started from Umeyama's closed form and from the coarse
    offset of :func:`~trackflow.calibration.estimate_clock_offset`. X's rotation does not enter
    the fit; its translation's covariance is propagated into Z's and the offset's.

    Parameters
    ----------
    robot : PoseStream
        ``T_base_tool`` of the new session (stream a).
    sensor : PoseStream
        ``T_world_body`` of the new session (stream b), the body rigidly mounted on the tool.
    X : UncertainPose
        ``T_tool_body`` with its 6x6 covariance ``(dt [m] in the tool frame, dtheta [rad] on
        the right)``, e.g. ``X`` of a stored ``calibrate hand-eye --json``.
    refit : str
        What to re-estimate: ``"world"`` (Z and the offset), the only value
        (:data:`REFIT_CHOICES`).
    offset_s : float, optional
        Known or starting clock offset ``t_a = t_b + offset`` [s]; found from the speed
        profiles when None (a stored offset is not used: each session re-synchronises).
    estimate_offset : bool
        Refine the offset jointly with Z (else keep ``offset_s``, which must then be given).
    max_offset_s : float
        Search range of the coarse offset [s].
    station_spacing_s, min_pair_angle_deg, max_pair_span_s : float
        Motion pairs of the world-independent ``pair_residual_*`` (as in
        :func:`~trackflow.calibration.solve_hand_eye`): stations every ``station_spacing_s``
        [s], pairs of at most ``max_pair_span_s`` [s] rotating at least ``min_pair_angle_deg``.

    Returns
    -------
    HandEyeResult
        ``form == "refit-world"``; ``X`` as given; ``Z`` with its covariance (the fit's plus
        what X's translation covariance induces); ``covariance`` over ``(X (6), Z (6), offset
        (1) if estimated)`` with the cross terms between X and Z; ``residual_*`` the RMS of
        ``A X = Z B`` at the alignment's samples (position [mm], rotation [deg]) over the
        blocks that pass the solvers' outlier test (``n_used``, ``n_outliers``, ``inliers``);
        ``pair_residual_*`` the motion-pair residual with X and the refitted offset.

    Raises
    ------
    ValueError
        An unknown ``refit`` (the message lists the allowed ones), ``estimate_offset=False``
        without ``offset_s``, no overlap or no motion, positions on a line, opposite handedness.
    """
    check_refit(refit)
    if not estimate_offset and offset_s is None:
        raise InputError("a fixed offset (estimate_offset=False) needs offset_s")
    C_X = np.asarray(X.covariance, float)
    al = align_trajectories(
        robot, sensor, offset_s=offset_s, estimate_offset=estimate_offset,
        max_offset_s=max_offset_s, lever_arm=X.position, lever_arm_covariance=C_X[:3, :3],
    )  # fmt: skip
    epoch = common_epoch_ns(robot, sensor)
    ta, tb = trajectory(robot, epoch, "robot"), trajectory(sensor, epoch, "sensor")
    grid = al.times_s
    A, B = ta.sample(grid), tb.sample(grid - al.offset_s)
    Xt = (np.asarray(X.position, float), np.asarray(X.quaternion, float))
    Zt = (np.asarray(al.T.position, float), np.asarray(al.T.quaternion, float))
    r = hand_eye_residuals(A.p, A.q, B.p, B.q, Xt, Zt)
    r = np.where((A.valid & B.valid)[:, None], r, np.nan)
    # The solver's outlier test on the 6-D residual (the alignment tests positions only), so
    # that residual_* is the measure a solve reports
    k = residual_inliers(r)
    n = 12 + int(estimate_offset)
    cov = np.zeros((n, n))
    cov[:6, :6] = C_X
    cov[6:, 6:] = al.covariance
    cross = al.lever_arm_gain @ C_X[:3, :]  # Cov((Z, offset), X): only t_X enters the fit
    cov[6:, :6] = cross
    cov[:6, 6:] = cross.T
    res = HandEyeResult(
        X=UncertainPose(Pose(Xt[0], Xt[1], normalize=True), C_X),
        Z=UncertainPose(Pose(Zt[0], Zt[1], normalize=True), al.covariance[:6, :6]),
        offset_s=al.offset_s,
        offset_sigma_s=al.offset_sigma_s,
        covariance=cov,
        form="refit-world",
        residual_pos_mm=float(np.sqrt(np.mean(np.sum(r[k, :3] ** 2, axis=1))) * 1e3),
        residual_ori_deg=float(np.degrees(np.sqrt(np.mean(np.sum(r[k, 3:] ** 2, axis=1))))),
        n_used=int(k.sum()),
        n_outliers=int((~k).sum()),
        times_s=grid,
        residuals=r,
        inliers=k,
        reference_time_s=float(0.5 * (grid[0] + grid[-1])),
    )
    lag = max(1, int(round(max_pair_span_s / station_spacing_s)))
    st = station_times(grid, station_spacing_s)
    return with_pair_residual(res, ta, tb, st, min_pair_angle_deg, lag)
