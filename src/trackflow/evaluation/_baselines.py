"""The two reference predictors of thesis tables 9.2-9.5: none and linear extrapolation."""

from __future__ import annotations

import numpy as np

from ..math import quat_exp, quat_multiply, quat_rminus
from ._prediction import Prediction, stack_predictions
from ._trajectory import Trajectory

__all__ = ["LinearPredictor", "NoPredictor", "predict_none", "predict_linear"]


def predict_none(
    t: np.ndarray, position: np.ndarray, quaternion: np.ndarray, horizon: float
) -> tuple[np.ndarray, np.ndarray]:
    """No prediction: the pose at ``t[k] + horizon`` is taken to be the last measurement.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Sample times [s].
    position, quaternion : ndarray, shape (N, 3) and (N, 4)
        Measured ``T_a_b`` [m], ``(x, y, z, w)``.
    horizon : float
        Prediction horizon [s] (unused; kept so every predictor has one signature).

    Returns
    -------
    position, quaternion : ndarray, shape (N, 3) and (N, 4)
    """
    return np.array(position, dtype=float), np.array(quaternion, dtype=float)


def predict_linear(
    t: np.ndarray, position: np.ndarray, quaternion: np.ndarray, horizon: float
) -> tuple[np.ndarray, np.ndarray]:
    """Linear extrapolation from the last two samples.

    ``p(t_k + h) = p_k + (p_k - p_{k-1}) h / (t_k - t_{k-1})`` and, with the body-frame
    rotation ``d = Log(q_{k-1}^* q_k)``, ``q(t_k + h) = q_k Exp(d h / (t_k - t_{k-1}))``
    (constant angular velocity). The first sample has no predecessor and is not extrapolated.

    Parameters and returns as :func:`predict_none`.
    """
    t = np.asarray(t, dtype=float)
    p = np.array(position, dtype=float)
    q = np.array(quaternion, dtype=float)
    if t.shape[0] < 2:
        return p, q
    s = horizon / np.diff(t)
    p[1:] = position[1:] + s[:, None] * (position[1:] - position[:-1])
    d = quat_rminus(quaternion[1:], quaternion[:-1])
    q[1:] = quat_multiply(quaternion[1:], quat_exp(s[:, None] * d))
    return p, q


class _Baseline:
    """A reference predictor as a :class:`~trackflow.evaluation.Predictor`: its function at
    every horizon, stacked."""

    family: str
    _function = staticmethod(predict_none)

    def predict(self, recording: Trajectory, horizons: np.ndarray) -> Prediction:
        r = recording
        per_h = {float(h): self._function(r.t, r.position, r.quaternion, float(h))
                 for h in horizons}  # fmt: skip
        return Prediction(*stack_predictions(per_h, horizons, len(r)))

    def as_dict(self) -> dict:
        return {"family": self.family}


class NoPredictor(_Baseline):
    """No prediction (:func:`predict_none`): the last measurement."""

    family = "none"


class LinearPredictor(_Baseline):
    """Linear extrapolation from the last two samples (:func:`predict_linear`)."""

    family = "linear"
    _function = staticmethod(predict_linear)
