"""The scalar checks of a packet's layout, written once for the decoders and the compiled pass.

The plain decoders (:class:`trackflow.trackers._packet.Reader`,
:func:`trackflow.trackers.natnet.decode_frame`) and the one compiled walk over a NatNet frame
(:func:`trackflow.trackers.kernels.natnet_frame`) refuse exactly the same packets because they
ask the same functions here: whether an announced count fits the bytes left, how many bytes
an item of a NatNet frame section takes in a given version, and from which version the
sections announce their sizes. Every input accepts a pose's quaternion by the same
:func:`near_unit`.

A kernel source (:mod:`trackflow.math._backend`): plain Python on integers, numba-compatible.
NatNet versions are given as one integer, :func:`natnet_version_code`.
"""

from __future__ import annotations

KERNELS = ("count_fits", "natnet_version_code", "sized_sections", "rigid_body_bytes",
           "labeled_marker_bytes", "near_unit")  # fmt: skip
KERNEL_SOURCES = ()

#: the largest element count a packet may announce (no huge allocations)
MAX_COUNT = 100_000
#: the longest NUL-terminated name of a NatNet frame [bytes, without the NUL]
MAX_NAME_BYTES = 256
#: the fewest bytes an item of these NatNet frame sections takes (a count is refused when
#: that many do not fit): a marker set (a name's NUL and a marker count), an unlabeled
#: marker, a skeleton (id and body count), a skeleton's rigid body (before its 3.0 extras:
#: id, position, quaternion, marker count), an asset, a force plate or device (id and
#: channel count), and a channel's frame or an f32
MARKER_SET_BYTES, MARKER_BYTES, SKELETON_BYTES, SKELETON_BODY_BYTES = 5, 12, 8, 32
ASSET_BYTES, DEVICE_BYTES, CHANNEL_BYTES = 12, 8, 4


def count_fits(n, item_bytes, left, limit):
    """Whether an announced count ``n`` of items of ``item_bytes`` each is acceptable:
    ``0 <= n <= limit`` and the items fit in the ``left`` bytes after the count."""
    return 0 <= n <= limit and n * item_bytes <= left


def natnet_version_code(major, minor):
    """A NatNet version ``(major, minor)`` as one integer, ordered as the versions are:
    ``256 * major + minor`` (a minor above 255 counts as 255: no layout changes there)."""
    return 256 * major + min(minor, 255)


def sized_sections(code):
    """Whether a frame's sections announce their size in bytes after their count (4.1+)."""
    return code >= 4 * 256 + 1


def rigid_body_bytes(code):
    """Bytes of a rigid body of a frame's table: 38 from NatNet 3.0 (id, position,
    quaternion, mean error, params); before, the fewest (32: id, position, quaternion and
    a marker count, markers following)."""
    return 38 if code >= 3 * 256 else 32


def labeled_marker_bytes(code):
    """Bytes of a labeled marker: 20 (id, position, size), with params from 2.6 (+2) and
    a residual from 3.0 (+4)."""
    return 20 + (2 if code >= 2 * 256 + 6 else 0) + (4 if code >= 3 * 256 else 0)


def near_unit(n2):
    """Whether a wire quaternion of squared norm ``n2`` is taken (and normalised): within
    10 % of unit norm, ``0.81 < n2 < 1.21``; a NaN is not. Works on a float or, element by
    element, on an array of them."""
    return (0.81 < n2) & (n2 < 1.21)
