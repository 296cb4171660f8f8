"""Clocks of other hosts: the time uncertainty of remote stamps in pose covariances.

Agents on different hosts disagree about the time. Every agent answers clock queries
(``trackflow/<realm>/clock/<agent>``) with its clock reading; a receiver estimates the offset
``host - remote`` from the round trips (:class:`trackflow.timesync.RoundTripOffset`, Cristian's
method) and maps a remote stamp ``s`` to ``s + offset``. The offset's time uncertainty
``sigma_t`` enters the pose covariance to first order through the relationship's velocity
(:func:`time_error_covariance`).
Zenoh's hybrid logical clock timestamps order events consistently across hosts, but they are
not tied to the sensors' exposure times, so trackflow maps stamps with this explicit estimate.
"""

from __future__ import annotations

import numpy as np

from ..math import quat_rminus

__all__ = ["time_error_covariance", "twist_between"]


def twist_between(p0, q0, p1, q1, dt_s: float) -> np.ndarray:
    """Velocity ``(v, omega)`` (6,) between two poses ``T_a_b`` ``dt_s`` apart.

    ``v`` is the translation rate in frame a [m/s]; ``omega`` the rotation rate in frame b
    [rad/s] (``R1 = R0 Exp(omega dt)``), matching the error convention ``t + dt``,
    ``R Exp(dtheta)`` of ``docs/conventions.md``.
    """
    if not dt_s > 0:
        return np.zeros(6)
    v = (np.asarray(p1, float) - np.asarray(p0, float)) / dt_s
    w = quat_rminus(np.asarray(q1, float), np.asarray(q0, float))
    return np.concatenate([v, np.asarray(w) / dt_s])


def time_error_covariance(twist, sigma_t_s: float) -> np.ndarray:
    """Pose covariance (6, 6) caused by a stamp error of standard deviation ``sigma_t_s``.

    A time error ``delta`` moves the pose by ``(v delta, omega delta)`` to first order, so
    ``C = sigma_t^2 xi xi^T`` with ``xi = (v, omega)`` from :func:`twist_between` (units
    m/s and rad/s; result over ``(dt [m], dtheta [rad])``).
    """
    xi = np.asarray(twist, dtype=float).reshape(6)
    return float(sigma_t_s) ** 2 * np.outer(xi, xi)
