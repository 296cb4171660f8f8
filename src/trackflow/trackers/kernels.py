"""Kernel source of the trackers package (:mod:`trackflow.math._backend`): the checks and
arithmetic that turn a packet's rigid-body rows into a block of samples in one pass, so a
packet costs no Python object per body; the walk over a whole NatNet frame that finds its
rigid-body table and clock ticks and makes that block in the same call.

Plain Python on NumPy arrays, numba-compatible (explicit loops, float64 arrays).
"""

from __future__ import annotations

import math

import numpy as np

from .wire_checks import (
    ASSET_BYTES,
    CHANNEL_BYTES,
    DEVICE_BYTES,
    MARKER_BYTES,
    MARKER_SET_BYTES,
    MAX_COUNT,
    MAX_NAME_BYTES,
    SKELETON_BODY_BYTES,
    SKELETON_BYTES,
    count_fits,
    labeled_marker_bytes,
    near_unit,
    rigid_body_bytes,
    sized_sections,
)

KERNELS = ("pose_row", "block_poses", "natnet_frame", "_i32", "_u32", "_count", "_section_end")

#: :func:`natnet_frame`'s answers: the block is made; the frame decodes (as
#: :func:`trackflow.trackers.natnet.decode_frame` would) but makes no block with the plan;
#: ask ``decode_frame`` (an error, or a layout this pass does not take); the frame decodes
#: but its rigid-body ids are not the plan's
FRAME_BLOCK, FRAME_DECODED, FRAME_SLOW, FRAME_NEW_IDS = 0, 1, 2, 3
KERNEL_SOURCES = ("trackflow.trackers.wire_checks",)


def pose_row(x, y, z, q0, q1, q2, q3, err, s, lo, hi, pos, quat, k):
    """Row ``k`` of a block from one rigid body's numbers, when it is plainly valid.

    Plainly valid: a finite position (also summed, and after the unit scale ``s``), a
    quaternion of norm within 10 % of 1 (:func:`~trackflow.trackers.wire_checks.near_unit`)
    and a mean marker error ``err`` [wire unit] whose scaled value lies in ``[lo, hi]``. The
    arithmetic is that of :meth:`trackflow.trackers.live_input.LiveInput._sample`, so the
    results are the same bits:
    ``p = s * position``, ``q = q / sqrt(|q|^2)``, written to ``pos[k]`` and ``quat[k]``.
    Returns ``False`` (nothing written) when the body is not plainly valid.
    """
    if not math.isfinite(x + y + z):
        return False
    n2 = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3
    if not near_unit(n2):
        return False
    e = err * s
    if not (lo <= e and e <= hi):
        return False
    px, py, pz = x * s, y * s, z * s
    if not math.isfinite(px + py + pz):
        return False
    n = math.sqrt(n2)
    pos[k, 0], pos[k, 1], pos[k, 2] = px, py, pz
    quat[k, 0], quat[k, 1], quat[k, 2], quat[k, 3] = q0 / n, q1 / n, q2 / n, q3 / n
    return True


