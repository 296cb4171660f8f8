"""Learned gyro extrapolation: the rotation over the next ``h`` seconds from the gyro history.

Holding the last angular velocity predicts ``Exp(omega h)``; hand and head motion turns back
within a fraction of a second, so the best linear predictor of the rotation ahead weighs the
recent history. :func:`fit_gyro_extrapolation` fits, for each horizon ``h``, lag weights
``c_j(h)`` (shared by the three axes) so that, with the angular velocity in a world frame
``omega_w = R_w_s omega``,

    integral of omega_w over [t_k, t_k + h]  ~  sum_j c_j(h) omega_w,{k-j}

by ridge least squares on the IMU's own samples (the target is the integrated future gyro: no
tracker or truth is needed). The filter applies it to bias-corrected samples (:mod:`.kernel`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from trackflow.math._lie import so3_exp

from ...errors import InputError

__all__ = ["GyroExtrapolation", "fit_gyro_extrapolation"]


@dataclass(frozen=True)
class GyroExtrapolation:
    """Lag weights per horizon.

    Attributes
    ----------
    horizons : ndarray (H,)
        Increasing horizons [s] the weights were fitted for.
    coef : ndarray (H, L) or (H, 3 L)
        ``coef[i, j]`` multiplies the sample ``j`` steps back [s] (newest first), the same for
        the three axes; with ``per_axis`` fits ``coef[i, 3 j + a]`` is the weight of axis
        ``a``.
    """

    horizons: np.ndarray
    coef: np.ndarray

    def __post_init__(self):
        h = np.asarray(self.horizons, dtype=float).reshape(-1)
        c = np.asarray(self.coef, dtype=float)
        if c.ndim != 2 or c.shape[0] != h.shape[0] or h.shape[0] == 0:
            raise InputError(f"coef must be (H, L) for H = {h.shape[0]} horizons, got {c.shape}")
        if np.any(np.diff(h) <= 0) or np.any(h <= 0) or not np.all(np.isfinite(c)):
            raise InputError("horizons must be positive and increasing, weights finite")
        object.__setattr__(self, "horizons", h)
        object.__setattr__(self, "coef", np.ascontiguousarray(c))

    @property
    def lags(self) -> int:
        """Columns of ``coef`` (lags, or 3 x lags for per-axis weights)."""
        return int(self.coef.shape[1])

    def for_horizons(self, horizons) -> np.ndarray:
        """Weights (H', L) for other horizons: linear in ``h`` between fits, 0 at ``h = 0``,
        scaled linearly beyond the last fitted horizon."""
        hq = np.asarray(horizons, dtype=float).reshape(-1)
        hs = np.concatenate([[0.0], self.horizons])
        cs = np.concatenate([np.zeros((1, self.lags)), self.coef])
        out = np.empty((hq.shape[0], self.lags))
        for i, v in enumerate(hq):
            if v >= hs[-1]:
                out[i] = cs[-1] * (v / hs[-1])
            else:
                out[i] = [np.interp(v, hs, cs[:, j]) for j in range(self.lags)]
        return out

    def as_dict(self) -> dict:
        return {"horizons": self.horizons.tolist(), "coef": self.coef.tolist()}


def _world_rates(t, w):
    """``R_k omega_k`` with ``R_k`` the gyro integrated from the identity (any start will do:
    the fitted weights are the same in every world frame)."""
    out = np.empty_like(w)
    r = np.eye(3)
    dt = np.diff(t, prepend=t[0])
    for k in range(w.shape[0]):
        r = r @ so3_exp(w[k] * dt[k])
        out[k] = r @ w[k]
    return out


def fit_gyro_extrapolation(
    imu_t,
    gyro,
    horizons,
    lags: int = 16,
    ridge: float = 1e-4,
    integrals: int = 1,
    per_axis: bool | None = None,
) -> GyroExtrapolation:
    """Fit lag weights predicting the integrated gyro ``h`` ahead (module docstring).

    With ``integrals=2`` the same fit predicts the double integral
    ``int_0^h (h - s) a(t_k + s) ds`` of a world acceleration ``a`` (the position change
    beyond ``v h``), for the accelerometer's extrapolation.

    Parameters
    ----------
    imu_t : array_like (M,)
        Increasing sample times [s] (regular sampling assumed for the lags).
    gyro : array_like (M, 3)
        Angular velocity [rad/s].
    horizons : sequence of float
        Horizons [s].
    lags : int
        History length in samples.
    ridge : float
        Tikhonov weight relative to the mean diagonal of the normal matrix.
    integrals : {1, 2}
    per_axis : bool, optional
        One weight per lag and world axis (gyro; the filter expects this, the default for
        ``integrals=1``) or shared by the axes (the default for ``integrals=2``).
    """
    if per_axis is None:
        per_axis = integrals == 1
    t = np.asarray(imu_t, dtype=float).reshape(-1)
    w = np.asarray(gyro, dtype=float).reshape(-1, 3)
    h = np.sort(np.asarray(horizons, dtype=float).reshape(-1))
    if lags < 1:
        raise InputError(f"lags must be >= 1, got {lags}")
    if t.shape[0] < 10 * lags + 100:
        raise InputError(f"{t.shape[0]} IMU samples are too few to fit {lags} lags")
    w = w - np.median(w, axis=0)  # constant offsets (bias) are not motion
    if integrals == 1:  # angular velocity into a world frame: integrate the gyro itself
        w = _world_rates(t, w)
    if integrals not in (1, 2):
        raise InputError(f"integrals must be 1 or 2, got {integrals}")

    def integral(v):
        steps = 0.5 * (v[1:] + v[:-1]) * np.diff(t)[:, None]
        return np.concatenate([np.zeros((1, 3)), np.cumsum(steps, 0)])

    cum = integral(w)
    cum2 = integral(cum) if integrals == 2 else None
    k = np.arange(lags - 1, t.shape[0])
    X = np.stack([w[k - j] for j in range(lags)], axis=-1)  # (K, 3, L)
    coef = np.empty((h.shape[0], 3 * lags if per_axis else lags))

    def solve(A, b):
        N = A.T @ A
        N += np.eye(A.shape[1]) * ridge * np.trace(N) / A.shape[1]
        return np.linalg.solve(N, A.T @ b)

    for i, hv in enumerate(h):
        ok = t[k] + hv <= t[-1]
        kk = k[ok]
        if cum2 is None:
            y = np.stack([np.interp(t[kk] + hv, t, cum[:, a]) for a in range(3)], 1) - cum[kk]
        else:
            ahead = np.stack([np.interp(t[kk] + hv, t, cum2[:, a]) for a in range(3)], 1)
            y = ahead - cum2[kk] - cum[kk] * hv
        if per_axis:
            for a in range(3):
                coef[i, a::3] = solve(X[ok][:, a, :], y[:, a])
        else:
            coef[i] = solve(X[ok].reshape(-1, lags), y.reshape(-1))
    return GyroExtrapolation(h, coef)
