"""Whole-sequence filtering for offline work (evaluation, parameter tuning)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from trackflow.math import Pose, UncertainPose, frozen

from ...errors import ExtrapolationError, InputError
from ..contract import FilterStatus
from .model import MotionModel
from .streaming import PoseKalmanFilter, kernels

__all__ = ["FilterResult", "run_filter", "smooth_filter"]


@dataclass(frozen=True)
class FilterResult:
    """Output of :func:`run_filter`, row ``i`` belonging to input row ``i``.

    Attributes
    ----------
    times : ndarray (N,)
        Measurement times (s), as given.
    filtered : UncertainPose (N,) or Pose (N,)
        Posterior pose at each measurement time (6x6 covariance over ``(dt, dtheta)``,
        ``t_true = t + dt``, ``R_true = R Exp(dtheta)``); a plain ``Pose`` (the means) when
        :func:`run_filter` was asked for ``covariance=False``.
    horizons : tuple of float
    predictions : dict float -> UncertainPose (N,) or Pose (N,)
        ``predictions[h][i]``: the pose predicted for ``times[i] + h`` from the state after
        measurement ``i`` (for prediction-error evaluation, thesis tables 9.2-9.5); ``Pose``
        with ``covariance=False``.
    nis : ndarray (N,)
        Normalised innovation squared per measurement (NaN where none was formed).
    status : ndarray (N,) of int8
        0 accepted, 1 gated, 2 diverged (filter reset), 3 invalid (non-finite input,
        skipped), 4 initialised, 5 reset after repeated gating.
    stats : dict
        ``updates, rejected_gate, rejected_invalid, resets, out_of_order``.
    """

    times: np.ndarray
    filtered: UncertainPose
    horizons: tuple[float, ...]
    predictions: dict = field(repr=False)
    nis: np.ndarray = field(repr=False)
    status: np.ndarray = field(repr=False)
    stats: dict = field(default_factory=dict)


def run_filter(
    times,
    poses: UncertainPose,
    model: MotionModel,
    horizons: Sequence[float] = (0.05,),
    gate_probability: float | None = 0.999,
    formulation: str = "error_state",
    max_angular_velocity: float = 50.0,
    reset_after: int = 10,
    covariance: bool = True,
    max_gap: float | None = None,
) -> FilterResult:
    """Run a pose Kalman filter over a whole recording in one compiled loop.

    Parameters
    ----------
    times : array_like (N,)
        Measurement times in seconds. Processed in time order (a stable sort), which is what a
        streaming filter with an unbounded history would do with out-of-order rows;
        ``stats["out_of_order"]`` counts the rows that were not in order.
    poses : UncertainPose, batch (N,)
        Measured poses ``T_a_b`` with 6x6 covariances. Rows with NaN/inf (tracker dropouts) are
        skipped and counted (``rejected_invalid``); their output is the prediction.
    model, gate_probability, formulation, max_angular_velocity, reset_after
        As for :class:`PoseKalmanFilter`.
    horizons : sequence of float
        Prediction horizons (s) evaluated after every measurement.
    covariance : bool
        ``False``: compute the same filter but output the means only (``Pose`` instead of
        ``UncertainPose``); the compiled loop then allocates nothing per measurement, about ten
        times faster (for parameter searches).
    max_gap : float, optional
        A measurement more than ``max_gap`` seconds after the previous one restarts the filter
        from scratch (status 4, initialised) instead of predicting across the dropout; the
        default never restarts.

    Returns
    -------
    FilterResult
    """
    opts = (gate_probability, formulation, max_angular_velocity, reset_after)
    kf, t, h, order, rows = _prepared(times, poses, model, horizons, max_gap, *opts)
    out = _run_segments(kf, rows, h, covariance, max_gap)
    out_t, out_q, out_c, pred_t, pred_q, pred_c, nis, status, _, _ = out
    out_of_order = 0 if order is None else int(np.count_nonzero(order != np.arange(t.size)))
    inv = slice(None) if order is None else np.argsort(order, kind="stable")
    if covariance:
        filtered = UncertainPose._trusted(out_t[inv], out_q[inv], out_c[inv])
        preds = {
            float(hv): UncertainPose._trusted(pred_t[j][inv], pred_q[j][inv], pred_c[j][inv])
            for j, hv in enumerate(h)
        }
    else:
        filtered = _means(out_t[inv], out_q[inv])
        preds = {float(hv): _means(pred_t[j][inv], pred_q[j][inv]) for j, hv in enumerate(h)}
    return FilterResult(
        times=t,
        filtered=filtered,
        horizons=tuple(float(v) for v in h),
        predictions=preds,
        nis=nis[inv],
        status=status[inv],
        stats={**_counts(status), "out_of_order": out_of_order},
    )


def smooth_filter(
    times,
    poses: UncertainPose,
    model: MotionModel,
    queries,
    gate_probability: float | None = 0.999,
    formulation: str = "error_state",
    max_angular_velocity: float = 50.0,
    reset_after: int = 10,
    max_gap: float | None = None,
) -> UncertainPose:
    """Smoothed poses at any times, from a whole recording, in two compiled passes.

    The recording is filtered forwards (as :func:`run_filter`), then smoothed backwards
    (Rauch-Tung-Striebel) and answered at ``queries``: the batch form of what a
    :class:`PoseKalmanFilter` holding the whole recording in its history answers with
    ``predict(t)``, in the same steps (a query between two states: one smoothing step from the
    filtered state before it to the smoothed state after it; at a state: the smoothed state;
    after the newest state of a segment: the motion model's prediction).

    Parameters
    ----------
    times, poses, model, gate_probability, formulation, max_angular_velocity, reset_after, max_gap
        As for :func:`run_filter`.
    queries : array_like (Q,)
        Times (s, same clock as ``times``), in any order, none before the first measurement.

    Returns
    -------
    UncertainPose (Q,)
        ``T_a_b`` at each query, 6x6 covariance over ``(dt, dtheta)`` with
        ``t_true = t + dt``, ``R_true = R Exp(dtheta)``.
    """
    opts = (gate_probability, formulation, max_angular_velocity, reset_after)
    kf, t, _, _, rows = _prepared(times, poses, model, (), max_gap, *opts)
    tq = np.ascontiguousarray(queries, dtype=float).reshape(-1)
    if not np.all(np.isfinite(tq)):
        raise InputError("query times must be finite")
    q_order = np.argsort(tq, kind="stable")
    tq_sorted = frozen(tq[q_order])
    if tq.size and tq_sorted[0] < rows[0][0]:
        raise ExtrapolationError(
            "the smoothed estimate", float(tq_sorted[0]), float(rows[0][0]), None,
            "the query is before the first measurement; a smoother answers only from its first "
            "state on"
        )  # fmt: skip
    *_, status, xs, ps = _run_segments(kf, rows, frozen(()), False, max_gap, states=True)
    n_dp, n_do, add, kind, sp, so = kf.kernel_settings.params
    out_t, out_q, out_c = np.zeros((tq.size, 3)), np.zeros((tq.size, 4)), np.zeros((tq.size, 6, 6))
    kernels().smooth_run(
        rows[0], xs, ps, status, tq_sorted, n_dp, n_do, add, kind, sp, so, out_t, out_q, out_c
    )
    inv = np.argsort(q_order, kind="stable")
    return UncertainPose._trusted(out_t[inv], out_q[inv], out_c[inv])


def _prepared(times, poses, model, horizons, max_gap, gate_probability, formulation, wmax, reset):
    """Checked inputs of a whole-recording run: the filter holding the validated options, the
    times and horizons, the sorting permutation (``None`` when already in order) and the rows
    ``(t, position, quaternion, covariance)`` in time order, as kernel inputs."""
    t, h = _checked_inputs(times, poses, horizons, max_gap)
    # validates the options the same way as the streaming filter
    kf = PoseKalmanFilter(
        model,
        gate_probability=gate_probability,
        formulation=formulation,
        max_angular_velocity=wmax,
        reset_after=reset,
    )
    order = np.argsort(t, kind="stable")
    if not np.any(order != np.arange(t.size)):  # in-order input (the usual case): no copies
        order = None

    def ordered(a):
        return frozen(a if order is None else a[order])

    rows = (ordered(t), ordered(poses.position), ordered(poses.quaternion))
    return kf, t, frozen(h), order, (*rows, ordered(poses.covariance))


def _checked_inputs(times, poses, horizons, max_gap) -> tuple[np.ndarray, np.ndarray]:
    """Times (N,) and horizons (H,) as contiguous floats; ``ValueError`` naming the problem."""
    t = np.ascontiguousarray(times, dtype=float).reshape(-1)
    if not isinstance(poses, UncertainPose) or poses.shape != t.shape:
        raise InputError(
            f"poses must be an UncertainPose batch of shape {t.shape}, "
            f"got {type(poses).__name__} {getattr(poses, 'shape', '')}"
        )
    if not np.all(np.isfinite(t)):
        bad = int(np.flatnonzero(~np.isfinite(t))[0])
        raise InputError(f"times must be finite (row {bad} is {t[bad]})")
    h = np.ascontiguousarray(horizons, dtype=float).reshape(-1)
    if not np.all(np.isfinite(h)) or np.any(h < 0):
        raise InputError(f"horizons must be finite and >= 0, got {h.tolist()}")
    if max_gap is not None and not (math.isfinite(max_gap) and max_gap > 0):
        raise InputError(f"max_gap must be a positive number of seconds, got {max_gap}")
    return t, h


def _run_segments(kf, rows, h, covariance, max_gap, states=False):
    """The compiled loop over each segment between dropouts longer than ``max_gap`` (each
    filtered from scratch); returns the output arrays in time order, and with ``states`` the
    filter states after each row (:func:`smooth_filter`)."""
    ts, pos, quat, cov = rows
    settings = kf.kernel_settings
    n_dp, n_do, add, kind, sp, so = settings.params
    gate, wmax, reset_after = settings.gate, settings.max_angular_velocity, settings.reset_after
    n, nh = ts.size, h.size
    out_t, out_q = np.zeros((n, 3)), np.zeros((n, 4))
    pred_t, pred_q = np.zeros((nh, n, 3)), np.zeros((nh, n, 4))
    m = n if covariance else 0  # the loop leaves the covariance outputs alone without them
    out_c, pred_c = np.zeros((m, 6, 6)), np.zeros((nh, m, 6, 6))
    nis = np.full(n, math.nan)
    status = np.zeros(n, dtype=np.int8)
    ns = n if states else 0
    out_x, out_p = np.zeros((ns, settings.x0.size)), np.zeros((ns, *settings.p0.shape))
    cuts = [0, n]
    if max_gap is not None and n > 1:
        cuts = [0, *(np.flatnonzero(np.diff(ts) > max_gap) + 1).tolist(), n]
    k = kernels()
    for a, b in zip(cuts[:-1], cuts[1:]):
        x, p = settings.x0.copy(), settings.p0.copy()
        seg = slice(a, b)
        cseg = seg if covariance else slice(0, 0)
        sseg = seg if states else slice(0, 0)
        # the per-horizon outputs of one segment are strided views of the whole arrays: the
        # kernel writes into contiguous buffers (one compiled specialisation), copied back
        seg_pt, seg_pq = np.zeros((nh, b - a, 3)), np.zeros((nh, b - a, 4))
        seg_pc = np.zeros((nh, (b - a) if covariance else 0, 6, 6))
        k.run(
            ts[seg], pos[seg], quat[seg], cov[seg], h, x, p, n_dp, n_do, add, kind, sp, so,
            gate, float(wmax), int(reset_after), bool(covariance), out_t[seg], out_q[seg],
            out_c[cseg], seg_pt, seg_pq, seg_pc, nis[seg], status[seg], out_x[sseg], out_p[sseg],
        )  # fmt: skip
        pred_t[:, seg], pred_q[:, seg], pred_c[:, cseg] = seg_pt, seg_pq, seg_pc
    return out_t, out_q, out_c, pred_t, pred_q, pred_c, nis, status, out_x, out_p


def _counts(status: np.ndarray) -> dict:
    """The offline statistics of the status codes (``FilterResult.stats``)."""
    counts = np.bincount(status, minlength=len(FilterStatus))
    return {
        "updates": int(
            counts[FilterStatus.ACCEPTED]
            + counts[FilterStatus.INITIALIZED]
            + counts[FilterStatus.RESET]
            + counts[FilterStatus.DIVERGED]
        ),
        "rejected_gate": int(counts[FilterStatus.GATED]),
        "rejected_invalid": int(counts[FilterStatus.INVALID]),
        "resets": int(counts[FilterStatus.RESET] + counts[FilterStatus.DIVERGED]),
    }


def _means(position: np.ndarray, quaternion: np.ndarray) -> Pose:
    # the kernels' quaternions are unit up to rounding, as in the covariance path
    return Pose._trusted(position, quaternion)