def block_poses(v, params, rows, scales, lo, hi, pos, quat):
    """Positions and unit quaternions of rigid-body rows when every one is plainly valid.

    Row ``k`` of the result is table row ``rows[k]``. It is plainly valid when it is tracked
    (``params & 1``) and :func:`pose_row` takes it.

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
        if not pose_row(v[r, 0], v[r, 1], v[r, 2], v[r, 3], v[r, 4], v[r, 5], v[r, 6],
                        v[r, 7], scales[k], lo[k], hi[k], pos, quat, k):  # fmt: skip
            return False
    return True


def _i32(buf, o):
    """The little-endian i32 at byte ``o`` of ``buf`` (uint8)."""
    return int(buf[o : o + 4].view(np.int32)[0])


def _u32(buf, o):
    return int(buf[o : o + 4].view(np.uint32)[0])


def _count(buf, p, end, item):
    """:meth:`trackflow.trackers._packet.Reader.count` at ``p``: the count, or -1 where the
    reader raises (truncated, or refused by :func:`~trackflow.trackers.wire_checks.count_fits`)."""
    if p + 4 > end:
        return -1
    n = _i32(buf, p)
    if not count_fits(n, item, end - p - 4, MAX_COUNT):
        return -1
    return n


def _section_end(buf, p, end, item, sized, out):
    """A frame section's head at ``p`` as ``natnet._section`` reads it: ``out[0]`` the
    count, ``out[1]`` its announced size in bytes (``sized``: NatNet 4.1); returns the
    position after the head, or -1 where the decoder raises."""
    n = _count(buf, p, end, item)
    if n < 0:
        return -1
    p += 4
    out[0] = n
    if sized:
        if p + 4 > end:
            return -1
        size = _u32(buf, p)
        p += 4
        if p + size > end:
            return -1
        out[1] = size
    return p


def natnet_frame(buf, version, ids, rows, bounds, want, pos, quat, out):
    """One pass over a NatNet datagram: a frame of mocap data's rigid-body table, frame
    number and clock ticks, and the plan's block of samples from it.

    The walk checks what :func:`trackflow.trackers.natnet.decode_message` and
    :func:`~trackflow.trackers.natnet.decode_frame` check (sizes, counts, strings, the 4.1
    section sizes) and answers :data:`FRAME_SLOW` wherever they would raise, for NatNet
    before 3.0, for another message than FRAMEOFDATA and for a marker set name that is not
    ASCII: the caller then asks ``decode_frame``, which raises the counted reason or decodes.

    Parameters
    ----------
    buf : ndarray (nbytes,) uint8
        The datagram, header included.
    version : int
        ``256 * major + minor`` of the server's NatNet version.
    ids : ndarray (n,) int64
        The rigid-body ids the plan was made for (the table's, in order).
    rows, bounds : ndarray (m,) int64, ndarray (3, m)
        Per body of the plan: its table row; its unit scale and the bounds of its scaled mean
        marker error (:func:`block_poses`).
    want : int
        0: no block (there is no plan): answer :data:`FRAME_DECODED` for a frame that decodes.
    pos : ndarray (m, 3), quat : ndarray (m, 4)
        Written: the block's positions [m] and unit quaternions (:func:`pose_row`).
    out : ndarray (5,) uint64
        Written when the frame decodes: frame number (its i32 bits), mid-exposure and
        transmit ticks, byte offset of the rigid-body table in ``buf`` and its row count.

    Returns
    -------
    int
        :data:`FRAME_BLOCK` (every body of the plan is tracked and plainly valid),
        :data:`FRAME_DECODED`, :data:`FRAME_NEW_IDS` or :data:`FRAME_SLOW`.
    """
    nbytes = buf.shape[0]
    if version < 3 * 256 or version > 4 * 256 + 1 or nbytes < 4 or nbytes > 65507:
        return FRAME_SLOW
    if int(buf[0]) + 256 * int(buf[1]) != 7:  # FRAMEOFDATA
        return FRAME_SLOW
    end = 4 + int(buf[2]) + 256 * int(buf[3])
    if end > nbytes:
        return FRAME_SLOW
    sized = sized_sections(version)
    head = np.zeros(2, np.int64)
    if end < 8:
        return FRAME_SLOW
    p = 8  # after the frame number
    # marker sets: a name (NUL-terminated, at most 256 bytes) and positions each
    p = _section_end(buf, p, end, MARKER_SET_BYTES, sized, head)
    if p < 0:
        return FRAME_SLOW
    start = p
    for _ in range(head[0]):
        stop = min(end, p + MAX_NAME_BYTES + 1)
        k = -1
        for j in range(p, stop):
            c = buf[j]
            if c == 0:
                k = j
                break
            if c >= 128:
                return FRAME_SLOW  # not ASCII: UTF-8 is for decode_frame to judge
        if k < 0:
            return FRAME_SLOW
        nm = _count(buf, k + 1, end, MARKER_BYTES)
        if nm < 0:
            return FRAME_SLOW
        p = k + 5 + MARKER_BYTES * nm
    if sized and p - start != head[1]:
        return FRAME_SLOW
    # legacy unlabeled markers (a 4.1 size is read, not checked)
    p = _section_end(buf, p, end, MARKER_BYTES, sized, head)
    if p < 0 or p + MARKER_BYTES * head[0] > end:
        return FRAME_SLOW
    p += MARKER_BYTES * head[0]
    # rigid bodies: the table
    rb = rigid_body_bytes(version)
    p = _section_end(buf, p, end, rb, sized, head)
    n = head[0]
    if p < 0 or p + rb * n > end or (sized and head[1] != rb * n):
        return FRAME_SLOW
    table = p
    p += rb * n
    # skeletons: an id and rigid bodies each
    p = _section_end(buf, p, end, SKELETON_BYTES, sized, head)
    if p < 0:
        return FRAME_SLOW
    start = p
    for _ in range(head[0]):
        nb = _count(buf, p + 4, end, SKELETON_BODY_BYTES)
        if p + 4 > end or nb < 0:
            return FRAME_SLOW
        p += 8
        for _ in range(nb):
            if p + rb > end:
                return FRAME_SLOW
            p += rb
    if sized and p - start != head[1]:
        return FRAME_SLOW
    if sized:  # assets: skipped by size
        p = _section_end(buf, p, end, ASSET_BYTES, sized, head)
        if p < 0:
            return FRAME_SLOW
        p += head[1]
    # labeled markers: 26 bytes each from 3.0
    lab = labeled_marker_bytes(version)
    p = _section_end(buf, p, end, lab, sized, head)
    if p < 0 or (sized and head[1] != lab * head[0]) or p + lab * head[0] > end:
        return FRAME_SLOW
    p += lab * head[0]
    # force plates, devices: an id and channels of counted f32 each
    for _ in range(2):
        p = _section_end(buf, p, end, DEVICE_BYTES, sized, head)
        if p < 0:
            return FRAME_SLOW
        start = p
        for _ in range(head[0]):
            nch = _count(buf, p + 4, end, CHANNEL_BYTES)
            if p + 4 > end or nch < 0:
                return FRAME_SLOW
            p += 8
            for _ in range(nch):
                nf = _count(buf, p, end, CHANNEL_BYTES)
                if nf < 0:
                    return FRAME_SLOW
                p += 4 + 4 * nf
        if sized and p - start != head[1]:
            return FRAME_SLOW
    # suffix: timecode (8), timestamp (8), ticks (3 x 8), 4.1 precision stamp (8), params (2)
    if p + (50 if sized else 42) > end:
        return FRAME_SLOW
    out[0] = buf[4:8].view(np.uint32)[0]
    out[1] = buf[p + 16 : p + 24].view(np.uint64)[0]
    out[2] = buf[p + 32 : p + 40].view(np.uint64)[0]
    out[3] = table
    out[4] = n
    if want == 0:
        return FRAME_DECODED
    if n != ids.shape[0]:
        return FRAME_NEW_IDS
    # the table's words as two arrays each (rows are 38 bytes: their words alternate
    # between two alignments), so reading a row makes no array view of its own
    a0, a2 = table % 4, (table + 2) % 4
    i0 = buf[a0 : a0 + (end - a0) // 4 * 4].view(np.int32)
    i2 = buf[a2 : a2 + (end - a2) // 4 * 4].view(np.int32)
    f0 = buf[a0 : a0 + (end - a0) // 4 * 4].view(np.float32)
    f2 = buf[a2 : a2 + (end - a2) // 4 * 4].view(np.float32)
    for r in range(n):
        o = table + 38 * r
        w = i0[(o - a0) // 4] if r % 2 == 0 else i2[(o - a2) // 4]
        if w != ids[r]:
            return FRAME_NEW_IDS
    for k in range(rows.shape[0]):
        o = table + 38 * rows[k]
        if buf[o + 36] & 1 == 0:  # params (i16, little-endian): bit 0 = tracked
            return FRAME_DECODED
        f, j = (f0, (o + 4 - a0) // 4) if rows[k] % 2 == 0 else (f2, (o + 4 - a2) // 4)
        if not pose_row(np.float64(f[j]), np.float64(f[j + 1]), np.float64(f[j + 2]),
                        np.float64(f[j + 3]), np.float64(f[j + 4]), np.float64(f[j + 5]),
                        np.float64(f[j + 6]), np.float64(f[j + 7]), bounds[0, k],
                        bounds[1, k], bounds[2, k], pos, quat, k):  # fmt: skip
            return FRAME_DECODED
    return FRAME_BLOCK
