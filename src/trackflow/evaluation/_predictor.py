"""The PoseTool's filter predictors: derivative-model, learned-increment and partwise.

Each implements :class:`~trackflow.evaluation.Predictor` (``predict(recording, horizons)``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..errors import InputError
from ..filters import MotionModel, run_filter
from ..filters.twist_ar import TwistARModel, run_twist_ar
from ..math import UncertainPose, quat_rminus
from ._prediction import Prediction, stack_predictions
from ._trajectory import Trajectory

__all__ = [
    "KalmanPredictor",
    "PartwisePredictor",
    "TwistARPredictor",
    "default_predictor",
    "estimate_noise",
]


def _check_sigmas(settings) -> None:
    """``pos_sigma`` and ``ori_sigma`` of a predictor's settings must be finite and > 0."""
    for name in ("pos_sigma", "ori_sigma"):
        v = getattr(settings, name)
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"{name} must be finite and > 0, got {v!r}")


@dataclass(frozen=True)
class KalmanPredictor:
    """Pose Kalman filter settings that the evaluation runs and the tuning chooses.

    The filter is :func:`trackflow.filters.run_filter` with ``model`` and a constant isotropic
    measurement covariance: position error ``t_true = t + dt`` with ``dt ~ N(0, pos_sigma^2 I)``
    (frame a, metres) and orientation error ``R_true = R Exp(dtheta)`` with
    ``dtheta ~ N(0, ori_sigma^2 I)`` (body frame, radians), uncorrelated.

    Because the measurement and process noise are block-diagonal and the error-state filter's
    position and orientation dynamics do not interact, the position and orientation parts of
    the filter are independent apart from the joint outlier gate: :meth:`part` gives the
    filter of one part, which tuning runs on its own.

    Attributes
    ----------
    model : MotionModel
        Derivative counts and process noise (kind ``"white_noise"`` or ``"thesis"``).
    pos_sigma : float
        Measurement standard deviation per position axis [m].
    ori_sigma : float
        Measurement standard deviation per rotation axis of ``dtheta`` [rad].
    gate_probability : float or None
        Outlier gate of the filter (chi-square quantile of the NIS); ``None`` = no gate.
    """

    family: ClassVar[str] = "derivative"
    model: MotionModel
    pos_sigma: float
    ori_sigma: float
    gate_probability: float | None = 0.999

    def __post_init__(self):
        if not isinstance(self.model, MotionModel):
            raise InputError(f"model must be a MotionModel, got {type(self.model).__name__}")
        _check_sigmas(self)
        g = self.gate_probability
        if g is not None and not 0.0 < g <= 1.0:
            raise InputError(f"gate_probability must be in (0, 1] or None, got {g!r}")

    def measurement_covariance(self) -> np.ndarray:
        """6x6 covariance over ``(dt, dtheta)`` of one measurement, shape (6, 6)."""
        return np.diag([self.pos_sigma**2] * 3 + [self.ori_sigma**2] * 3)

    def part(self, which: str) -> KalmanPredictor:
        """The filter of one part: ``"position"`` (``n_do = -1``) or ``"orientation"``."""
        m = self.model
        npl = m.n_dp + 1 if m.n_dp >= 0 else 0
        if which == "position":
            sub = MotionModel(m.n_dp, -1, m.noise[:npl], kind=m.kind)
        elif which == "orientation":
            sub = MotionModel(-1, m.n_do, m.noise[npl:], kind=m.kind)
        else:
            raise InputError(f"part must be 'position' or 'orientation', got {which!r}")
        return KalmanPredictor(sub, self.pos_sigma, self.ori_sigma, self.gate_probability)

    def measurements(self, position, quaternion) -> UncertainPose:
        """Samples as filter input: poses with :meth:`measurement_covariance`, (N,)."""
        p = np.ascontiguousarray(position, dtype=float)
        q = np.ascontiguousarray(quaternion, dtype=float)
        c = np.broadcast_to(self.measurement_covariance(), (p.shape[0], 6, 6))
        return UncertainPose._trusted(p, q, np.ascontiguousarray(c))

    def run(self, t, measurements: UncertainPose, horizons, max_gap=None, covariance=False):
        """:func:`trackflow.filters.run_filter` with these settings (means only by default)."""
        return run_filter(
            t, measurements, self.model, horizons, gate_probability=self.gate_probability,
            covariance=covariance, max_gap=max_gap,
        )  # fmt: skip

    def predict(self, recording: Trajectory, horizons: np.ndarray) -> Prediction:
        """:meth:`run` over the recording; the filter restarts after its gaps."""
        meas = recording.measurements(self.measurement_covariance())
        res = self.run(recording.t, meas, horizons, recording.max_gap)
        per_h = {v: (res.predictions[v].position, res.predictions[v].quaternion)
                 for v in res.predictions}  # fmt: skip
        return Prediction(*stack_predictions(per_h, horizons, len(recording)),
                          int(res.stats["rejected_gate"]))  # fmt: skip

    def as_dict(self) -> dict:
        return {
            "family": self.family,
            "n_dp": self.model.n_dp,
            "n_do": self.model.n_do,
            "noise": list(self.model.noise),
            "kind": self.model.kind,
            "pos_sigma": self.pos_sigma,
            "ori_sigma": self.ori_sigma,
            "gate_probability": self.gate_probability,
        }


