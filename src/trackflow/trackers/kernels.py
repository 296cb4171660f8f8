"""Kernel source of the trackers package (:mod:`trackflow.math._backend`): the checks and
arithmetic that turn a packet's rigid-body rows into a block of samples in one pass, so a
packet costs no Python object per body, and the lower envelope of the clock mapping, refitted
while a packet waits for its answer.

Plain Python on NumPy arrays, numba-compatible (explicit loops, float64 arrays).
"""

from __future__ import annotations

import math

import numpy as np

KERNELS = ("block_poses", "lower_envelope", "envelope_fit")
KERNEL_SOURCES = ()


def block_poses(v, params, rows, scales, lo, hi, pos, quat):
    """Positions and unit quaternions of rigid-body rows when every one is plainly valid.

    Row ``k`` of the result is table row ``rows[k]``. It is plainly valid when it is tracked
    (``params & 1``), its position is finite (also summed, and after the unit scale), its
    quaternion has a norm within 10 % of 1 (``0.81 < |q|^2 < 1.21``) and its mean marker error
    times the unit scale lies in ``[lo[k], hi[k]]``. The arithmetic is that of
    :meth:`trackflow.trackers.inputs.LiveInput._sample`, so the results are the same bits:
    ``p = scale * position``, ``q = q / sqrt(|q|^2)``.

    Parameters
    ----------
    v : ndarray (n, 8)
        The table's numbers: position (3) [wire unit], quaternion ``(x, y, z, w)`` (4), mean
        marker error [wire unit].
    params : ndarray (n,) int
        The rows' flags (bit 0: tracked).
    rows : ndarray (m,) int
        Table row of each body.
    scales, lo, hi : ndarray (m,)
        Per body: unit scale to metres and the bounds of its scaled mean marker error.
    pos : ndarray (m, 3), quat : ndarray (m, 4)
        Written: positions [m] and unit quaternions.

    Returns
    -------
    bool
        ``False`` as soon as one row is not plainly valid (``pos`` and ``quat`` are then
        partly written).
    """
    for k in range(rows.shape[0]):
        r = rows[k]
        if params[r] & 1 == 0:
            return False
        x, y, z = v[r, 0], v[r, 1], v[r, 2]
        if not math.isfinite(x + y + z):
            return False
        q0, q1, q2, q3 = v[r, 3], v[r, 4], v[r, 5], v[r, 6]
        n2 = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3
        if not (0.81 < n2 and n2 < 1.21):
            return False
        s = scales[k]
        e = v[r, 7] * s
        if not (lo[k] <= e and e <= hi[k]):
            return False
        px, py, pz = x * s, y * s, z * s
        if not math.isfinite(px + py + pz):
            return False
        n = math.sqrt(n2)
        pos[k, 0], pos[k, 1], pos[k, 2] = px, py, pz
        quat[k, 0], quat[k, 1], quat[k, 2], quat[k, 3] = q0 / n, q1 / n, q2 / n, q3 / n
    return True


def lower_envelope(x, y):
    """``(a, b)`` of the line ``a + b (x - mean(x))`` below every point ``(x[i], y[i])`` with
    the largest sum: the edge of the lower convex hull (monotone chain) above the mean of
    ``x``. ``x`` (n,) increasing, ``y`` (n,), ``n >= 1``; one point (or all at one ``x``): the
    lowest, ``b = 0``."""
    n = x.shape[0]
    xm = 0.0
    ymin = y[0]
    for i in range(n):
        xm += x[i]
        if y[i] < ymin:
            ymin = y[i]
    xm /= n
    if n == 1 or x[n - 1] == x[0]:
        return ymin, 0.0
    hull = np.empty(n, np.int64)
    h = 0
    for i in range(n):
        while h >= 2:
            o, p = hull[h - 2], hull[h - 1]
            if (x[p] - x[o]) * (y[i] - y[o]) - (y[p] - y[o]) * (x[i] - x[o]) <= 0.0:
                h -= 1
            else:
                break
        hull[h] = i
        h += 1
    for k in range(h - 1):
        i, j = hull[k], hull[k + 1]
        if x[i] <= xm and xm <= x[j] and x[j] > x[i]:
            b = (y[j] - y[i]) / (x[j] - x[i])
            return y[i] + b * (xm - x[i]), b
    return ymin, 0.0  # xm lies within [x0, xn]: not reached


def envelope_fit(tx, y, min_span_ns, max_drift, anchor_ns, stall_ns):
    """The clock mapping's line over per-bin minima: returns ``(a, b, sigma)``.

    The slope ``b`` is the lower envelope's (:func:`lower_envelope`, once the bins span
    ``min_span_ns``; clipped to ``max_drift``). With that slope: the line below every bin,
    and the line through the lowest bin of the last ``anchor_ns``; the recent one, unless it
    sits more than three times the bins' median height plus ``stall_ns`` above the other
    (every recent packet late: a stall). ``a`` is the line's height at the newest bin,
    ``sigma`` the median height of the recent bins above it.

    Parameters
    ----------
    tx : ndarray (n,) int
        Tracker times of the bins' minima [ns], increasing, ``n >= 1``.
    y : ndarray (n,)
        Their ``host - tracker`` offsets [ns].
    """
    n = tx.shape[0]
    ref = tx[0]
    b = 0.0
    if tx[n - 1] - ref >= min_span_ns:
        x = np.empty(n)
        for i in range(n):
            x[i] = (tx[i] - ref) * 1e-9  # seconds: a well-conditioned slope
        b = lower_envelope(x, y)[1]
        b = max(-max_drift * 1e9, min(max_drift * 1e9, b)) * 1e-9
    ref_ns = tx[n - 1]
    heights = np.empty(n)
    recent = np.empty(n)
    m = 0
    for i in range(n):
        heights[i] = y[i] - b * (tx[i] - ref_ns)
        if ref_ns - tx[i] <= anchor_ns:
            recent[m] = heights[i]
            m += 1
    a_full = heights.min()
    a = recent[:m].min()
    typical = np.sort(heights)[n // 2] - a_full
    if a > a_full + 3.0 * typical + stall_ns:  # every recent packet late (a stall)
        a = a_full
    res = np.sort(recent[:m] - a)
    return a, b, max(res[m // 2], 0.0)
