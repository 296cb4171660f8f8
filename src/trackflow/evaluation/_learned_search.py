"""The tuning's learned-model search: increment dynamics (:mod:`trackflow.filters.twist_ar`)
scored forward in time.

The tuning data is cut into blocks and each block after the first is predicted by a model
fitted to the blocks before it, as the evaluation predicts the future from the past (a model
that only fits the motion it saw, e.g. along one axis, loses here); a learned model is kept
per part where it beats the derivative model and is never worse than holding the last sample.
"""

from __future__ import annotations

import numpy as np

from ..filters.twist_ar import TwistARModel, excitation_ratios
from ._predictor import TwistARPredictor
from ._search import Progress
from ._trajectory import Trajectory
from ._tuning_cost import PARTS, TuningCost, part_error

__all__ = ["learned_evaluations", "search_learned"]

# couplings tried, validation blocks, measurement sigma relative to the estimated noise (that
# estimate, from second differences, mostly measures motion on smoothed recordings; the first
# scale is tried with every candidate, the others with each part's best), warm-up samples per
# order
_STRUCTURES = ("full", "isotropic")
_SPLITS = (1 / 3, 2 / 3)  # validation spans start here (fractions of the tuning duration)
_FOLDS = len(_SPLITS) + 1
_SCALES = (0.1, 1.0)
_WARMUP = 5
# smallest spread along a body axis relative to the largest (``excitation_ratios``) for which
# the full-coupling model is tried
_MIN_EXCITATION = 0.25


def learned_evaluations(n_orders: int) -> int:
    """Candidates the learned search scores at most (for the progress bar)."""
    return n_orders * len(_STRUCTURES) + 2 * (len(_SCALES) - 1)


class _ForwardValidation:
    """Blocks of the tuning data and the checks a learned candidate must pass on them."""

    def __init__(self, data: Trajectory, cost: TuningCost, check: np.ndarray):
        t = data.t
        self.data, self.cost = data, cost
        edges = t[0] + (t[-1] - t[0]) * np.array(_SPLITS)
        self.block = np.searchsorted(edges, t, side="right")  # 0: fit only; 1, 2: validated
        hold = (data.position, data.quaternion)
        self.hold_last = {float(v): hold for v in cost.horizons}  # the "none" predictor
        # horizons of the never-worse-than-holding check (besides the tuning horizons)
        self.horizons = np.unique(np.r_[cost.horizons, check]).astype(float)

    def worse_than_holding(self, part: str, preds: dict) -> list[int]:
        """Validation spans where some check horizon's RMS error exceeds holding's."""
        out = set()
        k = PARTS.index(part)
        held = (self.data.position, self.data.quaternion)[k]
        for v in self.horizons:
            pred = preds[float(v)][k]
            m, target = self.data.scored(v), self.data.target(v)[k]
            for b in range(1, _FOLDS):
                s = m & (self.block == b)
                if not np.any(s):
                    continue
                e = part_error(part, pred[s], target[s])
                e0 = part_error(part, held[s], target[s])
                if np.mean(e * e) > np.mean(e0 * e0):
                    out.add(b)
        return sorted(out)

    def scores(self, preds: dict) -> tuple[dict, dict]:
        """``({part: out-of-sample cost or inf if rejected}, {part: summary})``.

        A candidate is never worse than holding the last measurement, in any validation span
        (in the robust cost at the tuning horizons, in RMS at the check horizons): a model
        that is only better on average is not kept for that part.
        """
        costs, info = {}, {}
        blk = self.block
        for part in PARTS:
            c = float(self.cost(part, preds, blk > 0)[2])  # all out-of-sample
            worse = sorted(set(self.worse_than_holding(part, preds)) | {
                b for b in range(1, _FOLDS)
                if self.cost(part, preds, blk == b)[2]
                > self.cost(part, self.hold_last, blk == b)[2]})  # fmt: skip
            info[part] = {"cv_cost": c, "worse_than_none_in_blocks": worse}
            costs[part] = np.inf if worse else c
        return costs, info

    def predict(self, structure: str, order: int, sigmas) -> dict:
        """Each validated block predicted by a model fitted to the blocks before it:
        ``{h: (position (N, 3), quaternion (N, 4))}`` (zeros in block 0)."""
        d, blk, hc = self.data, self.block, self.horizons
        preds = {float(v): (np.zeros((len(d), 3)), np.zeros((len(d), 4))) for v in hc}
        for b in range(1, _FOLDS):
            rows = np.flatnonzero(blk == b)
            fitted = TwistARModel.fit(d.t, d.position, d.quaternion, order, dt=d.step,
                                      structure=structure, use=blk < b)  # fmt: skip
            lo = max(int(rows[0]) - _WARMUP * order, 0)
            seg = slice(lo, int(rows[-1]) + 1)
            out = TwistARPredictor(fitted, *sigmas).predict(d.select(seg), hc)
            for j, v in enumerate(hc):
                preds[float(v)][0][rows] = out.position[j][rows - lo]
                preds[float(v)][1][rows] = out.quaternion[j][rows - lo]
        return preds


