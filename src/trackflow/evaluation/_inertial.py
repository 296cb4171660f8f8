"""IMU-aided prediction scored like the PoseTool: ``trackflow evaluate REC --imu IMU``.

The recording's poses are the truth; ``pose_rate_hz`` thins them to act as a slower tracker
(:class:`TrackerTrajectory`). Both predictors see the same thinned poses; ``kalman_imu``
(:class:`InertialPredictor`) also sees the IMU samples. Targets are the full-rate recording
interpolated ``h`` after the prediction's origin. Two definitions of the origin
(``docs/inertial.md``):

* ``"poses"``: right after each tracker pose (the PoseTool's definition; every predictor has
  just received a fresh pose);
* ``"anytime"``: at every full-rate sample time of the recording, with the poses and IMU
  samples up to then (an application asking at any moment, e.g. once per display frame,
  for the pose ``h`` later). The pose-only predictors extrapolate from their newest pose
  over ``h`` plus its age; the IMU filter from its newest IMU sample.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar, NamedTuple, TextIO

import numpy as np

from ..errors import InputError
from ..filters.inertial import (
    ImuExtrinsics,
    ImuNoise,
    InertialModel,
    estimate_gravity,
    estimate_imu_rotation,
    fit_gyro_extrapolation,
    imu_clock_offset,
    run_inertial,
    world_acceleration,
)
from ._baselines import LinearPredictor, NoPredictor
from ._evaluate import PredictionReport
from ._metrics import error_stats, pose_errors
from ._prediction import Prediction, positive_horizons, stack_predictions
from ._predictor import estimate_noise
from ._shrinkage import ShrunkPredictor, apply_shrinkage, change_factors, fit_shrinkage
from ._targets import scored_mask
from ._thinned import TrackerTrajectory, predict_from_last_pose
from ._trajectory import Trajectory
from ._tuning import LEARNED_ORDERS, tune_model

__all__ = [
    "IMU_PREDICTORS",
    "ORIGINS",
    "ImuSamples",
    "InertialPredictor",
    "evaluate_with_imu",
    "tune_inertial",
]

#: predictors scored by :func:`evaluate_with_imu`
IMU_PREDICTORS = ("kalman", "kalman_imu", "linear", "none")
#: where predictions start (module docstring)
ORIGINS = ("poses", "anytime")


class ImuSamples(NamedTuple):
    """IMU samples on the pose recording's clock.

    Attributes
    ----------
    t : ndarray (M,)
        Strictly increasing times [s], same origin as the recording's ``t``.
    gyro, accel : ndarray (M, 3)
        Angular velocity [rad/s] and specific force [m/s^2] in the sensor frame.
    """

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray

    @classmethod
    def check(cls, t, gyro, accel) -> ImuSamples:
        """Validate arrays into :class:`ImuSamples` (``ValueError`` naming the problem)."""
        ti = np.ascontiguousarray(t, dtype=float).reshape(-1)
        w = np.ascontiguousarray(gyro, dtype=float)
        a = np.ascontiguousarray(accel, dtype=float)
        if w.shape != (ti.shape[0], 3) or a.shape != (ti.shape[0], 3):
            raise InputError(f"IMU arrays disagree: t {ti.shape}, gyro {w.shape}, accel {a.shape}")
        if ti.shape[0] < 2 or not (np.all(np.isfinite(ti)) and np.all(np.diff(ti) > 0)):
            raise InputError("IMU times must be finite and strictly increasing (>= 2 samples)")
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(a))):
            raise InputError("IMU samples must be finite")
        return cls(ti, w, a)

    def shifted(self, offset_s: float) -> ImuSamples:
        """The same samples with ``offset_s`` [s] added to their times."""
        return ImuSamples(self.t + offset_s, self.gyro, self.accel)

    def until(self, t_end: float) -> ImuSamples:
        """The samples at or before ``t_end`` [s]."""
        n = int(np.searchsorted(self.t, t_end, side="right"))
        return ImuSamples(self.t[:n], self.gyro[:n], self.accel[:n])


@dataclass(frozen=True)
class InertialPredictor:
    """The IMU filter (:func:`~trackflow.filters.run_inertial`) as a
    :class:`~trackflow.evaluation.Predictor`: it predicts from the recording's poses and the
    IMU samples up to each origin.

    Attributes
    ----------
    model : InertialModel
    imu : ImuSamples
        On the recording's clock.
    pose_sigma : tuple of float
        Measurement sigma of the poses (position [m], rotation [rad]).
    """

    family: ClassVar[str] = "inertial"
    model: InertialModel
    imu: ImuSamples
    pose_sigma: tuple

    def covariance(self) -> np.ndarray:
        """6x6 pose measurement covariance over ``(dp, dtheta)``."""
        sp, so = self.pose_sigma
        return np.diag([sp**2] * 3 + [so**2] * 3)

    def predict(self, recording: Trajectory, horizons: np.ndarray) -> Prediction:
        """Predictions ``horizons`` after every pose (``nan`` before the filter starts)."""
        r = recording
        h = np.ascontiguousarray(horizons, dtype=float).reshape(-1)
        imu = self.imu.until(float(r.t[-1]))
        res = run_inertial(imu.t, imu.gyro, imu.accel, r.t, r.position, r.quaternion,
                           self.covariance(), self.model, h)  # fmt: skip
        return Prediction(*stack_predictions(res.predictions, h, len(r)))

    def predict_at(self, recording: Trajectory, query_t, horizons) -> Prediction:
        """Predictions ``horizons`` after each query time (Q,) from the poses and IMU samples
        up to it: arrays (H, Q, ...)."""
        r = recording
        tq = np.ascontiguousarray(query_t, dtype=float).reshape(-1)
        h = np.ascontiguousarray(horizons, dtype=float).reshape(-1)
        imu = self.imu.until(float(tq[-1]))
        res = run_inertial(imu.t, imu.gyro, imu.accel, r.t, r.position, r.quaternion,
                           self.covariance(), self.model, h, query_t=tq)  # fmt: skip
        return Prediction(*stack_predictions(res.predictions, h, tq.shape[0]))

    def as_dict(self) -> dict:
        return {"family": self.family, "pose_sigma": list(self.pose_sigma),
                **self.model.as_dict()}  # fmt: skip


def _cost(pred: Prediction, rec: TrackerTrajectory, horizons, rows=None) -> float:
    """Mean over horizons of position RMS [m] / 1 cm + orientation RMS [rad] / 1 degree."""
    out = 0.0
    for i, h in enumerate(horizons):
        m = rec.scored(h) & np.isfinite(pred.position[i][:, 0])
        if rows is not None:
            m &= rows
        if not np.any(m):
            return np.inf
        tp, tq = rec.target(h)
        e_p, e_q = pose_errors(pred.position[i][m], pred.quaternion[i][m], tp[m], tq[m])
        out += np.sqrt(np.mean(e_p**2)) / 0.01 + np.sqrt(np.mean(e_q**2)) / np.radians(1.0)
    return out / len(horizons)


def tune_inertial(
    data: TrackerTrajectory,
    imu: ImuSamples,
    base: InertialModel,
    pose_sigma: tuple,
    horizons,
    fit_horizons=(),
) -> InertialModel:
    """Tune the IMU filter's noise scale and prediction on tuning data.

    Coordinate descent on the prediction cost (:func:`_cost`) of :class:`InertialPredictor`:
    the white-noise densities (gyro, accelerometer) scaled by ``{0.3, 1, 3, 10, 30}`` each,
    the integration of the samples (``input_hold``), then the input trend (``smoothing_s`` in
    ``{0, 10, 20, 50, 100}`` ms, with and without slope) and the learned gyro and
    acceleration extrapolations (:func:`~trackflow.filters.inertial.fit_gyro_extrapolation`
    for ``horizons`` and ``fit_horizons``; 16 to 64 lags chosen on the last 30 % of the
    tuning data, fitted on the rest, then refitted on all), then the densities again on a
    finer grid around the best.

    Parameters
    ----------
    data : TrackerTrajectory
        The tuning poses (and their full-rate targets).
    imu : ImuSamples
        The IMU on the tuning part, on the recording's clock.
    base : InertialModel
        Extrinsics, gravity and starting noise.
    pose_sigma : tuple of float
        Pose measurement sigma (position [m], rotation [rad]).
    horizons, fit_horizons : sequence of float
        Horizons [s] of the cost, and further ones the learned extrapolations are fitted for.
    """
    h = positive_horizons(horizons)

    def run(m, rows=None):
        return _cost(InertialPredictor(m, imu, pose_sigma).predict(data, h), data, h, rows)

    best_c, best = np.inf, replace(base, smoothing_s=0.02)

    def consider(m):
        nonlocal best_c, best
        c = run(m)
        if c < best_c:
            best_c, best = c, m

    start = best
    for sg in (0.3, 1.0, 3.0, 10.0, 30.0):
        for sa in (0.3, 1.0, 3.0, 10.0, 30.0):
            consider(replace(start, noise=start.noise.scaled(sg, sa)))
    consider(replace(best, input_hold="preceding"))
    start = best
    for sm in (0.0, 0.01, 0.02, 0.05, 0.1):
        for slope in (False, True):
            consider(replace(start, smoothing_s=sm, use_slope=slope))
    # learned extrapolations: fitted on the first 70 % of the tuning IMU samples with the lag
    # count chosen on the rest (fitting and scoring on the same samples always favours more
    # lags), then refitted on all of them
    fit_h = sorted(set(h.tolist()) | {float(v) for v in fit_horizons})
    t_cut = float(imu.t[0] + 0.7 * (imu.t[-1] - imu.t[0]))
    late = data.t > t_cut

    def choose(field, signal_t, signal, integrals, extra):
        ref, pick = run(best, late), None
        for lags in (16, 32, 64):
            early = signal_t <= t_cut
            ex = fit_gyro_extrapolation(signal_t[early], signal[early], fit_h, lags,
                                        integrals=integrals)  # fmt: skip
            c = run(replace(best, **{field: ex}, **extra), late)
            if c < ref:
                ref, pick = c, lags
        if pick is not None:
            ex = fit_gyro_extrapolation(signal_t, signal, fit_h, pick, integrals=integrals)
            consider(replace(best, **{field: ex}, **extra))

    if np.count_nonzero(imu.t <= t_cut) > 2000:
        choose("gyro_extrapolation", imu.t, imu.gyro, 1, {})
        if best.mode == "strapdown":
            a_w, inside = world_acceleration(imu.t, imu.accel, data.t, data.quaternion,
                                             best.extrinsics.quaternion, best.gravity)  # fmt: skip
            choose("accel_extrapolation", imu.t[inside], a_w, 2, {"smoothing_s": 0.0})
    start = best
    for sg in (1 / 1.7, 1.0, 1.7):
        for sa in (1 / 1.7, 1.0, 1.7):
            consider(replace(start, noise=start.noise.scaled(sg, sa)))
    return best


def _calibrate(truth: Trajectory, imu: ImuSamples, mode, noise, clock_offset_s, extrinsics):
    """Clock offset, IMU rotation, gravity and pose sigma from the (tuning) recording."""
    t, q = truth.t, truth.quaternion
    if clock_offset_s is None:
        clock_offset_s = imu_clock_offset(imu.t, imu.gyro, t, q)
    imu = imu.shifted(float(clock_offset_s))
    if extrinsics is None:
        q_bs, _ = estimate_imu_rotation(imu.t, imu.gyro, t, q)
        extrinsics = ImuExtrinsics(q_bs)
    g = estimate_gravity(imu.t, imu.accel, t, q, extrinsics.quaternion)
    sigma = estimate_noise(t, truth.position, q)
    base = InertialModel(mode=mode, noise=noise or ImuNoise(), extrinsics=extrinsics, gravity=g)
    return float(clock_offset_s), imu, base, (float(sigma[0]), float(sigma[1]))


def evaluate_with_imu(
    recording: Trajectory,
    imu: ImuSamples,
    pose_rate_hz: float | None = None,
    horizons=(0.01, 0.02, 0.05, 0.1, 0.2),
    tune_fraction: float = 0.5,
    tune_horizons=(0.05, 0.1),
    origins: str = "poses",
    mode: str = "strapdown",
    noise: ImuNoise | None = None,
    clock_offset_s: float | None = None,
    extrinsics: ImuExtrinsics | None = None,
    ar_orders=LEARNED_ORDERS,
    progress: TextIO | None = None,
) -> PredictionReport:
    """Score prediction with and without the IMU on one recording (PoseTool, thesis 9.2.1).

    The first ``tune_fraction`` of the duration tunes: the pose-only filter on the thinned
    poses (:func:`tune_model`, learned models included, then :func:`fit_shrinkage`), and the
    IMU filter (clock offset, IMU rotation, gravity and pose sigma from the full-rate tuning
    part; :func:`tune_inertial`; its own shrinkage). The rest is scored with the targets of
    :class:`TrackerTrajectory`.

    Parameters
    ----------
    recording : Trajectory
        The pose recording ``T_w_b``: the truth and, thinned, the tracker.
    imu : ImuSamples
        The IMU on the body, times on the recording's clock (before the estimated offset).
    pose_rate_hz : float, optional
        Rate of the simulated tracker; default the recording's own.
    horizons, tune_horizons : sequence of float
        Scored and tuned horizons [s].
    tune_fraction : float in (0, 1)
    origins : {"poses", "anytime"}
        Where predictions start (module docstring).
    mode : {"strapdown", "gyro"}
        The IMU filter variant.
    noise : ImuNoise, optional
        Starting densities (data sheet); default :class:`ImuNoise`.
    clock_offset_s : float, optional
        Known IMU-to-tracker offset [s] (added to IMU times); default estimated by
        angular-speed correlation.
    extrinsics : ImuExtrinsics, optional
        Known ``T_b_s``; default the rotation estimated from data and no lever arm.
    ar_orders : sequence of int
        Learned model orders of the pose-only tuning.
    progress : text stream, optional

    Returns
    -------
    PredictionReport
        ``stats`` for ``kalman``, ``kalman_imu``, ``linear`` and ``none``; ``tuning`` holds the
        pose-only tuning, its ``shrinkage``, ``imu`` (clock offset, model, pose sigma,
        shrinkage), ``pose_rate_hz`` and ``origins``.
    """
    if origins not in ORIGINS:
        raise InputError(f"origins must be one of {ORIGINS}, got {origins!r}")
    if not 0.0 < tune_fraction < 1.0:
        raise InputError(f"tune_fraction must be in (0, 1), got {tune_fraction}")
    h = positive_horizons(horizons)
    th = positive_horizons(tune_horizons, "tune_horizons")
    truth = recording
    thin = TrackerTrajectory.thinned(truth, pose_rate_hz)
    if len(thin) < 40:
        raise InputError(f"only {len(thin)} poses at {pose_rate_hz} Hz; need at least 40")
    split = float(truth.t[0] + tune_fraction * (truth.t[-1] - truth.t[0]))
    train = thin.t <= split
    if np.count_nonzero(train) < 20 or np.count_nonzero(~train) < 20:
        raise InputError(f"tune_fraction {tune_fraction} leaves too few poses on one side")
    tuning_poses = thin.select(train)

    # the IMU: clock, mounting and gravity from the tuning part (first: it fails fast on an
    # IMU recording that does not belong to the poses)
    offset, imu, base, sigma = _calibrate(truth.select(truth.t <= split), imu, mode, noise,
                                          clock_offset_s, extrinsics)  # fmt: skip
    # pose only: the PoseTool's tuned filter on the thinned tracker, shrunk per horizon
    res = tune_model(tuning_poses, th, ar_orders=ar_orders, check_horizons=h,
                     progress=progress)  # fmt: skip
    kalman = fit_shrinkage(tuning_poses, res.predictor, h)
    # the IMU filter's noise and prediction
    model = tune_inertial(tuning_poses, imu.until(split), base, sigma, th, h)
    imu_pred = InertialPredictor(model, imu, sigma)

    score = _score_at_poses if origins == "poses" else _score_anytime
    stats, imu_shrinkage = score(thin, split, h, kalman, imu_pred)
    tuning = {**res.as_dict(), "shrinkage": kalman.shrinkage_dict()}
    tuning["imu"] = {"clock_offset_s": offset, "model": model.as_dict(),
                     "pose_sigma": list(sigma), "shrinkage": imu_shrinkage}  # fmt: skip
    tuning["pose_rate_hz"] = pose_rate_hz
    tuning["origins"] = origins
    return PredictionReport(
        scored_from_s=split,
        horizons_ms=tuple(int(round(v * 1e3)) for v in h),
        stats=stats,
        predictor=res.predictor,
        n_samples=len(thin),
        n_gaps=thin.n_gaps,
        gap_s=thin.gap_s,
        n_gated=0,
        tuning=tuning,
    )


def _stats(runs: dict, masks, targets, h) -> dict:
    """``{name: {h_ms: ErrorStats}}`` of predictions ``runs[name]`` (H, N, ...)."""
    stats: dict = {name: {} for name in IMU_PREDICTORS}
    for i, v in enumerate(h):
        m = masks[i] & np.isfinite(runs["kalman_imu"].position[i][:, 0])
        tp, tq = targets[i]
        for name in IMU_PREDICTORS:
            run = runs[name]
            e_p, e_q = pose_errors(run.position[i][m], run.quaternion[i][m], tp[m], tq[m])
            stats[name][int(round(v * 1e3))] = error_stats(e_p, e_q)
    return stats


def _score_at_poses(thin: TrackerTrajectory, split, h, kalman, imu_pred):
    """Origins at the tracker's poses; the IMU predictions shrunk towards the last pose."""
    imu_shrunk = fit_shrinkage(thin.select(thin.t <= split), imu_pred, h)
    runs = {"kalman": kalman.predict(thin, h), "kalman_imu": imu_shrunk.predict(thin, h),
            "linear": LinearPredictor().predict(thin, h),
            "none": NoPredictor().predict(thin, h)}  # fmt: skip
    masks = [thin.scored(v) & (thin.t > split) for v in h]
    return _stats(runs, masks, [thin.target(v) for v in h], h), imu_shrunk.shrinkage_dict()


