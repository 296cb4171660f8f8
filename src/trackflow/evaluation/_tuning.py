"""Automatic tuning of the prediction filter (thesis section 8.1.4) and honest evaluation."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TextIO

import numpy as np
from scipy.optimize import minimize

from ..filters import MotionModel
from ..filters.twist_ar import TwistARModel, excitation_ratios
from ..math import quat_angle
from ._baselines import predict_linear
from ._evaluate import PredictionReport, evaluate_predictors
from ._predictor import KalmanPredictor, PartwisePredictor, TwistARPredictor, default_predictor
from ._trajectory import Trajectory

__all__ = ["LEARNED_ORDERS", "TuneResult", "tune_model", "evaluate_recording"]

#: orders of the learned increment models the tuning tries by default
LEARNED_ORDERS = (3, 5, 10)
_BOUNDS = (-9.0, 6.0)  # log10 of the white-noise densities
# coarse start grid in log10: value-level noise relative to the measurement sigma, and the
# highest-derivative noise (shifted up by half a decade per derivative above the first)
_GRID_VALUE = (-1.0, 0.5, 2.0, 3.5)
_GRID_TOP = (-1.0, 0.5, 2.0, 3.5)
_PRUNE = 1.25  # derivative counts whose best grid cost exceeds 1.25 x the part's best: skipped
# learned-increment filter (trackflow.filters.twist_ar): couplings tried, validation blocks,
# measurement sigma relative to the estimated noise (that estimate, from second differences,
# mostly measures motion on smoothed recordings; the first scale is tried with every
# candidate, the others with each part's best), warm-up samples per order
_AR_STRUCTURES = ("full", "isotropic")
_AR_SPLITS = (1 / 3, 2 / 3)  # validation spans start here (fractions of the tuning duration)
_AR_FOLDS = len(_AR_SPLITS) + 1
_AR_SCALES = (0.1, 1.0)
_AR_WARMUP = 5
# smallest spread along a body axis relative to the largest (``excitation_ratios``) for which
# the full-coupling model is tried
_AR_MIN_EXCITATION = 0.25


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


def _huber(e: np.ndarray, c: float) -> np.ndarray:
    return np.where(e <= c, 0.5 * e * e, c * (e - 0.5 * c))


class _Progress:
    """A one-line progress bar on a text stream (stderr in the CLI)."""

    def __init__(self, stream: TextIO | None, total: int, width: int = 30):
        self.stream, self.total, self.width, self.n = stream, total, width, 0
        self.label, self.best, self._last = "", float("inf"), 0.0

    def start(self, label: str) -> None:
        self.label, self.best = label, float("inf")

    def step(self, cost: float) -> None:
        self.n += 1
        self.best = min(self.best, cost)
        now = time.perf_counter()
        if self.stream is None or now - self._last < 0.2:
            return
        self._last = now
        done = min(self.n, self.total) * self.width // self.total
        self.stream.write(
            f"\rtuning {self.label:<22} [{'#' * done}{'.' * (self.width - done)}] "
            f"{self.n:4d} evals, best cost {self.best:.4f}"
        )
        self.stream.flush()

    def close(self) -> None:
        if self.stream is not None:
            self.stream.write("\n")
            self.stream.flush()


def _grid(cost, starts) -> tuple[np.ndarray, np.ndarray]:
    """``cost`` at every grid point: ``(points (G, D), values (G,))``."""
    pts = np.array([np.asarray(s, dtype=float) for s in starts])
    return pts, np.array([cost(s) for s in pts])


def _refine(cost, pts, values, options, n_starts: int = 2) -> np.ndarray:
    """Powell from the best basins of a grid (see :func:`_grid_then_powell`)."""
    step = np.array([np.min(np.diff(np.unique(c))) if np.unique(c).size > 1 else 1.0
                     for c in pts.T])  # fmt: skip
    near = np.all(np.abs(pts[:, None, :] - pts[None, :, :]) <= 1.5 * step, axis=2)
    local = [i for i in range(len(values)) if values[i] <= values[near[i]].min()]
    chosen = sorted(local, key=lambda i: values[i])[:n_starts]
    best_x, best_f = pts[chosen[0]], float(values[chosen[0]])
    for i in chosen:
        # local: Powell's bounded line searches span the whole box, so the box is the basin
        lo = np.maximum(pts[i] - 1.5 * step, _BOUNDS[0])
        hi = np.minimum(pts[i] + 1.5 * step, _BOUNDS[1])
        res = minimize(cost, pts[i], method="Powell", bounds=list(zip(lo, hi)),
                       options=options)  # fmt: skip
        if float(res.fun) < best_f:
            best_x, best_f = np.asarray(res.x, dtype=float), float(res.fun)
    return best_x


def _grid_then_powell(cost, starts, options, n_starts: int = 2) -> np.ndarray:
    """Minimise ``cost`` over log10 parameters: a coarse grid, then Powell from its best basins.

    The cost has long flat plateaus and several narrow ridges in these coordinates, so one
    local search lands in whichever optimum is nearest its start. The grid points that are
    local minima of the grid (no lower value among their neighbours, 1 grid step away in every
    coordinate) each stand for one basin; Powell refines the ``n_starts`` best of them, each
    inside the box of +-1.5 grid steps around it (scipy's bounded line searches range over
    the whole box, so wider bounds would let a refinement jump into another basin), and the
    lowest result wins (never worse than the best grid point).
    """
    pts, values = _grid(cost, starts)
    return _refine(cost, pts, values, options, n_starts)


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

    The filter is :func:`trackflow.filters.run_filter` (via :class:`KalmanPredictor`). Its
    position and orientation parts are independent (block-diagonal noise, see
    :meth:`KalmanPredictor.part`), so each is tuned on its own, with two parameters: the
    log10 white-noise densities on the value (level 0) and on the highest derivative. For each
    candidate derivative count a coarse 4 x 4 grid in log space is evaluated on the first
    ``1 - holdout`` of the tuning data; counts far behind on the grid (``_PRUNE``) are
    dropped, and for the others Powell's method (scipy) refines the two best basins of the
    grid, each inside its own box (:func:`_grid_then_powell`), so the result does not hinge
    on one starting point. The derivative count with the lowest mean of the search cost and
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
    data = recording
    t, p, q = data.t, data.position, data.quaternion
    h = np.ascontiguousarray(horizons, dtype=float).reshape(-1)
    if h.size == 0 or np.any(~np.isfinite(h)) or np.any(h <= 0):
        raise ValueError(f"horizons must be positive seconds, got {h.tolist()}")
    if not 0.0 <= holdout <= 0.5:
        raise ValueError(f"holdout must be in [0, 0.5], got {holdout}")
    if start is not None and not isinstance(start, KalmanPredictor):
        raise ValueError(
            f"start must be a KalmanPredictor (its measurement noise and gate are kept), got "
            f"{type(start).__name__}"
        )
    base = start if start is not None else default_predictor(t, p, q)
    cands = {
        "position": tuple(int(d) for d in pos_derivatives),
        "orientation": tuple(int(d) for d in ori_derivatives),
    }
    for part, ds in cands.items():
        if not ds or any(d < 0 for d in ds):
            raise ValueError(f"{part} derivative counts must be >= 0, got {ds}")
    t_hold = float(t[0] + (1.0 - holdout) * (t[-1] - t[0])) if holdout > 0 else np.inf
    # per part and horizon: (search mask, hold mask, target, Huber threshold, linear costs)
    targets = {"position": [], "orientation": []}
    for hs in h:
        m = data.scored(hs)
        search, hold = m & (t < t_hold), m & (t >= t_hold)
        if np.count_nonzero(search) < 10:
            raise ValueError(f"too few scorable samples for horizon {hs} s in the tuning data")
        ip, iq = data.target(hs)
        lp, lq = predict_linear(t, p, q, hs)
        for part, err, tgt in (
            ("position", np.linalg.norm(lp - ip, axis=1), ip),
            ("orientation", quat_angle(lq, iq), iq),
        ):
            c = 3.0 * float(np.median(err[search])) + 1e-12
            sets = (search, hold, search | hold)
            lin = [np.mean(_huber(err[s], c)) + 1e-300 if np.any(s) else np.nan
                   for s in sets]  # fmt: skip
            targets[part].append((sets, tgt, c, lin, err))
    n_hold = min(int(np.count_nonzero(tg[0][1])) for tg in targets["position"])

    n_grid = len(_GRID_VALUE) * len(_GRID_TOP)
    n_cand = sum(len(ds) for ds in cands.values())
    if isinstance(ar_orders, (str, bytes)) or not all(
        isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in ar_orders
    ):
        raise ValueError(f"ar_orders must be a sequence of integers, got {ar_orders!r}")
    ar_orders = tuple(int(v) for v in ar_orders)
    if any(v < 1 for v in ar_orders):
        raise ValueError(f"ar_orders must be >= 1, got {ar_orders}")
    check = np.asarray(check_horizons, dtype=float).reshape(-1)
    if np.any(~np.isfinite(check)) or np.any(check <= 0):
        raise ValueError(f"check_horizons must be positive seconds, got {check.tolist()}")
    step = data.step
    total = n_cand * (2 * max_evaluations + n_grid + 1) + max_evaluations
    total += len(ar_orders) * len(_AR_STRUCTURES) + 2 * (len(_AR_SCALES) - 1)
    bar = _Progress(progress, total=total)
    t0 = time.perf_counter()

    def _pad(z):  # one parameter (nd = 0): the value level alone
        z = np.asarray(z, dtype=float)
        return z if z.size == 2 else np.array([z[0], _BOUNDS[0]])

    def levels(lx, nd):
        v = np.zeros(nd + 1)
        v[0] += 10.0 ** lx[0]
        v[nd] += 10.0 ** lx[1]
        return v

    def run_part(part, lx, nd):
        if part == "position":
            model = MotionModel(nd, -1, levels(lx, nd), kind=base.model.kind)
        else:
            model = MotionModel(-1, nd, levels(lx, nd), kind=base.model.kind)
        # no gate during the search: the cost stays smooth in the parameters
        res = KalmanPredictor(model, base.pos_sigma, base.ori_sigma, None).predict(data, h)
        costs = part_costs(part, {float(v): (res.position[i], res.quaternion[i])
                                  for i, v in enumerate(h)})  # fmt: skip
        bar.step(costs[0])
        return costs

    def part_costs(part, preds, only=None):
        """Search, held-out and all-data costs of one part from ``{h: (pos, quat)}``.

        ``only`` (bool mask) restricts every set to those samples (normalised by linear
        extrapolation on the same samples).
        """
        costs = np.zeros(3)  # search, held-out, all tuning data
        for i, (sets, tgt, c, lin, lin_err) in enumerate(targets[part]):
            pk_p, pk_q = preds[float(h[i])]
            for j, s in enumerate(sets):
                norm = lin[j]
                if only is not None:
                    s = s & only
                    norm = np.mean(_huber(lin_err[s], c)) + 1e-300 if np.any(s) else np.nan
                if not np.any(s):
                    continue
                if part == "position":
                    e = np.linalg.norm(pk_p[s] - tgt[s], axis=1)
                else:
                    e = quat_angle(pk_q[s], tgt[s])
                costs[j] += np.mean(_huber(e, c)) / norm
        costs /= h.size
        costs[~np.isfinite(costs)] = 1e6
        return costs

    best, summary = {}, {}
    opts = {"xtol": 0.1, "ftol": 2e-3, "maxfev": max_evaluations}
    for part, ds in cands.items():
        sigma = base.pos_sigma if part == "position" else base.ori_sigma
        ls = np.log10(max(sigma, 1e-9))
        summary[part], grids = {}, {}
        for nd in ds:
            bar.start(f"{part} ({nd} deriv., grid)")
            if nd == 0:  # one level: one parameter (a random walk of the value)
                starts = [(ls + g,) for g in _GRID_VALUE]
            else:
                top = [g + 0.5 * (nd - 1) for g in _GRID_TOP]
                starts = [(ls + g, b) for g in _GRID_VALUE for b in top]
            cost = lambda z, nd=nd, part=part: run_part(part, _pad(z), nd)[0]  # noqa: E731
            grids[nd] = (cost, *_grid(cost, starts))
        floor = min(float(np.min(g[2])) for g in grids.values())
        for nd, (cost, pts, values) in grids.items():
            if np.min(values) > _PRUNE * floor:  # far behind on the grid: not refined
                x = _pad(pts[int(np.argmin(values))])
                summary[part][str(nd)] = {"search_cost": float(np.min(values)), "pruned": True,
                                          "noise": levels(x, nd).tolist()}  # fmt: skip
                continue
            bar.start(f"{part} ({nd} deriv.)")
            x = _pad(_refine(cost, pts, values, opts))
            c_search, c_hold, _ = run_part(part, x, nd)
            # the tail alone is short and noisy: choose on the mean of both costs
            choose = 0.5 * (c_search + c_hold) if n_hold >= 10 else c_search
            summary[part][str(nd)] = {"search_cost": float(c_search), "holdout_cost": float(c_hold),
                                      "noise": levels(x, nd).tolist()}  # fmt: skip
            if part not in best or choose < best[part][0]:
                best[part] = (float(choose), nd, x)
        # the chosen count is refined on all the tuning data (the held-out tail is the most
        # recent motion, so it should shape the final noise too), locally (+-1 decade)
        choose, nd, x = best[part]
        bar.start(f"{part} ({nd} deriv., all)")
        cost_all = lambda z, nd=nd, part=part: run_part(part, _pad(z), nd)[2]  # noqa: E731
        z0 = x if nd > 0 else x[:1]
        box = list(zip(np.maximum(z0 - 1.0, _BOUNDS[0]), np.minimum(z0 + 1.0, _BOUNDS[1])))
        res = minimize(cost_all, z0, method="Powell", bounds=box,
                       options={**opts, "maxfev": max(max_evaluations // 2, 1)})  # fmt: skip
        if float(res.fun) < cost_all(z0):
            x = _pad(res.x)
        best[part] = (choose, nd, levels(x, nd))
    (cp_, ndp, vp), (co_, ndo, vo) = best["position"], best["orientation"]
    model = MotionModel(ndp, ndo, np.r_[vp, vo], kind=base.model.kind)
    tuned = KalmanPredictor(model, base.pos_sigma, base.ori_sigma, base.gate_probability)
    chosen = {"position": (cp_, tuned), "orientation": (co_, tuned)}

    # learned increment dynamics (trackflow.filters.twist_ar), scored forward in time: the
    # tuning data is cut into blocks and each block after the first is predicted by a model
    # fitted to the blocks before it, as the evaluation predicts the future from the past (a
    # model that only fits the motion it saw, e.g. along one axis, loses here); kept per part
    # where it beats the derivative model
    if ar_orders:
        summary["twist_ar"] = {}
        edges = t[0] + (t[-1] - t[0]) * np.array(_AR_SPLITS)
        block = np.searchsorted(edges, t, side="right")  # 0: fit only; 1, 2: validated
        ar_best = {}
        # persistent excitation: full couplings only when the tuning data moves along every
        # body axis (otherwise the full model is unidentified along the others)
        ratios = excitation_ratios(t, p, q)
        structures = _AR_STRUCTURES if min(ratios) >= _AR_MIN_EXCITATION else ("isotropic",)
        summary["twist_ar"]["excitation"] = {"translation": ratios[0], "rotation": ratios[1]}

        hold_last = {float(v): (p, q) for v in h}  # the "none" predictor
        # horizons of the never-worse-than-holding check (besides the tuning horizons):
        # targets and the last sample's RMS errors per part, horizon and validation span
        hc = np.unique(np.r_[h, check]).astype(float)
        guard = []
        for v in hc:
            guard.append((float(v), data.scored(v), *data.target(v)))

        def worse_than_holding(part, preds):
            """Validation spans where some check horizon's RMS error exceeds holding's."""
            out = set()
            for v, m, ip, iq in guard:
                pp, pq = preds[v]
                for b in range(1, _AR_FOLDS):
                    s_ = m & (block == b)
                    if not np.any(s_):
                        continue
                    if part == "position":
                        e = np.linalg.norm(pp[s_] - ip[s_], axis=1)
                        e0 = np.linalg.norm(p[s_] - ip[s_], axis=1)
                    else:
                        e, e0 = quat_angle(pq[s_], iq[s_]), quat_angle(q[s_], iq[s_])
                    if np.mean(e * e) > np.mean(e0 * e0):
                        out.add(b)
            return sorted(out)

        def score_ar(structure, order, scale):
            """Forward-validated costs of one learned candidate, or None if it cannot be fit."""
            key = f"{structure} {order} @{scale:g}"
            bar.start(f"learned {structure} ({order})")
            preds = {float(v): (np.zeros((t.size, 3)), np.zeros((t.size, 4))) for v in hc}
            try:
                for b in range(1, _AR_FOLDS):
                    rows = np.flatnonzero(block == b)
                    fitted = TwistARModel.fit(t, p, q, order, dt=step, structure=structure,
                                              use=block < b)  # fmt: skip
                    lo = max(int(rows[0]) - _AR_WARMUP * order, 0)
                    seg = slice(lo, int(rows[-1]) + 1)
                    pred = TwistARPredictor(fitted, base.pos_sigma * scale,
                                            base.ori_sigma * scale)  # fmt: skip
                    out = pred.predict(data.select(seg), hc)
                    for j, v in enumerate(hc):
                        preds[float(v)][0][rows] = out.position[j][rows - lo]
                        preds[float(v)][1][rows] = out.quaternion[j][rows - lo]
            except ValueError as exc:  # too little regular data for this order
                summary["twist_ar"][key] = {"skipped": str(exc)}
                bar.step(np.inf)
                return None
            rec, info = {}, {}
            for part in ("position", "orientation"):
                c = float(part_costs(part, preds, block > 0)[2])  # all out-of-sample
                # never worse than holding the last measurement, in any validation span (in
                # the robust cost at the tuning horizons, in RMS at the check horizons): a
                # model that is only better on average is not kept for that part
                worse = sorted(set(worse_than_holding(part, preds)) | {
                    b for b in range(1, _AR_FOLDS)
                    if part_costs(part, preds, block == b)[2]
                    > part_costs(part, hold_last, block == b)[2]})  # fmt: skip
                info[part] = {"cv_cost": c, "worse_than_none_in_blocks": worse}
                rec[part] = np.inf if worse else c
            bar.step(min(rec.values()))
            summary["twist_ar"][key] = info
            return rec

        for structure in structures:
            for order in ar_orders:
                rec = score_ar(structure, order, _AR_SCALES[0])
                for part, c in (rec or {}).items():
                    if np.isfinite(c) and (part not in ar_best or c < ar_best[part][0]):
                        ar_best[part] = (c, structure, order, _AR_SCALES[0])
        # the measurement noise: the best candidates again with the other scales
        for structure, order in sorted({v[1:3] for v in ar_best.values()}):
            for scale in _AR_SCALES[1:]:
                for part, c in (score_ar(structure, order, scale) or {}).items():
                    best = ar_best.get(part)
                    if best is not None and c < best[0] and best[1:3] == (structure, order):
                        ar_best[part] = (c, structure, order, scale)
        finals = {}
        for part, (c, *key) in ar_best.items():
            if c < chosen[part][0]:
                key = tuple(key)
                if key not in finals:  # refitted on all the tuning data
                    structure, order, scale = key
                    m = TwistARModel.fit(t, p, q, order, dt=step, structure=structure)
                    finals[key] = TwistARPredictor(
                        m, base.pos_sigma * scale, base.ori_sigma * scale
                    )
                chosen[part] = (c, finals[key])
    bar.close()
    (cp_, pos_pred), (co_, ori_pred) = chosen["position"], chosen["orientation"]
    final = pos_pred if pos_pred is ori_pred else PartwisePredictor(pos_pred, ori_pred)
    return TuneResult(final, cp_, co_, bar.n, time.perf_counter() - t0, summary)


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
    cross-validated. ``tune_fraction = 0`` skips tuning, uses ``predictor`` (default
    :func:`default_predictor`) and scores the whole recording.

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
        ``tuning`` holds the :class:`TuneResult` summary when tuning ran.
    """
    rec = recording
    t = rec.t
    if not 0.0 <= tune_fraction < 1.0:
        raise ValueError(f"tune_fraction must be in [0, 1), got {tune_fraction}")
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
        raise ValueError(f"tune_fraction {tune_fraction} leaves too few samples on one side")
    res = tune_model(
        rec.select(train), tune_horizons, start=predictor, ar_orders=ar_orders,
        check_horizons=horizons, progress=progress,
    )  # fmt: skip
    report = evaluate_predictors(rec, res.predictor, horizons, split)
    report.tuning = res.as_dict()
    return report
