"""Shared machinery of the seed papers' streaming filters: a history of estimates for past
queries, and the validation / gating / reset / counting every adapter does.

The two adapters (:class:`trackflow.filters.RelativeMotionPoseFilter`, Dorfmueller-Ulhaas;
:class:`trackflow.filters.QuaternionSpacePoseFilter`, Ude) meet the
:class:`trackflow.filters.PoseFilter` contract through :class:`GatedPoseFilter`, which gates each
pose measurement against the prediction at its time with the chi-square test on the 6-dof NIS
and re-starts after ``reset_after`` consecutive gated measurements (the policy of
:mod:`trackflow.filters.gating`, shared with every family), and counts everything in ``stats``:
``updates``, ``rejected_gate``, ``rejected_old`` (time not after the newest measurement: the
seed filters are strictly sequential, so out-of-order measurements are refused, not inserted),
``rejected_invalid`` (non-finite time, pose or covariance, or a failed update), ``resets``.

Past queries (within ``history``) interpolate the two stored estimates around ``t``
(:func:`interpolate_estimates`).

Conventions (``docs/conventions.md``): poses ``T_a_b`` with ``x_a = R x_b + t``; every covariance
given or returned is over ``(dt, dtheta)`` with ``t_true = t + dt`` (frame a) and
``R_true = R Exp(dtheta)`` (frame b, radians).
"""

from __future__ import annotations

import bisect
import math

import numpy as np

from trackflow.math import UncertainPose

from ..errors import ExtrapolationError, InputError
from . import gating
from .contract import FilterClock
from .gating import GatePolicy

__all__ = ["EstimateHistory", "GatedPoseFilter", "interpolate_estimates"]


def _valid(t: float, z: UncertainPose) -> bool:
    """Finite time, position, quaternion and covariance (the types are checked by the caller)."""
    return bool(
        math.isfinite(t)
        and np.all(np.isfinite(z.position))
        and np.all(np.isfinite(z.quaternion))
        and np.all(np.isfinite(z.covariance))
    )


def _check_pose(z) -> None:
    if not isinstance(z, UncertainPose) or z.shape != ():
        raise InputError("update_pose needs a single UncertainPose")


def interpolate_estimates(
    a: UncertainPose, b: UncertainPose, s: float, correlated: bool
) -> UncertainPose:
    """Pose between two stored estimates, ``s`` in [0, 1] (lerp of position, slerp of rotation).

    ``J_s_a``, ``J_s_b`` are the interpolation Jacobians of :meth:`UncertainPose.interpolate`
    (errors ``(dt, dtheta)``, ``t_true = t + dt``, ``R_true = R Exp(dtheta)``).

    * ``correlated=False`` (independent end points, e.g. two measurements):
      ``C = J_s_a C_a J_s_a^T + J_s_b C_b J_s_b^T``.
    * ``correlated=True`` (successive filter estimates, whose cross-covariance is not kept):
      ``C = J_s_a C_a J_s_a^T / (1 - s) + J_s_b C_b J_s_b^T / s``, an upper bound (in the PSD
      order) of the covariance of ``J_s_a e_a + J_s_b e_b`` for *any* correlation of ``e_a`` and
      ``e_b``, since ``(x + y)(x + y)^T <= (1 + k) x x^T + (1 + 1/k) y y^T`` for ``k > 0``
      (here ``k = s / (1 - s)``). At the end points it is the stored covariance.
    """
    if s <= 0.0:
        return a
    if s >= 1.0:
        return b
    out, J_s_a, J_s_b = a.interpolate(b, s, jacobians=True)
    if not correlated:
        return out
    ca = J_s_a @ a.covariance @ J_s_a.T
    cb = J_s_b @ b.covariance @ J_s_b.T
    c = ca / (1.0 - s) + cb / s
    return UncertainPose(out.pose, 0.5 * (c + c.T))


class EstimateHistory:
    """Time-ordered ``(t, UncertainPose)`` estimates covering at least ``span`` seconds."""

    def __init__(self, span: float):
        self.span = float(span)
        self.times: list[float] = []
        self.poses: list[UncertainPose] = []

    def add(self, t: float, pose: UncertainPose) -> None:
        if self.times and t == self.times[-1]:  # a second measurement at the same time
            self.poses[-1] = pose
        else:
            self.times.append(t)
            self.poses.append(pose)
        horizon = t - self.span
        n = 0  # keep one estimate at or before the horizon, so the whole window interpolates
        while n + 1 < len(self.times) and self.times[n + 1] <= horizon:
            n += 1
        if n:
            del self.times[:n]
            del self.poses[:n]

    def at(self, t: float, correlated: bool) -> UncertainPose:
        if not self.times or t < self.times[0]:
            oldest = self.times[0] if self.times else None
            raise ExtrapolationError(
                "the estimate", t, oldest, None,
                f"older than the stored history (history={self.span} s)"
            )  # fmt: skip
        i = bisect.bisect_right(self.times, t) - 1
        if i == len(self.times) - 1:
            return self.poses[i]
        t0, t1 = self.times[i], self.times[i + 1]
        return interpolate_estimates(
            self.poses[i], self.poses[i + 1], (t - t0) / (t1 - t0), correlated
        )