def _score_anytime(thin: TrackerTrajectory, split, h, kalman, imu_pred):
    """Origins at every full-rate sample time: each predictor answers from the data it has.

    Pose-only predictors extrapolate from their newest pose ``k`` over ``h + (tau - t_k)``
    (predictions on a grid of horizons one full-rate step apart, interpolated); the IMU
    filter predicts from its newest IMU sample, shrunk towards its current estimate with
    factors fitted on the tuning part's origins.
    """
    truth = thin.truth
    tau = truth.t
    k = np.searchsorted(thin.t, tau, side="right") - 1  # newest pose at or before tau
    have = k >= 1
    k = np.clip(k, 0, len(thin) - 1)
    age = tau - thin.t[k]
    fresh = have & (age <= thin.gap_s) & (np.diff(thin.t, prepend=-np.inf)[k] <= thin.gap_s)
    masks = [scored_mask(tau, v, truth.gap_s) & fresh for v in h]
    targets = [truth.target(v) for v in h]
    step, age = truth.step, np.where(fresh, age, 0.0)  # unscored origins: no long grid
    runs = {name: predict_from_last_pose(pred, thin, k, age, h, step)
            for name, pred in (("kalman", kalman), ("linear", LinearPredictor()),
                               ("none", NoPredictor()))}  # fmt: skip
    # IMU: predictions and the current estimate at every origin, shrunk towards the estimate
    raw = imu_pred.predict_at(thin, tau, np.concatenate([[0.0], h]))
    now_p, now_q = raw.position[0], raw.quaternion[0]
    tune = [m & (tau <= split) for m in masks]
    lam = change_factors(now_p, now_q, raw.position[1:], raw.quaternion[1:],
                         [tg[0] for tg in targets], [tg[1] for tg in targets], tune)  # fmt: skip
    pp, pq = apply_shrinkage(now_p, now_q, raw.position[1:], raw.quaternion[1:], *lam)
    runs["kalman_imu"] = Prediction(pp, pq)
    masks = [m & (tau > split) for m in masks]
    shrink = ShrunkPredictor(imu_pred, tuple(h.tolist()), *lam).shrinkage_dict()
    return _stats(runs, masks, targets, h), {**shrink, "towards": "current estimate"}
