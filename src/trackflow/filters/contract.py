"""The contracts every pose filter family meets: status codes, the streaming protocol and the
measurement plug-in.

* :class:`FilterStatus`: what happened to one measurement (one code set for every family and
  both drivers, the streaming filter and the offline loop).
* :class:`PoseFilter`: the streaming interface the dataflow relies on (``update_pose`` /
  ``predict`` / ``time`` / ``initialized`` / ``stats``).
* :class:`MeasurementFunction`: a user-defined measurement of the pose, ``z = h(T_a_b) + v``, given
  as a function with its Jacobian; any filter with a pose in its state accepts it
  (:meth:`trackflow.filters.PoseKalmanFilter.update_measurement`, thesis 7.3.2).

Conventions (docs/conventions.md): poses ``T_a_b`` with 6x6 covariance over ``(dt, dtheta)``,
``t_true = t + dt`` (frame a, metres), ``R_true = R Exp(dtheta)`` (radians).
"""

from __future__ import annotations

import enum
from typing import Protocol, runtime_checkable

import numpy as np

from trackflow.math import Pose, UncertainPose

__all__ = ["STATS_KEYS", "FilterClock", "FilterStatus", "MeasurementFunction", "PoseFilter"]


class FilterStatus(enum.IntEnum):
    """Outcome of one measurement (the values are the int8 codes of offline results)."""

    ACCEPTED = 0  #: integrated
    GATED = 1  #: rejected by the innovation gate (state untouched)
    DIVERGED = 2  #: singular innovation covariance or non-finite state: filter re-initialised
    INVALID = 3  #: non-finite input, skipped
    INITIALIZED = 4  #: first measurement (or first after a gap): state set from it
    RESET = 5  #: re-initialised after ``reset_after`` consecutive gated measurements


#: Counters every family reports in ``stats`` (families may add their own).
STATS_KEYS = ("updates", "rejected_gate", "resets")


@runtime_checkable
class PoseFilter(Protocol):
    """Streaming filter of one spatial relationship ``T_a_b(t)``, times in seconds.

    ``update_pose`` integrates a measured pose and returns ``False`` for a counted rejection;
    ``predict(t)`` answers the pose with its covariance at any time within the filter's reach
    (prediction ahead of :attr:`time`, interpolation or smoothing behind it).
    """

    @property
    def initialized(self) -> bool: ...

    @property
    def time(self) -> float | None: ...

    @property
    def stats(self) -> dict: ...

    def update_pose(self, t: float, measurement: UncertainPose) -> bool: ...

    def predict(self, t: float) -> UncertainPose: ...

    def reset(self) -> None: ...


@runtime_checkable
class MeasurementFunction(Protocol):
    """A measurement of the pose: ``z = h(T_a_b) + v``, ``v ~ N(0, R)``.

    ``residual(T)`` returns the innovation ``y = z - h(T)`` (shape (m,)) and ``J_h_pose``
    (m, 6), the Jacobian of ``h`` with respect to the pose error ``e = (dt, dtheta)`` of the
    convention (``t_true = t + dt`` in frame a, ``R_true = R Exp(dtheta)``):
    ``h(T [+] e) ~ h(T) + J_h_pose e``, i.e. the measurement matrix ``H`` restricted to the pose.
    ``covariance`` is ``R`` (m, m). :func:`trackflow.filters.numerical_jacobian` checks
    ``J_h_pose`` against finite differences.
    """

    @property
    def covariance(self) -> np.ndarray: ...

    def residual(self, pose: Pose) -> tuple[np.ndarray, np.ndarray]: ...


class FilterClock:
    """The ``initialized`` / ``time`` part of :class:`PoseFilter` for filters keeping the time
    of their newest integrated measurement in ``self._t`` (``None`` before the first)."""

    _t: float | None = None

    @property
    def initialized(self) -> bool:
        """Whether at least one measurement has been integrated."""
        return self._t is not None

    @property
    def time(self) -> float | None:
        """Time [s] of the newest integrated measurement, ``None`` before the first."""
        return self._t
