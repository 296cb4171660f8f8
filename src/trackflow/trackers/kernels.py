"""Kernel source of the trackers package (:mod:`trackflow.math._backend`): the checks and
arithmetic that turn a packet's rigid-body rows into a block of samples in one pass, so a
packet costs no Python object per body.

Plain Python on NumPy arrays, numba-compatible (explicit loops, float64 arrays).
"""

from __future__ import annotations

import math

KERNELS = ("block_poses",)
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
