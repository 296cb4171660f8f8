"""Prediction shrinkage: never extrapolate further than the tuning data supports.

A derivative motion model extrapolates the estimated velocity over the whole horizon. Hand
motion turns back within a fraction of a second, so 200 ms ahead a constant-velocity
extrapolation overshoots and can be worse than holding the last sample, even when the model is
the best one at the tuned horizons (50 and 100 ms). :class:`ShrunkPredictor` scales the
predicted change from the last measurement, separately for position and orientation and per
horizon:

    p = p_k + lambda_p(h) (p_pred - p_k)        R = R_k Exp(lambda_o(h) Log(R_k^T R_pred))

with ``lambda`` in ``[0, 1]`` fitted by least squares on the tuning data
(:func:`fit_shrinkage`): 0 is holding the last sample, 1 the filter's own prediction. On the
tuning data the result is therefore never worse than either of them (per horizon, in the
squared error of the change); horizons between the fitted ones interpolate ``lambda``
linearly (``lambda(0) = 1``), later ones keep the last.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..math import quat_rminus, quat_rplus
from ._prediction import Prediction, Predictor, positive_horizons
from ._trajectory import Trajectory

__all__ = [
    "ShrunkPredictor",
    "apply_shrinkage",
    "change_factors",
    "fit_shrinkage",
    "shrinkage_factors",
]


@dataclass(frozen=True)
class ShrunkPredictor:
    """A :class:`~trackflow.evaluation.Predictor` whose predicted change is scaled per part
    and horizon (module docstring).

    Attributes
    ----------
    base : Predictor
        The filter whose predictions are scaled.
    horizons : tuple of float
        Fitted horizons [s], increasing.
    position, orientation : tuple of float
        ``lambda`` per fitted horizon, each in ``[0, 1]``.
    """

    base: Predictor
    horizons: tuple
    position: tuple
    orientation: tuple

    def __post_init__(self):
        n = len(self.horizons)
        if len(self.position) != n or len(self.orientation) != n:
            raise InputError("one lambda per fitted horizon and part")
        lam = np.asarray(self.position + self.orientation, dtype=float)
        if np.any(~np.isfinite(lam)) or np.any(lam < 0) or np.any(lam > 1):
            raise InputError(f"shrinkage factors must be in [0, 1], got {lam.tolist()}")

    @property
    def family(self) -> str:
        return self.base.family

    def factors(self, horizons) -> tuple[np.ndarray, np.ndarray]:
        """``(lambda_p, lambda_o)`` for ``horizons`` [s], shape (H,) each."""
        h = np.asarray(horizons, dtype=float).reshape(-1)
        hs = np.concatenate([[0.0], self.horizons])
        lp = np.interp(h, hs, np.concatenate([[1.0], self.position]))
        lo = np.interp(h, hs, np.concatenate([[1.0], self.orientation]))
        return lp, lo

    def predict(self, recording: Trajectory, horizons: np.ndarray) -> Prediction:
        """The base predictions ``horizons`` ahead of every sample, their change from the
        sample scaled by :meth:`factors`."""
        h = np.ascontiguousarray(horizons, dtype=float).reshape(-1)
        base = self.base.predict(recording, h)
        pp, pq = apply_shrinkage(recording.position, recording.quaternion, base.position,
                                 base.quaternion, *self.factors(h))  # fmt: skip
        return Prediction(pp, pq, base.n_gated)

    def shrinkage_dict(self) -> dict:
        """The factors, JSON-ready: ``horizons_ms``, ``position``, ``orientation``."""
        return {
            "horizons_ms": [round(v * 1e3, 3) for v in self.horizons],
            "position": list(self.position),
            "orientation": list(self.orientation),
        }

    def as_dict(self) -> dict:
        return {**self.base.as_dict(), "shrinkage": self.shrinkage_dict()}


def apply_shrinkage(position, quaternion, pp, pq, lam_p, lam_o) -> tuple:
    """Scale predictions towards the samples they were made from.

    Parameters
    ----------
    position, quaternion : array_like (N, 3), (N, 4)
        The samples ``T_a_b`` [m], ``(x, y, z, w)``.
    pp, pq : array_like (H, N, 3), (H, N, 4)
        Predictions from each sample at H horizons.
    lam_p, lam_o : array_like (H,)
        Position and orientation factors per horizon.

    Returns
    -------
    position (H, N, 3), quaternion (H, N, 4)
        ``p_k + lam_p (pp - p_k)`` and ``q_k Exp(lam_o Log(q_k^* pq))`` (body frame).
    """
    pp = np.asarray(pp, dtype=float)
    pq = np.asarray(pq, dtype=float)
    p = np.asarray(position, dtype=float)
    q = np.asarray(quaternion, dtype=float)
    out_p = np.empty_like(pp)
    out_q = np.empty_like(pq)
    for i in range(pp.shape[0]):
        out_p[i] = p + lam_p[i] * (pp[i] - p)
        out_q[i] = quat_rplus(q, lam_o[i] * quat_rminus(pq[i], q))
    return out_p, out_q


def change_factors(position, quaternion, pp, pq, tp, tq, masks) -> tuple[tuple, tuple]:
    """Least-squares ``lambda`` in ``[0, 1]`` per horizon and part, for any reference poses.

    Parameters
    ----------
    position, quaternion : array_like (N, 3), (N, 4)
        The poses the predicted change is measured from (the samples, or a filter's current
        estimate).
    pp, pq : array_like (H, N, 3), (H, N, 4)
        Predictions.
    tp, tq : array_like (H, N, 3), (H, N, 4)
        Their targets.
    masks : array_like of bool (H, N)
        Rows to fit on per horizon (rows with non-finite predictions are skipped anyway).

    Returns
    -------
    (lambda_p, lambda_o) : two tuples of H floats
        ``argmin_l sum |l d - y|^2`` clipped to ``[0, 1]``, with ``d`` the predicted and ``y``
        the true change from the reference (metres; body-frame rotation vector, radians); 1
        where nothing was predicted to change.
    """
    p = np.asarray(position, dtype=float)
    q = np.asarray(quaternion, dtype=float)
    lp, lo = [], []
    for i in range(len(masks)):
        m = np.asarray(masks[i], dtype=bool) & np.all(np.isfinite(pp[i]), axis=1)
        m &= np.all(np.isfinite(pq[i]), axis=1)
        d_pos, true_pos = pp[i][m] - p[m], tp[i][m] - p[m]
        d_ori = quat_rminus(pq[i][m], q[m])
        true_ori = quat_rminus(tq[i][m], q[m])
        for d, y, out in ((d_pos, true_pos, lp), (d_ori, true_ori, lo)):
            den = float(np.sum(d * d))
            out.append(float(np.clip(np.sum(d * y) / den, 0.0, 1.0)) if den > 0 else 1.0)
    return tuple(lp), tuple(lo)


def shrinkage_factors(recording: Trajectory, prediction: Prediction, horizons) -> tuple:
    """:func:`change_factors` of predictions ``horizons`` [s] (H,) after every sample of
    ``recording``, against ``recording.target(h)`` on its scored samples."""
    r = recording
    h = np.asarray(horizons, dtype=float).reshape(-1)
    targets = [r.target(v) for v in h]
    return change_factors(
        r.position, r.quaternion, prediction.position, prediction.quaternion,
        [tg[0] for tg in targets], [tg[1] for tg in targets], [r.scored(v) for v in h],
    )  # fmt: skip


def fit_shrinkage(recording: Trajectory, predictor: Predictor, horizons) -> ShrunkPredictor:
    """Fit the factors of ``predictor`` on a (tuning) recording at ``horizons`` [s]."""
    h = np.sort(positive_horizons(horizons))
    pred = predictor.predict(recording, h)
    lp, lo = shrinkage_factors(recording, pred, h)
    return ShrunkPredictor(predictor, tuple(float(v) for v in h), lp, lo)
