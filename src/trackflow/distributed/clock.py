"""Clocks of other hosts: offset estimation and the time uncertainty of remote stamps.

Agents on different hosts disagree about the time. Every agent answers clock queries
(``trackflow/<realm>/clock/<agent>``) with its clock reading; a receiver estimates the offset
by Cristian's method: it reads its clock before (``t0``) and after (``t1``) the round trip, so
the remote reading ``r`` was taken at an unknown local time in ``[t0, t1]``::

    offset = r - (t0 + t1) / 2        (remote clock = local clock + offset)
    |error| <= (t1 - t0) / 2          (uniform: sigma = rtt / (2 sqrt 3))

The round trip with the smallest ``rtt`` of a sliding window is the estimate. A remote stamp
``s`` is mapped to ``s - offset``; its time uncertainty ``sigma_t`` enters the pose covariance
to first order through the relationship's velocity (:func:`time_error_covariance`).
Zenoh's hybrid logical clock timestamps order events consistently across hosts, but they are
not tied to the sensors' exposure times, so trackflow maps stamps with this explicit estimate.
"""

from __future__ import annotations

import math
import threading
from collections import deque

import numpy as np

from ..math import quat_conjugate, quat_log, quat_multiply

__all__ = ["ClockOffset", "time_error_covariance", "twist_between"]


class ClockOffset:
    """Offset of one remote clock from the local clock, from round trips (Cristian).

    Parameters
    ----------
    window : int
        Round trips kept; the one with the smallest round-trip time gives the estimate.

    Safe to update from one thread while others read the estimate.
    """

    def __init__(self, window: int = 32):
        self._trips: deque[tuple[int, int]] = deque(maxlen=int(window))  # (rtt, offset)
        self._lock = threading.Lock()
        self._best_trip: tuple[int, int] | None = None  # read without the lock (atomic)

    def add_round_trip(self, t0_local_ns: int, remote_ns: int, t1_local_ns: int) -> None:
        """One exchange: local clock before, remote reading, local clock after [ns]."""
        rtt = int(t1_local_ns) - int(t0_local_ns)
        if rtt < 0:
            raise ValueError(f"round trip ends before it starts ({rtt} ns)")
        offset = int(remote_ns) - (int(t0_local_ns) + int(t1_local_ns)) // 2
        with self._lock:
            self._trips.append((rtt, offset))
            self._best_trip = min(self._trips)

    @property
    def known(self) -> bool:
        return self._best_trip is not None

    def _best(self) -> tuple[int, int]:
        best = self._best_trip
        if best is None:
            raise ValueError("no clock round trip yet")
        return best

    @property
    def offset_ns(self) -> int:
        """Remote clock minus local clock [ns]."""
        return self._best()[1]

    @property
    def sigma_s(self) -> float:
        """Standard deviation of the offset [s] (uniform over the best round trip)."""
        return self._best()[0] * 1e-9 / (2.0 * math.sqrt(3.0))

    def to_local(self, remote_ns: int) -> int:
        """A remote stamp on the local clock [ns]."""
        return int(remote_ns) - self.offset_ns


def twist_between(p0, q0, p1, q1, dt_s: float) -> np.ndarray:
    """Velocity ``(v, omega)`` (6,) between two poses ``T_a_b`` ``dt_s`` apart.

    ``v`` is the translation rate in frame a [m/s]; ``omega`` the rotation rate in frame b
    [rad/s] (``R1 = R0 Exp(omega dt)``), matching the error convention ``t + dt``,
    ``R Exp(dtheta)`` of ``docs/conventions.md``.
    """
    if not dt_s > 0:
        return np.zeros(6)
    v = (np.asarray(p1, float) - np.asarray(p0, float)) / dt_s
    w = quat_log(quat_multiply(quat_conjugate(np.asarray(q0, float)), np.asarray(q1, float)))
    return np.concatenate([v, np.asarray(w) / dt_s])


def time_error_covariance(twist, sigma_t_s: float) -> np.ndarray:
    """Pose covariance (6, 6) caused by a stamp error of standard deviation ``sigma_t_s``.

    A time error ``delta`` moves the pose by ``(v delta, omega delta)`` to first order, so
    ``C = sigma_t^2 xi xi^T`` with ``xi = (v, omega)`` from :func:`twist_between` (units
    m/s and rad/s; result over ``(dt [m], dtheta [rad])``).
    """
    xi = np.asarray(twist, dtype=float).reshape(6)
    return float(sigma_t_s) ** 2 * np.outer(xi, xi)
