"""Automatic tuning of the prediction filter (thesis section 8.1.4) and honest evaluation."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import TextIO

import numpy as np
from scipy.optimize import minimize

from ..math import quat_angle
from ._baselines import predict_linear
from ._evaluate import PredictionReport, _as_arrays, evaluate_predictors
from ._kalman import run_predictor_orientation, run_predictor_position
from ._model import PredictionModel, estimate_noise
from ._targets import default_gap, interpolate_poses, scored_mask

__all__ = ["TuneResult", "default_model", "tune_model", "evaluate_recording"]

_BOUNDS = (-10.0, 5.0)  # log10 of noise densities


@dataclass(frozen=True)
class TuneResult:
    """Outcome of :func:`tune_model`: the model and how the search went.

    ``cost_position`` / ``cost_orientation`` are the robust prediction costs relative to
    linear extrapolation on the tuning data (1.0 = as good as linear extrapolation).
    """

    model: PredictionModel
    cost_position: float
    cost_orientation: float
    n_evaluations: int
    seconds: float

    def as_dict(self) -> dict:
        return {
            "cost_position": self.cost_position,
            "cost_orientation": self.cost_orientation,
            "n_evaluations": self.n_evaluations,
            "seconds": self.seconds,
        }


def default_model(t, position, quaternion) -> PredictionModel:
    """Untuned starting model: measurement noise estimated from the data, generic dynamics.

    Position: constant acceleration with white jerk of 30 m/s^3/sqrt(s); orientation: constant
    angular velocity with white angular acceleration of 30 rad/s^2/sqrt(s) (fast hand motion).
    """
    ps, os_ = estimate_noise(t, position, quaternion)
    return PredictionModel(
        n_dp=2, n_do=1, pos_noise=ps, pos_top_noise=30.0, ori_noise=os_, ori_top_noise=30.0,
        pos_sigma=ps, ori_sigma=os_,
    )  # fmt: skip


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


def tune_model(
    t,
    position,
    quaternion,
    horizons=(0.05, 0.1),
    derivatives=(1, 2),
    start: PredictionModel | None = None,
    gap_s: float | None = None,
    max_evaluations: int = 120,
    progress: TextIO | None = None,
) -> TuneResult:
    """Choose process noise and derivative counts that minimise the prediction error.

    Position and orientation are tuned separately (thesis 9.2.1), each over the derivative
    counts in ``derivatives``; for each, Powell's method searches the log10 of the two noise
    densities (value level and highest derivative) from ``start`` (default
    :func:`default_model`). The cost is, summed over ``horizons``, the mean Huber loss of the
    prediction error divided by that of linear extrapolation; the Huber threshold is three
    times the median linear-extrapolation error, so outliers (tracking spikes, the thesis had
    to delete them by hand) count linearly instead of quadratically. The filter's own gate
    down-weights isolated outlier measurements.

    Parameters
    ----------
    t, position, quaternion : array_like, shapes (N,), (N, 3), (N, 4)
        Tuning data ``T_a_b``: times [s], positions [m], quaternions ``(x, y, z, w)``.
    horizons : sequence of float
        Horizons [s] the cost is taken at.
    derivatives : sequence of int
        Candidate derivative counts (0, 1, 2) for both parts.
    start : PredictionModel, optional
    gap_s : float, optional
        Default :func:`default_gap`.
    max_evaluations : int
        Powell evaluation budget per part and derivative count.
    progress : text stream, optional
        Where to draw a progress bar (e.g. ``sys.stderr``).

    Returns
    -------
    TuneResult
    """
    t, p, q = _as_arrays(t, position, quaternion)
    h = np.ascontiguousarray(horizons, dtype=float).reshape(-1)
    gap = default_gap(t) if gap_s is None else float(gap_s)
    model = start if start is not None else default_model(t, p, q)
    derivs = tuple(int(d) for d in derivatives)
    if not derivs or any(d not in (0, 1, 2) for d in derivs):
        raise ValueError(f"derivatives must be a non-empty subset of (0, 1, 2), got {derivatives}")
    masks, tp, tq, base_p, base_q, c_p, c_q = [], [], [], [], [], [], []
    for hs in h:
        m = scored_mask(t, hs, gap)
        if np.count_nonzero(m) < 10:
            raise ValueError(f"too few scorable samples for horizon {hs} s in the tuning data")
        ip, iq = interpolate_poses(t, p, q, t + hs)
        lp, lq = predict_linear(t, p, q, hs)
        ep = np.linalg.norm(lp[m] - ip[m], axis=1)
        eq = quat_angle(lq[m], iq[m])
        cp, cq = 3.0 * np.median(ep) + 1e-12, 3.0 * np.median(eq) + 1e-12
        masks.append(m)
        tp.append(ip[m])
        tq.append(iq[m])
        c_p.append(cp)
        c_q.append(cq)
        base_p.append(np.mean(_huber(ep, cp)) + 1e-300)
        base_q.append(np.mean(_huber(eq, cq)) + 1e-300)

    bar = _Progress(progress, total=2 * len(derivs) * max_evaluations)
    t0 = time.perf_counter()

    def cost_pos(lx, nd):
        lv = np.zeros(nd + 1)
        lv[0] += 10.0 ** lx[0]
        lv[nd] += 10.0 ** lx[1]
        pred, _ = run_predictor_position(t, p, nd, lv, model.pos_sigma, model.gate, gap, h)
        c = 0.0
        for i in range(h.size):
            e = np.linalg.norm(pred[i][masks[i]] - tp[i], axis=1)
            c += np.mean(_huber(e, c_p[i])) / base_p[i]
        c /= h.size
        bar.step(c)
        return c if np.isfinite(c) else 1e6

    def cost_ori(lx, nd):
        lv = np.zeros(nd + 1)
        lv[0] += 10.0 ** lx[0]
        lv[nd] += 10.0 ** lx[1]
        pred, _ = run_predictor_orientation(t, q, nd, lv, model.ori_sigma, model.gate, gap, h)
        c = 0.0
        for i in range(h.size):
            e = quat_angle(pred[i][masks[i]], tq[i])
            c += np.mean(_huber(e, c_q[i])) / base_q[i]
        c /= h.size
        bar.step(c)
        return c if np.isfinite(c) else 1e6

    best = {}
    for part, fun, sigma in (
        ("position", cost_pos, model.pos_sigma),
        ("orientation", cost_ori, model.ori_sigma),
    ):
        for nd in derivs:
            bar.start(f"{part} ({nd} deriv.)")
            x0 = np.log10([max(sigma, 1e-9), 30.0 if nd == 2 else (1.0 if nd == 1 else 1e-2)])
            res = minimize(
                fun, x0, args=(nd,), method="Powell", bounds=[_BOUNDS, _BOUNDS],
                options={"xtol": 1e-2, "ftol": 1e-3, "maxfev": max_evaluations},
            )  # fmt: skip
            if part not in best or res.fun < best[part][0]:
                best[part] = (float(res.fun), nd, 10.0**res.x)
    bar.close()
    (cp_, ndp, xp), (co_, ndo, xo) = best["position"], best["orientation"]
    tuned = replace(
        model, n_dp=ndp, pos_noise=float(xp[0]), pos_top_noise=float(xp[1]),
        n_do=ndo, ori_noise=float(xo[0]), ori_top_noise=float(xo[1]),
    )  # fmt: skip
    return TuneResult(tuned, cp_, co_, bar.n, time.perf_counter() - t0)


def evaluate_recording(
    t,
    position,
    quaternion,
    horizons=(0.01, 0.02, 0.05, 0.1, 0.2),
    tune_fraction: float = 0.5,
    tune_horizons=(0.05, 0.1),
    model: PredictionModel | None = None,
    progress: TextIO | None = None,
) -> PredictionReport:
    """Tune on the first part of a recording and score all predictors on the rest.

    The first ``tune_fraction`` of the duration is used by :func:`tune_model`; the prediction
    errors (:func:`evaluate_predictors`) are scored only from there on, so the figures are
    cross-validated. ``tune_fraction = 0`` skips tuning, uses ``model`` (default
    :func:`default_model`) and scores the whole recording.

    Parameters
    ----------
    t, position, quaternion : array_like, shapes (N,), (N, 3), (N, 4)
        The recording ``T_a_b`` [s, m, (x, y, z, w)].
    horizons, tune_horizons : sequence of float
        Scored and tuned horizons [s].
    tune_fraction : float in [0, 1)
    model : PredictionModel, optional
        Starting (or, without tuning, the evaluated) model.
    progress : text stream, optional

    Returns
    -------
    PredictionReport
        ``tuning`` holds the :class:`TuneResult` summary when tuning ran.
    """
    t, p, q = _as_arrays(t, position, quaternion)
    if not 0.0 <= tune_fraction < 1.0:
        raise ValueError(f"tune_fraction must be in [0, 1), got {tune_fraction}")
    gap = default_gap(t)
    if tune_fraction == 0.0:
        m = model if model is not None else default_model(t, p, q)
        return evaluate_predictors(t, p, q, m, horizons, None, gap)
    split = float(t[0] + tune_fraction * (t[-1] - t[0]))
    train = t <= split
    if np.count_nonzero(train) < 20 or np.count_nonzero(~train) < 20:
        raise ValueError(f"tune_fraction {tune_fraction} leaves too few samples on one side")
    res = tune_model(
        t[train], p[train], q[train], tune_horizons, start=model, gap_s=gap, progress=progress
    )
    report = evaluate_predictors(t, p, q, res.model, horizons, split, gap)
    report.tuning = res.as_dict()
    return report