@dataclass(frozen=True)
class TwistARPredictor:
    """Settings of the autoregressive-twist Kalman filter (:mod:`trackflow.filters.twist_ar`).

    Attributes
    ----------
    model : TwistARModel
        Learned increment dynamics (order, step, coefficients, increment noise).
    pos_sigma : float
        Measurement standard deviation per position axis [m].
    ori_sigma : float
        Measurement standard deviation per rotation axis of ``dtheta`` [rad]
        (``R_true = R Exp(dtheta)``).
    """

    family: ClassVar[str] = "twist_ar"
    model: TwistARModel
    pos_sigma: float
    ori_sigma: float

    def __post_init__(self):
        if not isinstance(self.model, TwistARModel):
            raise InputError(f"model must be a TwistARModel, got {type(self.model).__name__}")
        _check_sigmas(self)

    def predict(self, recording: Trajectory, horizons: np.ndarray) -> Prediction:
        """:func:`~trackflow.filters.twist_ar.run_twist_ar` over the recording (restarting
        after its gaps); the learned filter has no gate."""
        r = recording
        per_h = run_twist_ar(
            r.t, r.position, r.quaternion, self.model, self.pos_sigma, self.ori_sigma, horizons,
            max_gap=r.max_gap,
        ).predictions  # fmt: skip
        return Prediction(*stack_predictions(per_h, horizons, len(r)))

    def as_dict(self) -> dict:
        return {
            "family": self.family,
            **self.model.as_dict(),
            "pos_sigma": float(self.pos_sigma),
            "ori_sigma": float(self.ori_sigma),
        }


@dataclass(frozen=True)
class PartwisePredictor:
    """Position and orientation each predicted by its own filter.

    The tuning chooses the motion model of each part separately (thesis 9.2.1 tunes them
    separately too); when the best models of the two parts differ, the prediction takes its
    position from one filter and its orientation from the other.

    Attributes
    ----------
    position, orientation : KalmanPredictor or TwistARPredictor
    """

    family: ClassVar[str] = "partwise"
    position: KalmanPredictor | TwistARPredictor
    orientation: KalmanPredictor | TwistARPredictor

    def __post_init__(self):
        for name in ("position", "orientation"):
            v = getattr(self, name)
            if not isinstance(v, (KalmanPredictor, TwistARPredictor)):
                raise InputError(
                    f"{name} must be a KalmanPredictor or TwistARPredictor, got {type(v).__name__}"
                )

    def predict(self, recording: Trajectory, horizons: np.ndarray) -> Prediction:
        """Positions from :attr:`position`'s predictions, quaternions from
        :attr:`orientation`'s (one run when both are the same filter); gated counts add."""
        pos = self.position.predict(recording, horizons)
        if self.orientation is self.position:
            return pos
        ori = self.orientation.predict(recording, horizons)
        return Prediction(pos.position, ori.quaternion, pos.n_gated + ori.n_gated)

    def as_dict(self) -> dict:
        return {
            "family": self.family,
            "kind": "partwise",
            "position": self.position.as_dict(),
            "orientation": self.orientation.as_dict(),
        }


def default_predictor(t, position, quaternion) -> KalmanPredictor:
    """Untuned starting filter: measurement noise estimated from the data, generic dynamics.

    Position: constant acceleration with white jerk of 30 m/s^3/sqrt(s); orientation: constant
    angular velocity with white angular acceleration of 30 rad/s^2/sqrt(s) (fast hand motion);
    white noise of the size of the measurement noise on both values.
    """
    ps, os_ = estimate_noise(t, position, quaternion)
    model = MotionModel(2, 1, noise=(ps, 0.0, 30.0, os_, 30.0), kind="white_noise")
    return KalmanPredictor(model, ps, os_, None)


def estimate_noise(t, position, quaternion) -> tuple[float, float]:
    """Robust measurement-noise estimate from second differences.

    For white noise of standard deviation ``s`` on smooth motion the second difference
    ``z[k+1] - 2 z[k] + z[k-1]`` has standard deviation ``sqrt(6) s``; its median absolute
    value (times 1.4826) ignores outliers and fast motion phases. Orientation uses the
    body-frame increments ``Log(q[k]^* q[k+1])``.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Times [s] (only the count is used; irregular sampling makes this a rough estimate).
    position : ndarray, shape (N, 3)
    quaternion : ndarray, shape (N, 4)

    Returns
    -------
    pos_sigma : float
        Per-axis position noise [m], at least 1e-6.
    ori_sigma : float
        Per-axis rotation noise [rad], at least 1e-6.
    """
    p = np.asarray(position, dtype=float)
    q = np.asarray(quaternion, dtype=float)
    if p.shape[0] < 4:
        raise InputError("need at least four samples to estimate the measurement noise")
    d2 = p[2:] - 2.0 * p[1:-1] + p[:-2]
    ps = 1.4826 * float(np.median(np.abs(d2))) / np.sqrt(6.0)
    inc = quat_rminus(q[1:], q[:-1])
    os_ = 1.4826 * float(np.median(np.abs(np.diff(inc, axis=0)))) / np.sqrt(6.0)
    return max(ps, 1e-6), max(os_, 1e-6)
