"""Kernel source of :mod:`trackflow.timesync` (:mod:`trackflow.math._backend`): the lower
envelope of a clock mapping, refitted while a packet waits for its answer.

Plain Python on NumPy arrays, numba-compatible (explicit loops, float64 arrays).
"""

from __future__ import annotations

import numpy as np

KERNELS = ("lower_envelope", "envelope_fit")
KERNEL_SOURCES = ()


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
    """The clock mapping's line over per-bin minima: returns ``(a, b, sigma, scatter)``.

    The slope ``b`` is the lower envelope's (:func:`lower_envelope`, once the bins span
    ``min_span_ns``; clipped to ``max_drift``). With that slope: the line below every bin,
    and the line through the lowest bin of the last ``anchor_ns``; the recent one, unless it
    sits more than three times the bins' median height plus ``stall_ns`` above the other
    (every recent packet late: a stall). ``a`` is the line's height at the newest bin,
    ``sigma`` the median height of the recent bins above it, ``scatter`` the height of the
    second lowest bin above the line that anchors it (the gap between the two smallest
    delays, the standard deviation of the smallest one; 0 with one bin).

    Parameters
    ----------
    tx : ndarray (n,) int
        Tracker times of the bins' minima [ns], increasing, ``n >= 1``.
    y : ndarray (n,)
        Their ``host - remote`` offsets [ns].
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
    stalled = a > a_full + 3.0 * typical + stall_ns  # every recent packet late (a stall)
    if stalled:
        a = a_full
    res = np.sort(recent[:m] - a)
    gaps = np.sort(heights - a) if stalled else res
    scatter = gaps[1] if gaps.shape[0] > 1 else 0.0
    return a, b, max(res[m // 2], 0.0), max(scatter, 0.0)