def search_learned(
    data: Trajectory,
    cost: TuningCost,
    sigmas: tuple[float, float],
    orders: tuple[int, ...],
    check: np.ndarray,
    chosen: dict,
    bar: Progress,
) -> tuple[dict, dict]:
    """The learned-model search of :func:`~trackflow.evaluation.tune_model`.

    Parameters
    ----------
    sigmas : (float, float)
        Estimated measurement noise (position [m], rotation [rad]), scaled by ``_SCALES``.
    orders : tuple of int
        Orders ``L`` tried, each with the structures ``"full"`` (only when the tuning data
        excites every body axis, :func:`excitation_ratios` >= 0.25) and ``"isotropic"``.
    check : ndarray
        Horizons [s] at which a kept model is also never worse (RMS) than holding.
    chosen : dict
        ``{part: (cost, predictor)}`` of the derivative search; a part's learned model
        replaces it when its cost is lower (refitted on all the tuning data).

    Returns
    -------
    chosen : dict
        ``{part: (cost, KalmanPredictor or TwistARPredictor)}``.
    summary : dict
        ``{"excitation": {...}, "<structure> <order> @<scale>": {...}, ...}``.
    """
    val = _ForwardValidation(data, cost, check)
    ratios = excitation_ratios(data.t, data.position, data.quaternion)
    # persistent excitation: full couplings only when the tuning data moves along every body
    # axis (otherwise the full model is unidentified along the others)
    structures = _STRUCTURES if min(ratios) >= _MIN_EXCITATION else ("isotropic",)
    summary = {"excitation": {"translation": ratios[0], "rotation": ratios[1]}}

    def score(structure, order, scale):
        """Forward-validated costs of one learned candidate, or None if it cannot be fit."""
        key = f"{structure} {order} @{scale:g}"
        bar.start(f"learned {structure} ({order})")
        try:
            preds = val.predict(structure, order, (sigmas[0] * scale, sigmas[1] * scale))
        except ValueError as exc:  # too little regular data for this order
            summary[key] = {"skipped": str(exc)}
            bar.step(np.inf)
            return {}
        costs, summary[key] = val.scores(preds)
        bar.step(min(costs.values()))
        return costs

    best = {}
    for structure in structures:
        for order in orders:
            for part, c in score(structure, order, _SCALES[0]).items():
                if np.isfinite(c) and (part not in best or c < best[part][0]):
                    best[part] = (c, structure, order, _SCALES[0])
    # the measurement noise: the best candidates again with the other scales
    for structure, order in sorted({v[1:3] for v in best.values()}):
        for scale in _SCALES[1:]:
            for part, c in score(structure, order, scale).items():
                b = best.get(part)
                if b is not None and c < b[0] and b[1:3] == (structure, order):
                    best[part] = (c, structure, order, scale)
    return _refit_winners(data, sigmas, best, dict(chosen)), summary


def _refit_winners(data: Trajectory, sigmas, best: dict, chosen: dict) -> dict:
    """Per part, the learned winner (refitted on all the tuning data, once per setting)
    where its cost beats ``chosen``'s."""
    finals = {}
    for part, (c, *key) in best.items():
        if c < chosen[part][0]:
            key = tuple(key)
            if key not in finals:
                structure, order, scale = key
                m = TwistARModel.fit(data.t, data.position, data.quaternion, order,
                                     dt=data.step, structure=structure)  # fmt: skip
                finals[key] = TwistARPredictor(m, sigmas[0] * scale, sigmas[1] * scale)
            chosen[part] = (c, finals[key])
    return chosen
