"""Marker blobs in infrared images: threshold, connected components, sub-pixel centroids.

One pass over the image finds runs of pixels at or above the threshold, joins runs that touch
(8-connectivity) with a union-find, and accumulates each component's intensity moments, so no
label image is allocated. The centroid is intensity weighted with the background removed,
``sum (I - b) (x, y) / sum (I - b)``, in OpenCV's pixel convention (pixel centres at integer
coordinates). The loops are kernels of the backend seam (:func:`trackflow.math.kernels_for`):
compiled with numba when it is installed, plain Python (slow, for tests and small images)
without it.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..math import kernels_for

__all__ = ["Blobs", "detect_blobs"]

KERNELS = ("_find", "_bright_chunks", "_bright_chunks_u8", "_runs_and_moments", "_components")
KERNEL_SOURCES = ()
KERNEL_OPTIONS = {"nogil": True}


@dataclass
class Blobs:
    """Blobs of one image.

    Attributes
    ----------
    uv : ndarray (K, 2)
        Intensity-weighted centroids [px].
    area : ndarray (K,) of int
        Pixels at or above the threshold.
    flux : ndarray (K,)
        Sum of ``I - background`` over the blob.
    """

    uv: np.ndarray
    area: np.ndarray
    flux: np.ndarray

    def __len__(self) -> int:
        return len(self.uv)


def _find(parent, i):
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


_CHUNK = 16


def _bright_chunks(img, thr):
    """(H, ceil(W / 16)) flags: does the chunk hold a pixel >= thr (a branch-free pass that
    the compiler vectorises; the exact scan then visits flagged chunks only)."""
    H, W = img.shape
    n = (W + _CHUNK - 1) // _CHUNK
    out = np.zeros((H, n), np.bool_)
    full = W // _CHUNK
    for y in range(H):
        for k in range(full):
            acc = False
            for i in range(k * _CHUNK, (k + 1) * _CHUNK):
                acc |= img[y, i] >= thr
            out[y, k] = acc
        if full < n:
            acc = False
            for i in range(full * _CHUNK, W):
                acc |= img[y, i] >= thr
            out[y, full] = acc
    return out


_LOW7 = np.uint64(0x7F7F7F7F7F7F7F7F)
_HIGH = np.uint64(0x8080808080808080)
_ONES = np.uint64(0x0101010101010101)


def _bright_chunks_u8(words, thr):
    """:func:`_bright_chunks` for 8-bit images read as 64-bit words (8 pixels at a time, two
    words per chunk): a byte ``b >= thr`` sets its high bit in ``(b & 0x7f) + (128 - thr)``
    (no carry between bytes) or has it set already (``thr <= 128``); for ``thr > 128`` the
    byte's own high bit and ``(b & 0x7f) + (256 - thr)`` must both have it."""
    H, n = words.shape[0], words.shape[1] // 2
    out = np.zeros((H, n), np.bool_)
    if thr <= 128:
        add = np.uint64(128 - thr) * _ONES
        for y in range(H):
            for k in range(n):
                a = words[y, 2 * k]
                b = words[y, 2 * k + 1]
                t = (((a & _LOW7) + add) | a) | (((b & _LOW7) + add) | b)
                out[y, k] = (t & _HIGH) != 0
    else:
        add = np.uint64(256 - thr) * _ONES
        for y in range(H):
            for k in range(n):
                a = words[y, 2 * k]
                b = words[y, 2 * k + 1]
                t = (((a & _LOW7) + add) & a) | (((b & _LOW7) + add) & b)
                out[y, k] = (t & _HIGH) != 0
    return out


