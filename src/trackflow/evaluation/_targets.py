"""Prediction targets: the recording interpolated ``h`` after each sample, and which to score."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..math import quat_make_continuous, quat_slerp

__all__ = ["default_gap", "interpolate_poses", "scored_mask"]


def default_gap(t: np.ndarray) -> float:
    """Gap threshold [s]: three times the median sample interval of ``t`` (shape (N,), s)."""
    t = np.asarray(t, dtype=float)
    if t.shape[0] < 2:
        raise InputError("need at least two samples to find the sample interval")
    dt = np.diff(t)
    return 3.0 * float(np.median(dt))


def interpolate_poses(
    t: np.ndarray, position: np.ndarray, quaternion: np.ndarray, t_query: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The recording interpolated at ``t_query``: linear in position, slerp in orientation.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Increasing sample times [s].
    position : ndarray, shape (N, 3)
        Positions of ``T_a_b`` [m].
    quaternion : ndarray, shape (N, 4)
        Orientations of ``T_a_b`` ``(x, y, z, w)``; sign flips are allowed.
    t_query : ndarray, shape (M,)
        Query times [s]; values outside ``[t[0], t[-1]]`` are clamped to the ends.

    Returns
    -------
    position : ndarray, shape (M, 3)
    quaternion : ndarray, shape (M, 4)
    """
    t = np.asarray(t, dtype=float)
    tq = np.clip(np.asarray(t_query, dtype=float), t[0], t[-1])
    j = np.clip(np.searchsorted(t, tq, side="right") - 1, 0, t.shape[0] - 2)
    s = (tq - t[j]) / (t[j + 1] - t[j])
    p = position[j] + s[:, None] * (position[j + 1] - position[j])
    q = quat_make_continuous(quaternion)
    return p, quat_slerp(q[j], q[j + 1], s)


def scored_mask(t: np.ndarray, horizon: float, gap_s: float) -> np.ndarray:
    """Which samples have a trustworthy target ``horizon`` seconds later.

    Sample ``k`` is scored when ``t[k] + horizon <= t[-1]``, ``k > 0``, and no sample interval
    longer than ``gap_s`` lies in ``[t[k-1], t[k] + horizon]`` (interpolating across a dropout
    invents motion; extrapolating from samples across a dropout predicts from stale data).

    Returns
    -------
    ndarray of bool, shape (N,)
    """
    t = np.asarray(t, dtype=float)
    n = t.shape[0]
    gap = np.diff(t) > gap_s  # interval i is [t[i], t[i+1]]
    cum = np.concatenate([[0], np.cumsum(gap)])  # cum[i] = gaps among intervals 0..i-1
    k = np.arange(n)
    tq = t + horizon
    inside = tq <= t[-1]
    # last interval touched by [t[k], t[k] + horizon]: the one containing tq
    j = np.clip(np.searchsorted(t, tq, side="left"), 0, n - 1)  # t[j-1] < tq <= t[j]
    first = np.maximum(k - 1, 0)
    n_gaps = cum[j] - cum[first]
    return inside & (k > 0) & (n_gaps == 0)
