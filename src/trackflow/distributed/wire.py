"""The wire encoding of pose measurements between agents (``docs/wire.md``).

One message is one uncertain pose ``T_a_b`` of an edge, little-endian, fixed layout::

    offset size  field
    0      2     magic b"TF"
    2      1     version (1)
    3      1     flags: bit 0 = covariance present, other bits must be 0
    4      8     sequence number, uint64 (per publisher, +1 per message)
    12     8     exposure stamp, int64 ns: the time the pose is valid at (sender's clock)
    20     8     host stamp, int64 ns: sender's clock when the message was sent
    28     8     origin stamp, int64 ns: sensor stamp of the newest raw measurement that
                 contributed (delivery latency is measured from it)
    36     24    position t_a_b, 3 x float64 [m]
    60     32    quaternion (x, y, z, w), 4 x float64, unit
    92     168   covariance upper triangle, row by row, 21 x float64 (only with flag bit 0)
                 over (dt [m, frame a], dtheta [rad, right]): t_true = t + dt,
                 R_true = R Exp(dtheta)

A message with covariance is 260 bytes, without 92. No pickle, no self-describing framing:
the key expression names the edge. Every decoding problem raises :class:`WireError` with a
short ``reason`` that receivers count (:class:`Rejections`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..math import Pose, UncertainPose

__all__ = [
    "MAGIC",
    "VERSION",
    "Rejections",
    "WireError",
    "WireSample",
    "decode",
    "encode",
]

MAGIC = b"TF"
VERSION = 1
_FLAG_COV = 0x01
_HEAD = struct.Struct("<2sBBQqqq7d")
_COV = struct.Struct("<21d")
_STAMPS = struct.Struct("<2sBBQqqq")
_IU = np.triu_indices(6)
_SYM = np.zeros((6, 6), dtype=np.intp)  # index of each entry of the 6x6 in the upper triangle
_SYM[_IU] = np.arange(21)
_SYM.T[_IU] = np.arange(21)


class WireError(ValueError):
    """A message that cannot be decoded; ``reason`` is a short counter key."""

    def __init__(self, reason: str, detail: str = ""):
        super().__init__(reason + (f": {detail}" if detail else ""))
        self.reason = reason


class WireSample(NamedTuple):
    """A decoded message.

    Parameters
    ----------
    seq : int
        Sequence number of the publisher.
    exposure_ns, host_ns, origin_ns : int
        Valid-at time, send time and origin sensor stamp [ns], on the sender's clock.
    pose : UncertainPose
        ``T_a_b`` with a 6x6 covariance over ``(dt, dtheta)`` (zeros if none was sent).
    """

    seq: int
    exposure_ns: int
    host_ns: int
    origin_ns: int
    pose: UncertainPose


def encode(
    pose: UncertainPose,
    *,
    seq: int,
    exposure_ns: int,
    host_ns: int,
    origin_ns: int | None = None,
    covariance: bool = True,
) -> bytes:
    """One message (260 bytes with covariance, 92 without); see the module docstring."""
    if pose.shape != ():
        raise ValueError("encode takes a single pose, not a batch")
    p = pose.position
    q = pose.quaternion
    head = _HEAD.pack(
        MAGIC,
        VERSION,
        _FLAG_COV if covariance else 0,
        int(seq) & 0xFFFFFFFFFFFFFFFF,
        int(exposure_ns),
        int(host_ns),
        int(exposure_ns if origin_ns is None else origin_ns),
        p[0],
        p[1],
        p[2],
        q[0],
        q[1],
        q[2],
        q[3],
    )
    if not covariance:
        return head
    return head + _COV.pack(*pose.covariance[_IU])


def decode(buf) -> WireSample:
    """Decode one message; raises :class:`WireError` (reason: ``bad magic``, ``unknown
    version``, ``unknown flags``, ``truncated``, ``wrong length``, ``non-finite``, ``non-unit
    quaternion``, ``invalid covariance``)."""
    b = bytes(buf)
    if len(b) < 4:
        raise WireError("truncated", f"{len(b)} bytes")
    if b[:2] != MAGIC:
        raise WireError("bad magic", repr(b[:2]))
    if b[2] != VERSION:
        raise WireError("unknown version", str(b[2]))
    flags = b[3]
    if flags & ~_FLAG_COV:
        raise WireError("unknown flags", f"0x{flags:02x}")
    want = _HEAD.size + (_COV.size if flags & _FLAG_COV else 0)
    if len(b) < want:
        raise WireError("truncated", f"{len(b)} of {want} bytes")
    if len(b) != want:
        raise WireError("wrong length", f"{len(b)} instead of {want} bytes")
    _, _, _, seq, exposure, host, origin = _STAMPS.unpack_from(b)
    values = np.frombuffer(b, "<f8", count=(want - _STAMPS.size) // 8, offset=_STAMPS.size)
    if not np.isfinite(values).all():
        raise WireError("non-finite")
    cov = values[7 + _SYM] if len(values) > 7 else np.zeros((6, 6))
    with np.errstate(over="ignore", invalid="ignore"):  # finite but huge garbage: rejected
        try:
            pose = Pose(values[:3], values[3:7])
        except ValueError as exc:
            raise WireError("non-unit quaternion", str(exc)) from None
        try:
            up = UncertainPose(pose, cov)
        except ValueError as exc:
            raise WireError("invalid covariance", str(exc)) from None
    return WireSample(seq, exposure, host, origin, up)


@dataclass
class Rejections:
    """Counted rejections by reason (thread-safe enough for counters updated under the GIL)."""

    counts: dict[str, int] = field(default_factory=dict)

    def add(self, reason: str) -> None:
        self.counts[reason] = self.counts.get(reason, 0) + 1

    @property
    def total(self) -> int:
        return sum(self.counts.values())
