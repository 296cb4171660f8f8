"""Parameters of the prediction filter that the evaluation runs and tunes."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..math import quat_conjugate, quat_log, quat_multiply

__all__ = ["PredictionModel", "estimate_noise"]


@dataclass(frozen=True)
class PredictionModel:
    """Motion model and measurement noise of the evaluation's Kalman predictor.

    Position and orientation are separate derivative chains; each has white process noise on
    its value (level 0) and on its highest derivative, exactly as
    ``trackflow.filters.MotionModel(n_dp, n_do, noise=..., kind="white_noise")`` with the
    intermediate levels at 0 (see :meth:`motion_model_noise`). Measurement errors are
    ``t_true = t + dt``, ``R_true = R Exp(dtheta)`` with isotropic standard deviations.

    Attributes
    ----------
    n_dp, n_do : int
        Position / orientation derivatives (0, 1 or 2).
    pos_noise, pos_top_noise : float
        White-noise densities on position [m/sqrt(s)] and on its highest derivative
        [m/s^n_dp/sqrt(s)].
    ori_noise, ori_top_noise : float
        The same for orientation [rad/sqrt(s)], [rad/s^n_do/sqrt(s)] (body frame).
    pos_sigma : float
        Measurement standard deviation per position axis [m].
    ori_sigma : float
        Measurement standard deviation per rotation axis of ``dtheta`` [rad].
    gate : float
        Squared normalised innovation (3 DoF) above which an isolated measurement's variance
        is inflated (Huber-type weight).
    """

    n_dp: int = 2
    n_do: int = 1
    pos_noise: float = 1e-3
    pos_top_noise: float = 30.0
    ori_noise: float = 1e-3
    ori_top_noise: float = 30.0
    pos_sigma: float = 2e-4
    ori_sigma: float = 1e-3
    gate: float = 16.0

    def __post_init__(self):
        for name in ("n_dp", "n_do"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or not 0 <= v <= 2:
                raise ValueError(f"{name} must be 0, 1 or 2, got {v!r}")
        for name in ("pos_noise", "pos_top_noise", "ori_noise", "ori_top_noise"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
        for name in ("pos_sigma", "ori_sigma", "gate"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be finite and > 0, got {v!r}")

    @staticmethod
    def _levels(n: int, base: float, top: float) -> np.ndarray:
        s = np.zeros(n + 1)
        s[0] += base
        s[n] += top
        return s

    def position_levels(self) -> np.ndarray:
        """White-noise density per position level, shape (n_dp + 1,)."""
        return self._levels(self.n_dp, self.pos_noise, self.pos_top_noise)

    def orientation_levels(self) -> np.ndarray:
        """White-noise density per orientation level, shape (n_do + 1,)."""
        return self._levels(self.n_do, self.ori_noise, self.ori_top_noise)

    def motion_model_noise(self) -> tuple[float, ...]:
        """The ``noise`` argument of the equivalent ``trackflow.filters.MotionModel``."""
        return tuple(float(v) for v in np.r_[self.position_levels(), self.orientation_levels()])

    def motion_model(self):
        """The equivalent ``trackflow.filters.MotionModel`` (kind ``"white_noise"``)."""
        from ..filters import MotionModel

        return MotionModel(self.n_dp, self.n_do, self.motion_model_noise(), kind="white_noise")

    def measurement_covariance(self) -> np.ndarray:
        """6x6 covariance over ``(dt, dtheta)`` of one measurement."""
        return np.diag([self.pos_sigma**2] * 3 + [self.ori_sigma**2] * 3)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["kind"] = "white_noise"
        d["noise"] = list(self.motion_model_noise())
        return d


def estimate_noise(t, position, quaternion) -> tuple[float, float]:
    """Robust measurement-noise estimate from second differences.

    For white noise of standard deviation ``s`` on smooth motion the second difference
    ``z[k+1] - 2 z[k] + z[k-1]`` has standard deviation ``sqrt(6) s``; its median absolute
    value (times 1.4826) ignores outliers and fast motion phases.

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
        raise ValueError("need at least four samples to estimate the measurement noise")
    d2 = p[2:] - 2.0 * p[1:-1] + p[:-2]
    ps = 1.4826 * float(np.median(np.abs(d2))) / np.sqrt(6.0)
    inc = quat_log(quat_multiply(quat_conjugate(q[:-1]), q[1:]))
    os_ = 1.4826 * float(np.median(np.abs(np.diff(inc, axis=0)))) / np.sqrt(6.0)
    return max(ps, 1e-6), max(os_, 1e-6)
