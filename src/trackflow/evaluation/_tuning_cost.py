"""The tuning's robust prediction cost, relative to linear extrapolation, per part."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..math import quat_angle
from ._baselines import predict_linear
from ._search import huber
from ._trajectory import Trajectory

__all__ = ["PARTS", "TuningCost", "part_error"]

PARTS = ("position", "orientation")


def part_error(part: str, predicted: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Errors of one part, shape (M,): position distance [m] (both (M, 3)) or rotation angle
    [rad] (quaternions, both (M, 4))."""
    if part == "position":
        return np.linalg.norm(predicted - target, axis=1)
    return quat_angle(predicted, target)


class TuningCost:
    """Search, held-out and all-data costs of predictions on the tuning data.

    The cost of one part is, averaged over ``horizons``, the mean Huber loss of the prediction
    error divided by that of linear extrapolation on the same samples; the Huber threshold is
    three times the median linear-extrapolation error on the search samples. The search
    samples are the scored ones before the held-out tail (the last ``holdout`` of the
    duration).

    Parameters
    ----------
    data : Trajectory
        The tuning data.
    horizons : ndarray, shape (H,)
        Positive horizons [s].
    holdout : float in [0, 0.5]

    Raises
    ------
    ValueError
        Fewer than 10 scorable search samples at some horizon.
    """

    def __init__(self, data: Trajectory, horizons: np.ndarray, holdout: float):
        t, p, q = data.t, data.position, data.quaternion
        self.horizons = horizons
        t_hold = float(t[0] + (1.0 - holdout) * (t[-1] - t[0])) if holdout > 0 else np.inf
        # per part and horizon: (search, hold, all masks), target, Huber threshold, linear
        # extrapolation's cost per set and its errors
        self.targets: dict[str, list] = {part: [] for part in PARTS}
        for hs in horizons:
            m = data.scored(hs)
            search, hold = m & (t < t_hold), m & (t >= t_hold)
            if np.count_nonzero(search) < 10:
                raise InputError(f"too few scorable samples for horizon {hs} s in the tuning data")
            ip, iq = data.target(hs)
            lp, lq = predict_linear(t, p, q, hs)
            for part, lin_pred, tgt in zip(PARTS, (lp, lq), (ip, iq)):
                err = part_error(part, lin_pred, tgt)
                c = 3.0 * float(np.median(err[search])) + 1e-12
                sets = (search, hold, search | hold)
                lin = [np.mean(huber(err[s], c)) + 1e-300 if np.any(s) else np.nan
                       for s in sets]  # fmt: skip
                self.targets[part].append((sets, tgt, c, lin, err))
        #: scored held-out samples (the fewest over the horizons)
        self.n_hold = min(int(np.count_nonzero(tg[0][1])) for tg in self.targets["position"])

    def __call__(self, part: str, preds: dict, only: np.ndarray | None = None) -> np.ndarray:
        """Search, held-out and all-data costs (3,) of one part from ``{h: (pos, quat)}``.

        ``only`` (bool mask) restricts every set to those samples (normalised by linear
        extrapolation on the same samples). Sets without samples cost 0; non-finite costs
        become 1e6.
        """
        costs = np.zeros(3)  # search, held-out, all tuning data
        k = PARTS.index(part)
        for i, (sets, tgt, c, lin, lin_err) in enumerate(self.targets[part]):
            pred = preds[float(self.horizons[i])][k]
            for j, s in enumerate(sets):
                norm = lin[j]
                if only is not None:
                    s = s & only
                    norm = np.mean(huber(lin_err[s], c)) + 1e-300 if np.any(s) else np.nan
                if not np.any(s):
                    continue
                e = part_error(part, pred[s], tgt[s])
                costs[j] += np.mean(huber(e, c)) / norm
        costs /= self.horizons.size
        costs[~np.isfinite(costs)] = 1e6
        return costs
