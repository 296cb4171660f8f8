"""A remote sensor's advertised covariance checked against its measured innovations.

A sensor's agent publishes its filter's state after every measurement (``docs/wire.md``);
the consumer's replica (:class:`~trackflow.distributed.replica.RemoteFilter`) adopts them.
A well-formed state can still claim a covariance far below what the sensor delivers (a
hostile peer, or a real sensor configured with a noise 100 times too small): every answer
built on it would then be overconfident. The states themselves show it:

* The replica predicts the previous state ``(x_0, P_0)`` to the new state's time with the
  sensor's own motion model (the one the replica answers queries with):
  ``x_pred, P_pred``. For a consistent Kalman filter the correction
  ``d = x_new [-] x_pred`` (the filter's error-state coordinates, ``docs/conventions.md``)
  is zero-mean with covariance ``S = P_pred - P_new`` (the information the measurements
  since the previous state added; positive semidefinite for a Kalman update). This holds
  across any number of updates between two received states, so lost messages and thinned
  streams are judged as well.
* The check uses the pose block (position and orientation, the levels a pose measurement
  reaches): ``s = d' S^+ d`` is chi-square with ``dof = rank(S)`` degrees of freedom (6 for
  a pose, 0 for a state that only predicted: a gated measurement). ``S`` is normalised by
  ``diag(P_pred)`` and its eigen-directions below :data:`RANK_TOL` are dropped (roundoff);
  directions where ``P_new`` exceeds ``P_pred`` by more than that are counted
  (``covariance above its prediction``) and left out.
* Over the last :data:`WINDOW` states the sum of ``s`` is chi-square with the sum of the
  dofs ``D``: the window's mean ratio ``m = sum(s) / D`` is 1 for an honest filter. The
  sensor is flagged while ``m`` exceeds the threshold ``max(chi2.isf(FALSE_ALARM, D) / D,
  RATIO_FLOOR)``: the quantile bounds false alarms where the window is short (its first
  states), the floor says what "far below" means (a factor 2 in covariance, 1.41 in sigma:
  a real filter's model is only approximately right, and mild inconsistency is not what
  this is for).
* A flagged sensor is not refused (a faulty but real sensor must keep answering): the
  replica adopts its states with the covariance scaled by ``m`` (bounded by
  :data:`MAX_SCALE`), each counted as ``covariance below its innovations``. The check
  itself always runs on the advertised states (no feedback of the scale), so the scale
  goes back to 1 once the window's mean is below the threshold again.

A scalar scale assumes the lie is the same in every direction (the measurement noise
scaled); a sensor lying in one direction only is scaled by the mean over all six.
"""

from __future__ import annotations

import collections
import math
from functools import lru_cache

import numpy as np

from ..filters.derivative.motion_kernels import predict_scratch
from ..filters.derivative.streaming import FilterSnapshot
from ..math import kernels_for
from . import kernels as _kernels

__all__ = [
    "FALSE_ALARM",
    "MAX_SCALE",
    "RATIO_FLOOR",
    "WINDOW",
    "InnovationCheck",
    "correction_statistic",
    "threshold",
]

#: states in the running window of the statistic
WINDOW = 32
#: probability that an honest filter's window mean exceeds the threshold, per state
FALSE_ALARM = 1e-9
#: smallest window mean ratio flagged: "far below" is a covariance at least 2x too small
RATIO_FLOOR = 2.0
#: largest scale applied to an adopted covariance (sigma 100x)
MAX_SCALE = 1e4
#: eigenvalues of the normalised S below this (relative to P_pred's diagonal) are roundoff
RANK_TOL = 1e-9


@lru_cache(maxsize=1024)
def threshold(dof: int) -> float:
    """The window mean ratio above which a window of ``dof`` degrees of freedom in all is
    flagged: ``max(chi2.isf(FALSE_ALARM, dof) / dof, RATIO_FLOOR)``."""
    from scipy.stats import chi2

    return max(float(chi2.isf(FALSE_ALARM, dof)) / dof, RATIO_FLOOR)


def correction_statistic(d, p_pred, p_new) -> tuple[float, int, bool]:
    """``d' S^+ d`` with ``S = p_pred - p_new`` over the kept directions.

    Parameters
    ----------
    d : ndarray (k,)
        The correction ``x_new [-] x_pred`` in the filter's covariance coordinates (units of
        the state: m, rad, ...).
    p_pred, p_new : ndarray (k, k)
        The predicted and the new state's covariance over the same coordinates.

    Returns
    -------
    statistic : float
        ``d' S^+ d`` (chi-square with ``dof`` degrees of freedom for a consistent filter);
        ``nan`` when ``S`` is not finite.
    dof : int
        The directions kept: eigenvalues of ``N S N`` above :data:`RANK_TOL`, ``N =
        diag(P_pred)^(-1/2)``.
    above : bool
        ``P_new`` exceeds ``P_pred`` in some direction by more than :data:`RANK_TOL`.
    """
    scale = np.sqrt(np.maximum(np.diagonal(p_pred), 1e-300))
    s = (p_pred - p_new) / np.outer(scale, scale)
    if not math.isfinite(float(s.sum())):
        return math.nan, 0, False
    return _eigen_statistic(np.asarray(d) / scale, s)


