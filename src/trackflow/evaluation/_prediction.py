"""The PoseTool's predictor contract: predictions ``h`` ahead of every sample of a recording."""

from __future__ import annotations

from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np

from ..errors import InputError
from ._trajectory import Trajectory

__all__ = ["Prediction", "Predictor", "positive_horizons", "predict_kalman", "stack_predictions"]


class Prediction(NamedTuple):
    """Predictions of one predictor over a recording of N samples at H horizons.

    Attributes
    ----------
    position : ndarray, shape (H, N, 3)
        ``position[h, k]``: ``T_a_b`` position [m] predicted for ``t[k] + horizons[h]`` from
        samples ``0..k``.
    quaternion : ndarray, shape (H, N, 4)
        The predicted orientations ``(x, y, z, w)``.
    n_gated : int
        Measurements an outlier gate rejected (0 for predictors without one).
    """

    position: np.ndarray
    quaternion: np.ndarray
    n_gated: int = 0


@runtime_checkable
class Predictor(Protocol):
    """What the PoseTool evaluates: a pose predictor over a checked recording.

    ``family`` names it in reports (``as_dict()["family"]``); ``predict`` runs over the whole
    recording causally (the prediction from sample ``k`` uses samples ``0..k`` only) and
    restarts after the recording's gaps where it has a state.
    """

    family: str

    def predict(self, recording: Trajectory, horizons: np.ndarray) -> Prediction: ...

    def as_dict(self) -> dict: ...


def stack_predictions(per_horizon: dict, horizons: np.ndarray, n: int) -> tuple:
    """``{h: (position (N, 3), quaternion (N, 4))}`` -> arrays (H, N, 3), (H, N, 4) in the
    order of ``horizons`` (shape (H,); H = 0 gives empty arrays)."""
    if horizons.size == 0:
        return np.empty((0, n, 3)), np.empty((0, n, 4))
    pp = np.stack([per_horizon[float(v)][0] for v in horizons])
    pq = np.stack([per_horizon[float(v)][1] for v in horizons])
    return pp, pq


def positive_horizons(horizons, name: str = "horizons") -> np.ndarray:
    """``horizons`` as an array (H,) of seconds; ``ValueError`` unless H > 0 and all are finite
    and > 0."""
    h = np.ascontiguousarray(horizons, dtype=float).reshape(-1)
    if h.size == 0 or np.any(~np.isfinite(h)) or np.any(h <= 0):
        raise InputError(f"{name} must be positive seconds, got {h.tolist()}")
    return h


def predict_kalman(recording: Trajectory, predictor: Predictor, horizons) -> Prediction:
    """``predictor``'s predictions ``horizons`` [s] (sequence, length H) ahead of every sample.

    The filter restarts after the recording's gaps (``recording.gap_s``).

    Returns
    -------
    Prediction
        Positions (H, N, 3), quaternions (H, N, 4) and the gated-measurement count.

    Raises
    ------
    ValueError
        ``predictor`` is not a :class:`Predictor`.
    """
    if not isinstance(predictor, Predictor):
        raise InputError(f"not a predictor: {type(predictor).__name__}")
    return predictor.predict(recording, np.ascontiguousarray(horizons, dtype=float).reshape(-1))
