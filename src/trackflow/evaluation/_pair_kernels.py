"""Kernel source of the trajectory comparison (:mod:`trackflow.math._backend`): the sequential
scans that choose RPE pose pairs by path length or rotation angle, and the motion filter.

Each scan walks the poses once in order (or, for all pairs, once per start pose), so it is a
loop, not an array expression; written as plain Python on NumPy arrays, numba-compatible.
Angles are those of the relative rotation ``R_a^T R_b`` of two orientations, ``2 atan2(|v|,
|w|)`` of the quaternion ``q_a^* q_b = (v, w)`` (:func:`trackflow.math._lie.qbetween_into`),
in ``[0, pi]``.

The definitions are the evaluation tools' (module docstring of
:mod:`trackflow.evaluation._pairs`); where a scan compares an accumulated length with a
threshold, the length is accumulated in the same order, so the same pairs come out.
"""

from __future__ import annotations

import math

import numpy as np

from ..math._lie import qbetween_into

KERNELS = (
    "relative_angle",
    "first_at_least",
    "ids_by_path",
    "pairs_by_path_all",
    "ids_by_angle",
    "count_pairs_by_angle_all",
    "fill_pairs_by_angle_all",
    "motion_filter_ids",
)
KERNELS_INLINE = ("relative_angle", "first_at_least")
KERNEL_SOURCES = ("trackflow.math._lie",)


def relative_angle(qa, qb, tmp):
    """Angle [rad] of the rotation between unit quaternions ``qa`` and ``qb`` (4,); ``tmp``
    (4,) is scratch."""
    qbetween_into(qa, qb, tmp)
    n = math.sqrt(tmp[0] * tmp[0] + tmp[1] * tmp[1] + tmp[2] * tmp[2])
    return 2.0 * math.atan2(n, abs(tmp[3]))


def ids_by_path(p, delta):
    """Indices (M,) where the path travelled since the previous index reaches ``delta``.

    ``p`` (N, 3) positions [m], ``delta`` [m]. Index 0 first; the path is the sum of the
    straight steps between consecutive positions, restarted at 0 at every index taken.
    """
    n = p.shape[0]
    ids = np.empty(max(n, 1), np.int64)
    ids[0] = 0
    m = 1
    path = 0.0
    for k in range(1, n):
        dx = p[k, 0] - p[k - 1, 0]
        dy = p[k, 1] - p[k - 1, 1]
        dz = p[k, 2] - p[k - 1, 2]
        path += math.sqrt(dx * dx + dy * dy + dz * dz)
        if path >= delta:
            ids[m] = k
            m += 1
            path = 0.0
    return ids[:m]


def first_at_least(dist, i, lo, hi, value):
    """First ``j`` in ``[lo, hi)`` with ``dist[j] - dist[i] >= value`` (``hi`` if none);
    ``dist`` is non-decreasing, so the predicate is monotone in ``j``."""
    while lo < hi:
        mid = (lo + hi) // 2
        if dist[mid] - dist[i] >= value:
            hi = mid
        else:
            lo = mid + 1
    return lo


def pairs_by_path_all(dist, delta, tol):
    """For every start ``i``, the end ``j > i`` whose path ``dist[j] - dist[i]`` is nearest to
    ``delta`` (the first such ``j`` on a tie), kept if within ``tol``.

    ``dist`` (N,) accumulated path lengths [m] (non-decreasing, ``dist[0] = 0``). Returns
    ``(i, j)``, each (M,).
    """
    n = dist.shape[0]
    out_i = np.empty(max(n - 1, 1), np.int64)
    out_j = np.empty(max(n - 1, 1), np.int64)
    m = 0
    for i in range(n - 1):
        a = first_at_least(dist, i, i + 1, n, delta)  # first end at or beyond delta
        best = -1
        err = 0.0
        if a > i + 1:  # the last end short of delta, moved to the first of its equals
            err = abs(dist[a - 1] - dist[i] - delta)
            best = first_at_least(dist, i, i + 1, a - 1, dist[a - 1] - dist[i])
        if a < n:
            e = abs(dist[a] - dist[i] - delta)
            if best < 0 or e < err:
                best = a
                err = e
        if best >= 0 and err <= tol:
            out_i[m] = i
            out_j[m] = best
            m += 1
    return out_i[:m], out_j[:m]


def ids_by_angle(q, delta):
    """Pairs ``(i, j)`` of consecutive segments whose summed step angles reach ``delta``.

    ``q`` (N, 4) unit quaternions, ``delta`` [rad]. The angles between consecutive
    orientations are summed from the segment's start; when the sum reaches ``delta`` the
    segment ends there and the next one starts at the same pose.
    """
    n = q.shape[0]
    out_i = np.empty(max(n, 1), np.int64)
    out_j = np.empty(max(n, 1), np.int64)
    tmp = np.empty(4)
    m = 0
    start = 0
    acc = 0.0
    for k in range(n - 1):
        acc += relative_angle(q[k], q[k + 1], tmp)
        if acc >= delta:
            out_i[m] = start
            out_j[m] = k + 1
            m += 1
            acc = 0.0
            start = k + 1
    return out_i[:m], out_j[:m]


def count_pairs_by_angle_all(q, lo, hi):
    """Number of pairs ``i < j`` whose relative angle lies in ``[lo, hi]`` [rad]."""
    n = q.shape[0]
    tmp = np.empty(4)
    c = 0
    for i in range(n - 1):
        for j in range(i + 1, n):
            a = relative_angle(q[i], q[j], tmp)
            if lo <= a and a <= hi:
                c += 1
    return c


def fill_pairs_by_angle_all(q, lo, hi, out_i, out_j):
    """The pairs counted by :func:`count_pairs_by_angle_all`, in order of ``i`` then ``j``."""
    n = q.shape[0]
    tmp = np.empty(4)
    c = 0
    for i in range(n - 1):
        for j in range(i + 1, n):
            a = relative_angle(q[i], q[j], tmp)
            if lo <= a and a <= hi:
                out_i[c] = i
                out_j[c] = j
                c += 1
    return c


def motion_filter_ids(dist, q, min_dist, min_angle):
    """Indices (M,) of the poses kept by the motion filter.

    Index 0 is kept; a later pose is kept when the path since the last kept pose
    (``dist[k] - dist[last]``, ``dist`` the accumulated path [m]) reaches ``min_dist``, or else
    when its rotation from the last kept pose reaches ``min_angle`` [rad].
    """
    n = dist.shape[0]
    ids = np.empty(max(n, 1), np.int64)
    ids[0] = 0
    m = 1
    last = 0
    tmp = np.empty(4)
    for k in range(1, n):
        if dist[k] - dist[last] >= min_dist or relative_angle(q[last], q[k], tmp) >= min_angle:
            ids[m] = k
            m += 1
            last = k
    return ids[:m]