def _runs_and_moments(img, flags, thr, bg, max_runs):
    H, W = img.shape
    # a run starts in a flagged chunk, at most 8 per 16 pixels: allocate only that much
    cap = min(max_runs, 8 * int(flags.sum()) + 1)
    r_row = np.empty(cap, np.int32)
    r_start = np.empty(cap, np.int32)
    r_end = np.empty(cap, np.int32)  # inclusive
    parent = np.empty(cap, np.int64)
    s0 = np.empty(cap)
    sx = np.empty(cap)
    sy = np.empty(cap)
    cnt = np.empty(cap, np.int64)
    n = 0
    prev_lo = 0  # runs of the previous row: [prev_lo, prev_hi)
    prev_hi = 0
    for y in range(H):
        row_lo = n
        x = 0
        while x < W:
            if not flags[y, x // _CHUNK]:
                x = (x // _CHUNK + 1) * _CHUNK
                continue
            if img[y, x] >= thr:
                x0 = x
                a = 0.0
                ax = 0.0
                while x < W and img[y, x] >= thr:
                    w = img[y, x] - bg
                    a += w
                    ax += w * x
                    x += 1
                if n == cap:
                    return -1, r_row, parent, s0, sx, sy, cnt
                r_row[n] = y
                r_start[n] = x0
                r_end[n] = x - 1
                parent[n] = n
                s0[n] = a
                sx[n] = ax
                sy[n] = a * y
                cnt[n] = x - x0
                # join with touching runs of the previous row (8-connectivity)
                for j in range(prev_lo, prev_hi):
                    if r_end[j] >= x0 - 1 and r_start[j] <= x:
                        ra = _find(parent, j)
                        rb = _find(parent, n)
                        if ra != rb:
                            if ra < rb:
                                parent[rb] = ra
                            else:
                                parent[ra] = rb
                n += 1
            else:
                x += 1
        prev_lo = row_lo
        prev_hi = n
    return n, r_row, parent, s0, sx, sy, cnt


def _components(n, parent, s0, sx, sy, cnt):
    label = np.full(n, -1, np.int64)
    k = 0
    for i in range(n):
        r = _find(parent, i)
        if label[r] < 0:
            label[r] = k
            k += 1
        label[i] = label[r]
    a = np.zeros(k)
    ax = np.zeros(k)
    ay = np.zeros(k)
    c = np.zeros(k, np.int64)
    for i in range(n):
        j = label[i]
        a[j] += s0[i]
        ax[j] += sx[i]
        ay[j] += sy[i]
        c[j] += cnt[i]
    return a, ax, ay, c


def detect_blobs(
    image,
    threshold: float,
    background: float = 0.0,
    min_area: int = 1,
    max_area: int = 10000,
    max_runs: int = 200000,
) -> Blobs:
    """Bright blobs of an infrared image.

    Parameters
    ----------
    image : array_like (H, W)
        Grey image (uint8, uint16 or float).
    threshold : float
        Pixels ``>= threshold`` belong to blobs.
    background : float
        Level subtracted before weighting (the dark level of the image); below ``threshold``.
    min_area, max_area : int
        Blobs with fewer or more pixels are dropped (noise, lamps, large reflections).
    max_runs : int
        Safety bound on the runs of bright pixels (an overexposed frame raises instead of
        taking unbounded time and memory).

    Returns
    -------
    Blobs
    """
    img = np.asarray(image)
    if img.ndim != 2:
        raise InputError(f"image must be 2-D (H, W), got shape {img.shape}")
    if img.dtype.kind not in "uif":
        raise InputError(f"image must be numeric, got {img.dtype}")
    if not background < threshold:
        raise InputError(f"background ({background}) must be below threshold ({threshold})")
    if not np.isfinite(threshold):
        raise InputError("threshold must be finite")
    if (
        img.dtype.kind in "ui"
        and not np.iinfo(img.dtype).min < threshold <= np.iinfo(img.dtype).max
    ):
        raise InputError(f"threshold {threshold} is outside the range of {img.dtype} images")
    if not img.flags.c_contiguous:
        img = np.ascontiguousarray(img)
    thr = img.dtype.type(np.ceil(threshold)) if img.dtype.kind in "ui" else threshold
    k = kernels_for(sys.modules[__name__])
    if img.dtype == np.uint8 and img.shape[1] % _CHUNK == 0:
        flags = k._bright_chunks_u8(img.view(np.uint64), int(thr))
    else:
        flags = k._bright_chunks(img, thr)
    n, _, parent, s0, sx, sy, cnt = k._runs_and_moments(
        img, flags, thr, float(background), int(max_runs)
    )
    if n < 0:
        raise InputError(f"more than {max_runs} runs of bright pixels: overexposed image?")
    a, ax, ay, c = k._components(n, parent, s0, sx, sy, cnt)
    keep = (c >= min_area) & (c <= max_area) & (a > 0)
    a, ax, ay, c = a[keep], ax[keep], ay[keep], c[keep]
    uv = np.stack([ax / a, ay / a], axis=1) if len(a) else np.zeros((0, 2))
    return Blobs(uv, c, a)
