"""Automatic tuning of the prediction filter (thesis section 8.1.4) and honest evaluation."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TextIO

import numpy as np

from ..errors import InputError
from ._derivative_search import GRID_SIZE, search_derivatives
from ._evaluate import PredictionReport, evaluate_predictors
from ._learned_search import learned_evaluations, search_learned
from ._prediction import positive_horizons
from ._predictor import KalmanPredictor, PartwisePredictor, TwistARPredictor, default_predictor
from ._search import Progress
from ._shrinkage import fit_shrinkage
from ._trajectory import Trajectory
from ._tuning_cost import TuningCost

__all__ = ["LEARNED_ORDERS", "TuneResult", "tune_model", "evaluate_recording"]

#: orders of the learned increment models the tuning tries by default
LEARNED_ORDERS = (3, 5, 10)


@dataclass(frozen=True)
class TuneResult:
    """Outcome of :func:`tune_model`: the chosen filter and how the search went.

    ``predictor`` is a :class:`KalmanPredictor` (derivative models for both parts), a
    :class:`TwistARPredictor` (one learned model for both) or a :class:`PartwisePredictor`.

    ``cost_position`` / ``cost_orientation`` are the robust prediction costs of the chosen
    derivative counts (mean of the search and held-out costs), relative to linear
    extrapolation (1.0 = as good as linear extrapolation). ``candidates`` lists every derivative
    count tried with its search and held-out costs.
    """

    predictor: KalmanPredictor | TwistARPredictor | PartwisePredictor
    cost_position: float
    cost_orientation: float
    n_evaluations: int
    seconds: float
    candidates: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {
            "cost_position": self.cost_position,
            "cost_orientation": self.cost_orientation,
            "n_evaluations": self.n_evaluations,
            "seconds": self.seconds,
            "candidates": self.candidates,
        }


def tune_model(
    recording: Trajectory,
    horizons=(0.05, 0.1),
    pos_derivatives=(1, 2, 3),
    ori_derivatives=(1, 2),
    start: KalmanPredictor | None = None,
    holdout: float = 0.25,
    max_evaluations: int = 15,
    ar_orders=LEARNED_ORDERS,
    check_horizons=(0.01, 0.02, 0.05, 0.1, 0.2),
    progress: TextIO | None = None,
) -> TuneResult:
    """Choose process noise and derivative counts that minimise the prediction error.

    Two searches, one after the other: the derivative-model search (``_derivative_search``)
    and the learned-model search (``_learned_search``); both score predictions with the same
    cost (``_tuning_cost.TuningCost``).

    The filter is :func:`trackflow.filters.run_filter` (via :class:`KalmanPredictor`). Its
    position and orientation parts are independent (block-diagonal noise, see
    :meth:`KalmanPredictor.part`), so each is tuned on its own, with two parameters: the
    log10 white-noise densities on the value (level 0) and on the highest derivative. For each
    candidate derivative count a coarse 4 x 4 grid in log space is evaluated on the first
    ``1 - holdout`` of the tuning data; counts far behind on the grid (1.25 x the best) are
    dropped, and for the others Powell's method (scipy) refines the two best basins of the
    grid, each inside its own box (``_search.grid_then_powell``), so the result does not
    hinge on one starting point. The derivative count with the lowest mean of the search cost and
    the cost on the held-out tail wins (more derivatives can fit the search data yet
    extrapolate noise); its densities are then refined locally on all the tuning data.

    The cost is, averaged over ``horizons``, the mean Huber loss of the prediction error
    divided by that of linear extrapolation from the last two samples; the Huber threshold is
    three times the median linear-extrapolation error, so outliers (tracking spikes, which the
    thesis removed by hand) count linearly instead of quadratically. Targets across gaps
    (intervals longer than ``gap_s``) are not scored, and the filter restarts after them; its
    chi-square gate rejects isolated outlier measurements.

    Parameters
    ----------
    recording : Trajectory
        Tuning data ``T_a_b``; its ``gap_s`` marks the gaps.
    horizons : sequence of float
        Horizons [s] the cost is taken at.
    pos_derivatives, ori_derivatives : sequence of int
        Candidate derivative counts (>= 0) of the two parts.
    start : KalmanPredictor, optional
        Measurement noise and gate to keep (default :func:`default_predictor`).
    holdout : float in [0, 0.5]
        Fraction of the tuning duration (at its end) used only to choose the derivative counts;
        0 chooses on the search cost.
    max_evaluations : int
        Powell evaluation budget per start (two starts per part and derivative count; half
        of it for the final refinement).
    ar_orders : sequence of int
        Orders ``L`` of the learned increment models (:mod:`trackflow.filters.twist_ar`)
        tried after the derivative search, each with the structures ``"full"`` (only when
        :func:`~trackflow.filters.excitation_ratios` of the tuning data are >= 0.25) and
        ``"isotropic"``. They are scored forward in time: the tuning data is cut into three
        spans, the second predicted by a model fitted to the first, the third by one fitted
        to the first two. A learned model that is worse than holding the last sample in
        either span is not kept for that part; otherwise, per part, it replaces the
        derivative model if its cost is lower, refitted on all the tuning data. ``()``:
        derivative models only.
    check_horizons : sequence of float
        Horizons [s] at which a learned model must also not be worse (RMS) than holding the
        last sample in either validation span (besides ``horizons``).
    progress : text stream, optional
        Where to draw a progress bar (e.g. ``sys.stderr``).

    Returns
    -------
    TuneResult
    """
    h = positive_horizons(horizons, "horizons")
    if not 0.0 <= holdout <= 0.5:
        raise InputError(f"holdout must be in [0, 0.5], got {holdout}")
    if start is not None and not isinstance(start, KalmanPredictor):
        raise InputError(
            f"start must be a KalmanPredictor (its measurement noise and gate are kept), got "
            f"{type(start).__name__}"
        )
    counts = {"position": _counts(pos_derivatives, "position"),
              "orientation": _counts(ori_derivatives, "orientation")}  # fmt: skip
    ar_orders = _orders(ar_orders)
    check = np.asarray(check_horizons, dtype=float).reshape(-1)
    if np.any(~np.isfinite(check)) or np.any(check <= 0):
        raise InputError(f"check_horizons must be positive seconds, got {check.tolist()}")
    data = recording
    base = start if start is not None else default_predictor(data.t, data.position,
                                                             data.quaternion)  # fmt: skip
    cost = TuningCost(data, h, holdout)
    n_cand = sum(len(ds) for ds in counts.values())
    total = n_cand * (2 * max_evaluations + GRID_SIZE + 1) + max_evaluations
    bar = Progress(progress, total=total + learned_evaluations(len(ar_orders)))
    t0 = time.perf_counter()
    tuned, costs, summary = search_derivatives(data, cost, base, counts, max_evaluations, bar)
    chosen = {part: (costs[part], tuned) for part in costs}
    if ar_orders:
        sigmas = (base.pos_sigma, base.ori_sigma)
        chosen, summary["twist_ar"] = search_learned(data, cost, sigmas, ar_orders, check,
                                                     chosen, bar)  # fmt: skip
    bar.close()
    (cp, pos_pred), (co, ori_pred) = chosen["position"], chosen["orientation"]
    final = pos_pred if pos_pred is ori_pred else PartwisePredictor(pos_pred, ori_pred)
    return TuneResult(final, cp, co, bar.n, time.perf_counter() - t0, summary)


def _counts(derivatives, part: str) -> tuple[int, ...]:
    ds = tuple(int(d) for d in derivatives)
    if not ds or any(d < 0 for d in ds):
        raise InputError(f"{part} derivative counts must be >= 0, got {ds}")
    return ds


def _orders(ar_orders) -> tuple[int, ...]:
    if isinstance(ar_orders, (str, bytes)) or not all(
        isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in ar_orders
    ):
        raise InputError(f"ar_orders must be a sequence of integers, got {ar_orders!r}")
    orders = tuple(int(v) for v in ar_orders)
    if any(v < 1 for v in orders):
        raise InputError(f"ar_orders must be >= 1, got {orders}")
    return orders


def evaluate_recording(
    recording: Trajectory,
    horizons=(0.01, 0.02, 0.05, 0.1, 0.2),
    tune_fraction: float = 0.5,
    tune_horizons=(0.05, 0.1),
    predictor: KalmanPredictor | None = None,
    ar_orders=LEARNED_ORDERS,
    progress: TextIO | None = None,
) -> PredictionReport:
    """Tune on the first part of a recording and score all predictors on the rest.

    The first ``tune_fraction`` of the duration is used by :func:`tune_model`; the prediction
    errors (:func:`evaluate_predictors`) are scored only from there on, so the figures are
    cross-validated. The tuned filter's predicted change is scaled per horizon
    (:func:`~trackflow.evaluation.fit_shrinkage`, fitted on the tuning part) so that it is
    never worse than holding the last sample there. ``tune_fraction = 0`` skips tuning, uses
    ``predictor`` (default :func:`default_predictor`) and scores the whole recording.

    Parameters
    ----------
    recording : Trajectory
        The checked recording ``T_a_b``; its gaps hold for the tuning and the scoring.
    horizons, tune_horizons : sequence of float
        Scored and tuned horizons [s].
    tune_fraction : float in [0, 1)
    predictor : KalmanPredictor, optional
        Starting point of the tuning (its measurement noise and gate are kept), or, without
        tuning, the evaluated filter.
    ar_orders : sequence of int
        Orders of the learned increment models the tuning tries (``()``: derivative models
        only); see :func:`tune_model`.
    progress : text stream, optional

    Returns
    -------
    PredictionReport
        ``tuning`` holds the :class:`TuneResult` summary and the ``shrinkage`` factors when
        tuning ran; ``predictor`` is the tuned filter (before shrinkage).
    """
    rec = recording
    t = rec.t
    if not 0.0 <= tune_fraction < 1.0:
        raise InputError(f"tune_fraction must be in [0, 1), got {tune_fraction}")
    if tune_fraction == 0.0:
        m = (
            predictor
            if predictor is not None
            else default_predictor(t, rec.position, rec.quaternion)
        )
        return evaluate_predictors(rec, m, horizons)
    split = float(t[0] + tune_fraction * (t[-1] - t[0]))
    train = t <= split
    if np.count_nonzero(train) < 20 or np.count_nonzero(~train) < 20:
        raise InputError(f"tune_fraction {tune_fraction} leaves too few samples on one side")
    res = tune_model(
        rec.select(train), tune_horizons, start=predictor, ar_orders=ar_orders,
        check_horizons=horizons, progress=progress,
    )  # fmt: skip
    # scale the predicted change per horizon so that on the tuning data it is never worse than
    # holding the last sample (fast hand motion turns back within the longer horizons)
    shrunk = fit_shrinkage(rec.select(train), res.predictor, horizons)
    report = evaluate_predictors(rec, shrunk, horizons, split)
    report.predictor = res.predictor  # the tuned filter; its shrinkage is in the tuning dict
    report.tuning = {**res.as_dict(), "shrinkage": shrunk.shrinkage_dict()}
    return report
