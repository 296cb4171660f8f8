"""A slower tracker made from a recording: its poses, scored against the full-rate truth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..math import quat_slerp
from ._prediction import Prediction
from ._targets import default_gap, interpolate_poses, scored_mask
from ._trajectory import Trajectory

__all__ = ["TrackerTrajectory", "predict_from_last_pose", "thin_poses"]


def thin_poses(t, rate_hz: float | None) -> np.ndarray:
    """Indices of the samples a tracker at ``rate_hz`` would deliver: the first sample at or
    after each tick ``t[0] + k / rate_hz`` (all samples when ``rate_hz`` is ``None``)."""
    t = np.asarray(t, dtype=float)
    if rate_hz is None:
        return np.arange(t.shape[0])
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"pose rate must be a positive number of Hz, got {rate_hz!r}")
    ticks = t[0] + np.arange(0.0, t[-1] - t[0] + 1e-12, 1.0 / rate_hz)
    return np.unique(np.searchsorted(t, ticks - 1e-9, side="left").clip(0, t.shape[0] - 1))


@dataclass(frozen=True)
class TrackerTrajectory(Trajectory):
    """The poses a (slower) tracker delivers, scored against the full-rate recording.

    A :class:`Trajectory` whose targets are ``truth`` interpolated ``h`` after each sample
    (not the tracker's own samples), and whose scored samples also need ``truth`` to have no
    gap at the target. Tuning, shrinkage fitting and scoring all see these targets.

    Attributes
    ----------
    truth : Trajectory
        The full-rate recording.
    """

    truth: Trajectory | None = None

    @classmethod
    def thinned(cls, truth: Trajectory, rate_hz: float | None) -> TrackerTrajectory:
        """``truth`` thinned to ``rate_hz`` (:func:`thin_poses`); gap threshold the larger
        of the thinned stream's default and the truth's."""
        sel = thin_poses(truth.t, rate_hz)
        if sel.shape[0] < 4:
            raise InputError(f"only {sel.shape[0]} poses at {rate_hz} Hz")
        gap = max(default_gap(truth.t[sel]), truth.gap_s)
        return cls(truth.t[sel], truth.position[sel], truth.quaternion[sel], gap, truth=truth)

    def select(self, rows) -> TrackerTrajectory:
        return TrackerTrajectory(self.t[rows], self.position[rows], self.quaternion[rows],
                                 self.gap_s, truth=self.truth)  # fmt: skip

    def scored(self, horizon: float) -> np.ndarray:
        def make():
            tt = self.truth.t
            tq = self.t + horizon
            j = np.clip(np.searchsorted(tt, tq, side="left"), 1, tt.shape[0] - 1)
            ok = (tt[j] - tt[j - 1] <= self.truth.gap_s) & (tq <= tt[-1])
            return scored_mask(self.t, horizon, self.gap_s) & ok

        return self._cached(("scored", float(horizon)), make)

    def target(self, horizon: float) -> tuple[np.ndarray, np.ndarray]:
        tr = self.truth
        return self._cached(
            ("target", float(horizon)),
            lambda: interpolate_poses(tr.t, tr.position, tr.quaternion, self.t + horizon),
        )


def predict_from_last_pose(predictor, recording: Trajectory, k, age, horizons, step: float):
    """A pose-only predictor asked at times after its samples: from sample ``k[i]`` over
    ``horizons + age[i]``.

    The predictor runs once at the horizons ``h + j * step`` (``j = 0, 1, ..``, enough to
    cover the largest age); each answer interpolates between the two bracketing horizons
    (linear position, slerp), exact for constant-rate extrapolations.

    Parameters
    ----------
    predictor : Predictor
    recording : Trajectory
        The samples the predictor sees.
    k : ndarray of int (Q,)
        Newest sample of each query.
    age : ndarray (Q,)
        Query time minus ``t[k]`` [s], >= 0.
    horizons : ndarray (H,)
        [s] after the query time.
    step : float
        Grid spacing [s].

    Returns
    -------
    Prediction
        (H, Q, ...) arrays.
    """
    h = np.asarray(horizons, dtype=float).reshape(-1)
    n_grid = int(np.ceil(np.max(age, initial=0.0) / step)) + 2
    grid = (h[:, None] + step * np.arange(n_grid)[None, :]).reshape(-1)
    j = np.clip(np.floor(age / step).astype(int), 0, n_grid - 2)
    s = np.clip(age / step - j, 0.0, 1.0)
    g = predictor.predict(recording, grid)
    gp = g.position.reshape(h.shape[0], n_grid, len(recording), 3)
    gq = g.quaternion.reshape(h.shape[0], n_grid, len(recording), 4)
    pp = gp[:, j, k] + s[None, :, None] * (gp[:, j + 1, k] - gp[:, j, k])
    return Prediction(pp, quat_slerp(gq[:, j, k], gq[:, j + 1, k], s[None, :]), g.n_gated)