def _eigen_statistic(dn, s) -> tuple[float, int, bool]:
    """:func:`correction_statistic` of the normalised correction ``dn`` and ``S``."""
    w, v = np.linalg.eigh(0.5 * (s + s.T))
    keep = w > RANK_TOL
    above = bool(w[0] < -RANK_TOL)
    if not keep.any():
        return 0.0, 0, above
    proj = v[:, keep].T @ dn
    return float(np.sum(proj * proj / w[keep])), int(keep.sum()), above


class InnovationCheck:
    """The running check of one remote sensor's advertised states (module docstring).

    Parameters
    ----------
    model : MotionModel
        The sensor filter's motion model (from its agent's fragment; the replica's).
    formulation : {"error_state", "additive"}
    window : int
        States in the running window.

    Attributes
    ----------
    scale : float
        The factor the replica applies to the covariance it adopts (1: not flagged).
    counts : dict
        ``checked`` (states with a statistic), ``scaled`` (adopted with ``scale > 1``),
        ``above`` (``P_new`` above ``P_pred`` somewhere), ``degenerate`` (a state that moved
        although its covariance claims nothing was learned, or not finite).
    """

    def __init__(self, model, formulation: str = "error_state", window: int = WINDOW):
        self.params = model.kernel_params(formulation)
        n_dp, n_do, add = self.params[:3]
        idx = list(range(3)) if n_dp >= 0 else []
        if n_do >= 0:
            o = 3 * (n_dp + 1)
            idx += list(range(o, o + (4 if add else 3)))
        self._pose = np.array(idx)
        self._kern = kernels_for(_kernels)
        self._ws = predict_scratch(n_dp, n_do, add)
        k = len(idx)
        self._out = np.empty(k + 1 + k * k + k)
        self._window: collections.deque = collections.deque(maxlen=int(window))
        self._sum = 0.0
        self._dof = 0
        self._prev: FilterSnapshot | None = None
        self.scale = 1.0
        self.counts = {"checked": 0, "scaled": 0, "above": 0, "degenerate": 0}

    @property
    def mean_ratio(self) -> float:
        """The window's ``sum(s) / sum(dof)`` (1 for an honest filter; nan while empty)."""
        return self._sum / self._dof if self._dof else math.nan

    @property
    def flagged(self) -> bool:
        return self.scale > 1.0

    def check(self, snap: FilterSnapshot) -> float:
        """Judge the new state ``snap`` (time in s, on the replica's clock) against the
        previous one; returns the scale for its covariance (1 unless flagged). A state older
        than the previous is ignored (the replica refuses it); one at the same time replaces
        it (the sensor re-filtered); a segment start (reset) is not judged."""
        prev = self._prev
        if prev is not None and snap.t < prev.t:
            return self.scale
        self._prev = snap
        if prev is None or snap.segment_start or snap.t == prev.t:
            return self.scale
        i, k, out = self._pose, len(self._pose), self._out
        x1 = np.asarray(snap.x, dtype=float)
        p1 = np.asarray(snap.p, dtype=float)
        if self._kern.correction_chol(
            prev.x, prev.p, snap.t - prev.t, x1, p1, *self.params, i, self._ws, out
        ):
            stat, dof, above = float(out[k]), k, False
        elif math.isnan(out[k]):
            stat, dof, above = math.nan, 0, False
        else:  # S near singular or indefinite: its kept directions only
            stat, dof, above = _eigen_statistic(
                out[:k].copy(), out[k + 1 : k + 1 + k * k].reshape(k, k)
            )
        dn = out[:k]
        if above:
            self.counts["above"] += 1
        if not math.isfinite(stat) or (dof == 0 and bool((np.abs(dn) > 1e-6).any())):
            self.counts["degenerate"] += 1  # moved without learning anything: no verdict
            return self.scale
        if dof == 0:
            return self.scale  # a predicted state (gated measurement): nothing to judge
        self.counts["checked"] += 1
        w = self._window
        if len(w) == w.maxlen:
            s0, k0 = w[0]
            self._sum -= s0
            self._dof -= k0
        w.append((stat, dof))
        self._sum += stat
        self._dof += dof
        if self.counts["checked"] % w.maxlen == 0:  # no drift of the running sum
            self._sum = math.fsum(s for s, _ in w)
        m = self.mean_ratio
        self.scale = min(m, MAX_SCALE) if m > threshold(self._dof) else 1.0
        if self.scale > 1.0:
            self.counts["scaled"] += 1
        return self.scale

    def status(self) -> dict:
        """``scale``, the window's ``mean_ratio`` and the counts, for an agent's status."""
        m = self.mean_ratio
        return {"scale": self.scale, "mean_ratio": None if math.isnan(m) else m, **self.counts}
