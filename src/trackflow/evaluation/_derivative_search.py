"""The tuning's derivative-model search: process noise and derivative count per part.

The position and orientation parts of :class:`KalmanPredictor` are independent
(block-diagonal noise, see :meth:`KalmanPredictor.part`), so each is tuned on its own, with
two parameters: the log10 white-noise densities on the value (level 0) and on the highest
derivative. See :func:`trackflow.evaluation.tune_model` for the procedure.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..filters import MotionModel
from ._predictor import KalmanPredictor
from ._search import BOUNDS, Progress, grid, refine
from ._trajectory import Trajectory
from ._tuning_cost import PARTS, TuningCost

__all__ = ["GRID_SIZE", "search_derivatives"]

# coarse start grid in log10: value-level noise relative to the measurement sigma, and the
# highest-derivative noise (shifted up by half a decade per derivative above the first)
_GRID_VALUE = (-1.0, 0.5, 2.0, 3.5)
_GRID_TOP = (-1.0, 0.5, 2.0, 3.5)
GRID_SIZE = len(_GRID_VALUE) * len(_GRID_TOP)
_PRUNE = 1.25  # derivative counts whose best grid cost exceeds 1.25 x the part's best: skipped


def _pad(z) -> np.ndarray:
    """Two log10 levels; one parameter (``nd = 0``) is the value level alone."""
    z = np.asarray(z, dtype=float)
    return z if z.size == 2 else np.array([z[0], BOUNDS[0]])


def _levels(lx, nd: int) -> np.ndarray:
    """Noise densities of levels ``0..nd`` (nd + 1,): ``10**lx[0]`` on the value, ``10**lx[1]``
    on the highest derivative (added when they are the same level)."""
    v = np.zeros(nd + 1)
    v[0] += 10.0 ** lx[0]
    v[nd] += 10.0 ** lx[1]
    return v


@dataclass
class _PartSearch:
    """The filter of one part as a function of its two log10 noise levels."""

    part: str
    data: Trajectory
    base: KalmanPredictor
    cost: TuningCost
    bar: Progress

    def costs(self, lx, nd: int) -> np.ndarray:
        """Search, held-out and all-data costs (3,) of the part's filter with ``nd``
        derivatives and levels ``lx`` (2,); no gate, so the cost stays smooth."""
        kind = self.base.model.kind
        if self.part == "position":
            model = MotionModel(nd, -1, _levels(lx, nd), kind=kind)
        else:
            model = MotionModel(-1, nd, _levels(lx, nd), kind=kind)
        b = self.base
        res = KalmanPredictor(model, b.pos_sigma, b.ori_sigma, None).predict(
            self.data, self.cost.horizons
        )
        costs = self.cost(self.part, {float(v): (res.position[i], res.quaternion[i])
                                      for i, v in enumerate(self.cost.horizons)})  # fmt: skip
        self.bar.step(costs[0])
        return costs

    def objective(self, nd: int, which: int):
        """``z -> costs(z, nd)[which]`` over one or two log10 parameters."""
        return lambda z: self.costs(_pad(z), nd)[which]

    def grids(self, counts) -> dict:
        """The coarse grid of every derivative count: ``{nd: (objective, points, values)}``."""
        sigma = self.base.pos_sigma if self.part == "position" else self.base.ori_sigma
        ls = np.log10(max(sigma, 1e-9))
        out = {}
        for nd in counts:
            self.bar.start(f"{self.part} ({nd} deriv., grid)")
            if nd == 0:  # one level: one parameter (a random walk of the value)
                starts = [(ls + g,) for g in _GRID_VALUE]
            else:
                top = [g + 0.5 * (nd - 1) for g in _GRID_TOP]
                starts = [(ls + g, b) for g in _GRID_VALUE for b in top]
            f = self.objective(nd, 0)
            out[nd] = (f, *grid(f, starts))
        return out

    def choose(self, grids: dict, opts: dict) -> tuple[tuple, dict]:
        """Refine the counts not far behind on the grid; the best ``(cost, nd, levels)`` by
        the mean of search and held-out cost, and the summary of every count."""
        summary, best = {}, None
        floor = min(float(np.min(g[2])) for g in grids.values())
        for nd, (f, pts, values) in grids.items():
            if np.min(values) > _PRUNE * floor:  # far behind on the grid: not refined
                x = _pad(pts[int(np.argmin(values))])
                summary[str(nd)] = {"search_cost": float(np.min(values)), "pruned": True,
                                    "noise": _levels(x, nd).tolist()}  # fmt: skip
                continue
            self.bar.start(f"{self.part} ({nd} deriv.)")
            x = _pad(refine(f, pts, values, opts))
            c_search, c_hold, _ = self.costs(x, nd)
            # the tail alone is short and noisy: choose on the mean of both costs
            chosen = 0.5 * (c_search + c_hold) if self.cost.n_hold >= 10 else c_search
            summary[str(nd)] = {"search_cost": float(c_search), "holdout_cost": float(c_hold),
                                "noise": _levels(x, nd).tolist()}  # fmt: skip
            if best is None or chosen < best[0]:
                best = (float(chosen), nd, x)
        return best, summary

    def refine_on_all(self, nd: int, x: np.ndarray, opts: dict, budget: int) -> np.ndarray:
        """The chosen count's levels refined locally (+-1 decade) on all the tuning data (the
        held-out tail is the most recent motion, so it should shape the final noise too)."""
        from scipy.optimize import minimize  # ~0.4 s: only when searching

        self.bar.start(f"{self.part} ({nd} deriv., all)")
        f = self.objective(nd, 2)
        z0 = x if nd > 0 else x[:1]
        box = list(zip(np.maximum(z0 - 1.0, BOUNDS[0]), np.minimum(z0 + 1.0, BOUNDS[1])))
        res = minimize(f, z0, method="Powell", bounds=box, options={**opts, "maxfev": budget})
        return _pad(res.x) if float(res.fun) < f(z0) else x


def search_derivatives(
    data: Trajectory,
    cost: TuningCost,
    base: KalmanPredictor,
    counts: dict,
    max_evaluations: int,
    bar: Progress,
) -> tuple[KalmanPredictor, dict, dict]:
    """The derivative-model search of :func:`~trackflow.evaluation.tune_model`.

    Parameters
    ----------
    counts : dict
        ``{"position": (n_dp, ...), "orientation": (n_do, ...)}`` candidate derivative counts.
    max_evaluations : int
        Powell evaluation budget per start (half of it for the final refinement).

    Returns
    -------
    tuned : KalmanPredictor
        Both parts' best counts and noise, ``base``'s measurement noise and gate.
    cost : dict
        ``{part: cost}`` of the chosen count (mean of search and held-out cost).
    summary : dict
        ``{part: {str(nd): {...}}}``: every count's costs and noise.
    """
    opts = {"xtol": 0.1, "ftol": 2e-3, "maxfev": max_evaluations}
    best, summary = {}, {}
    for part in PARTS:
        search = _PartSearch(part, data, base, cost, bar)
        (chosen, nd, x), summary[part] = search.choose(search.grids(counts[part]), opts)
        x = search.refine_on_all(nd, x, opts, max(max_evaluations // 2, 1))
        best[part] = (chosen, nd, _levels(x, nd))
    (cp, ndp, vp), (co, ndo, vo) = best["position"], best["orientation"]
    model = MotionModel(ndp, ndo, np.r_[vp, vo], kind=base.model.kind)
    tuned = KalmanPredictor(model, base.pos_sigma, base.ori_sigma, base.gate_probability)
    return tuned, {"position": cp, "orientation": co}, summary