class GatedPoseFilter(FilterClock):
    """Validation, ordering, gating, resets and counters shared by both adapters."""

    _extra_counters: tuple[str, ...] = ()

    def __init__(self, history: float, gate_probability: float | None, reset_after: int):
        if not (math.isfinite(history) and history >= 0):
            raise InputError(f"history must be finite and >= 0 seconds, got {history}")
        self._history_s = float(history)
        self._policy = GatePolicy(gate_probability, reset_after)
        self._gate = self._policy.threshold(6)
        self.reset()

    def reset(self) -> None:
        """Forget everything: state, history and statistics."""
        self._t: float | None = None
        self._gated_run = 0
        self._hist = EstimateHistory(self._history_s)
        self._counts = dict.fromkeys(
            ("updates", "rejected_gate", "rejected_old", "rejected_invalid", "resets")
            + self._extra_counters,
            0,
        )
        self._restart()

    @property
    def stats(self) -> dict:
        """Counters (module docstring): ``updates``, ``rejected_gate``, ``rejected_old``,
        ``rejected_invalid``, ``resets`` (and adapter-specific ones)."""
        return dict(self._counts)

    def update_pose(self, t: float, measurement: UncertainPose) -> bool:
        """Integrate the pose ``T_a_b`` measured at ``t`` [s].

        ``measurement.covariance`` (6x6) is over ``(dt, dtheta)``, ``t_true = t + dt``,
        ``R_true = R Exp(dtheta)``.

        Returns
        -------
        bool
            ``True`` if integrated; ``False`` for a counted rejection (gate, not after the
            newest measurement, non-finite input or a failed update).

        Raises
        ------
        ValueError
            If ``measurement`` is not a single ``UncertainPose``.
        """
        _check_pose(measurement)
        t = float(t)
        if not _valid(t, measurement):
            self._counts["rejected_invalid"] += 1
            return False
        if self._t is not None and not self._accepts_time(t):
            self._counts["rejected_old"] += 1
            return False
        try:
            if gating.reset_due(self._t is not None, self._gated_run, self._policy.reset_after):
                if self._t is not None:
                    self._counts["resets"] += 1
                    self._hist = EstimateHistory(self._history_s)
                    self._restart()
                estimate = self._first(t, measurement)
                self._gated_run = 0
            else:
                nis = self._nis(t, measurement)
                if gating.is_gated(nis, self._gate):  # a NaN NIS is gated too
                    self._gated_run = gating.next_gated_run(gating.GATED, self._gated_run)
                    self._counts["rejected_gate"] += 1
                    return False
                estimate = self._step(t, measurement)
                self._gated_run = 0
        except (ValueError, np.linalg.LinAlgError):
            self._counts["rejected_invalid"] += 1
            return False
        self._t = t
        self._hist.add(t, estimate)
        self._counts["updates"] += 1
        return True

    def predict(self, t: float) -> UncertainPose:
        """Pose ``T_a_b`` at ``t`` [s] with its 6x6 covariance over ``(dt, dtheta)``
        (``t_true = t + dt``, ``R_true = R Exp(dtheta)``).

        ``t`` at or after :attr:`time`: the seed filter's motion-model prediction. Earlier
        ``t`` (within ``history``): interpolated between the stored estimates around it (module
        docstring).

        Raises
        ------
        ValueError
            Before the first measurement, for a non-finite ``t`` or one older than the history.
        """
        if self._t is None:
            raise InputError("the filter has no measurement yet; cannot predict")
        t = float(t)
        if not math.isfinite(t):
            raise InputError(f"prediction time must be finite, got {t}")
        if t >= self._t:
            return self._forward(t)
        return self._hist.at(t, self._correlated)

    @staticmethod
    def _innovation_nis(r: np.ndarray, S: np.ndarray) -> float:
        S = 0.5 * (S + S.T)
        return float(r @ np.linalg.solve(S, r))
