"""The wire encoding of pose measurements between agents (``docs/wire.md``).

One message is one uncertain pose ``T_a_b`` of an edge, little-endian, fixed layout::

    offset size  field
    0      2     magic b"TF"
    2      1     version (1)
    3      1     flags: bit 0 = covariance present, bit 1 = path present, others 0
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
    ..     2     path, uint16 (only with flag bit 1): which of the query's candidate paths
                 gave the answer (0 the preferred one, k its k-th fallback)

A message with covariance is 260 bytes, without 92; a path adds 2.

Version 2 is the other message kind: a sensor filter's state after a measurement (what a
consumer's copy of the filter adopts, :class:`trackflow.filters.FilterSnapshot`)::

    offset size  field
    0      2     magic b"TF"
    2      1     version (2)
    3      1     flags: bit 0 = segment start (the filter (re)started here), others 0
    4      8     sequence number, uint64
    12     8     state stamp, int64 ns: the measurement's time corrected by the sensor's
                 stamp offset (sender's clock)
    20     8     host stamp, int64 ns: sender's clock when the message was sent
    28     8     origin stamp, int64 ns
    36     1     n_dp, int8: position derivatives of the motion model (-1..8)
    37     1     n_do, int8: orientation derivatives (-1..8)
    38     1     formulation, uint8: 0 error_state, 1 additive
    39     1     reserved, 0
    40     2     nx, uint16: state size (must match n_dp, n_do)
    42     2     nc, uint16: covariance size (nx - 1 for error_state with orientation, else nx)
    44     4     reserved, 0
    48     8 nx  state x: position and nx its derivatives (3 each, frame a), then the unit
                 quaternion (x, y, z, w) and its derivatives (3 each, body frame b)
    ..     8 k   covariance upper triangle row by row, k = nc (nc + 1) / 2

With n_dp = n_do = 1 (constant velocity) a state is 48 + 104 + 624 = 776 bytes.

Version 3 carries the states an agent's sensors made in one dispatch round (one tracker
frame) as one message, each a version-2 state behind its edge's name::

    offset size  field
    0      2     magic b"TF"
    2      1     version (3)
    3      1     flags, 0
    4      2     count n, uint16 (1..MAX_BATCH)
    6      2     reserved, 0
    8      ..    n entries: name length L (uint8, 1..255), the edge's name (L bytes:
                 letters, digits, ``_``, ``-``), state length S (uint16), a version-2 state
                 (S bytes)

No pickle, no self-describing framing beyond that: the key expression names the edge (1, 2)
or the sending agent (3). Every decoding problem raises :class:`WireError` with a short
``reason`` that receivers count (:class:`Rejections`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from ..errors import FormatError, InputError
from ..filters import FilterSnapshot, MotionModel
from ..math import Pose, UncertainPose, kernels_for
from . import kernels as _kernels

__all__ = [
    "BATCH_VERSION",
    "MAGIC",
    "MAX_BATCH",
    "STATE_VERSION",
    "VERSION",
    "Rejections",
    "StateSample",
    "WireError",
    "WireSample",
    "decode",
    "decode_batch",
    "decode_state",
    "encode",
    "encode_batch",
    "encode_state",
]

MAGIC = b"TF"
VERSION = 1
STATE_VERSION = 2
BATCH_VERSION = 3
#: the most states one batch message carries
MAX_BATCH = 1024
_KNOWN = (VERSION, STATE_VERSION, BATCH_VERSION)
_BATCH_HEAD = struct.Struct("<2sBBHH")
_NAME_BYTES = frozenset(b"abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-")
_FLAG_COV = 0x01
_FLAG_PATH = 0x02
_PATH = struct.Struct("<H")
_FLAG_SEGMENT = 0x01
_STATE_HEAD = struct.Struct("<2sBBQqqqbbBBHHI")
_FORMULATIONS = ("error_state", "additive")
_STATE_ERRORS = {
    _kernels.STATE_NON_FINITE: "non-finite",
    _kernels.STATE_NON_UNIT: "non-unit quaternion",
    _kernels.STATE_NOT_PD: "invalid covariance",
}
_HEAD = struct.Struct("<2sBBQqqq7d")
_COV = struct.Struct("<21d")
_STAMPS = struct.Struct("<2sBBQqqq")
_IU = np.triu_indices(6)
_SYM = np.zeros((6, 6), dtype=np.intp)  # index of each entry of the 6x6 in the upper triangle
_SYM[_IU] = np.arange(21)
_SYM.T[_IU] = np.arange(21)


class WireError(FormatError):
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
    path : int or None
        The candidate path of the query that gave the answer (0 the preferred one), when sent.
    """

    seq: int
    exposure_ns: int
    host_ns: int
    origin_ns: int
    pose: UncertainPose
    path: int | None = None


def encode(
    pose: UncertainPose,
    *,
    seq: int,
    exposure_ns: int,
    host_ns: int,
    origin_ns: int | None = None,
    covariance: bool = True,
    path: int | None = None,
) -> bytes:
    """One message (260 bytes with covariance, 92 without, 2 more with ``path``); see the
    module docstring."""
    if pose.shape != ():
        raise InputError("encode takes a single pose, not a batch")
    if path is not None and not 0 <= path <= 0xFFFF:
        raise InputError(f"path index must be in [0, 65535], got {path}")
    p = pose.position
    q = pose.quaternion
    head = _HEAD.pack(
        MAGIC,
        VERSION,
        (_FLAG_COV if covariance else 0) | (0 if path is None else _FLAG_PATH),
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
    tail = b"" if path is None else _PATH.pack(path)
    if not covariance:
        return head + tail
    return head + _COV.pack(*pose.covariance[_IU]) + tail


class StateSample(NamedTuple):
    """A decoded filter state (version 2).

    Parameters
    ----------
    seq : int
    stamp_ns, host_ns, origin_ns : int
        State time, send time and origin sensor stamp [ns], on the sender's clock.
    n_dp, n_do : int
        The motion model's derivative orders.
    formulation : str
        ``"error_state"`` or ``"additive"``.
    x : ndarray (nx,)
    p : ndarray (nc, nc)
    segment_start : bool
    """

    seq: int
    stamp_ns: int
    host_ns: int
    origin_ns: int
    n_dp: int
    n_do: int
    formulation: str
    x: np.ndarray
    p: np.ndarray
    segment_start: bool

    def snapshot(self, offset_ns: int = 0) -> FilterSnapshot:
        """The state for :meth:`trackflow.filters.PoseKalmanFilter.adopt`, its time mapped by
        ``stamp + offset_ns`` onto the receiver's clock [s] (``offset_ns`` = receiver minus
        sender, the :mod:`trackflow.timesync` sign)."""
        return FilterSnapshot(
            (self.stamp_ns + offset_ns) * 1e-9, self.x, self.p, self.segment_start
        )


@lru_cache(maxsize=128)
def _state_layout(n_dp: int, n_do: int, additive: int) -> tuple[int, int, int]:
    """(nx, nc, quaternion offset or -1) of a motion model (layout of MotionModel)."""
    m = MotionModel(n_dp, n_do)
    nx = m.state_size
    nc = nx if additive else m.error_size
    return nx, nc, (3 * (n_dp + 1) if n_dp >= 0 else 0) if n_do >= 0 else -1


@lru_cache(maxsize=16)
def _triangle(n: int) -> np.ndarray:
    """Flat indices of an n x n matrix's upper triangle, row by row."""
    return np.ravel_multi_index(np.triu_indices(n), (n, n))


def encode_state(
    snap: FilterSnapshot,
    *,
    seq: int,
    stamp_ns: int,
    host_ns: int,
    origin_ns: int,
    n_dp: int,
    n_do: int,
    formulation: str = "error_state",
) -> bytes:
    """One filter-state message (version 2; module docstring). ``stamp_ns`` is the state's
    time in integer ns (``snap.t`` in seconds is not sent: the receiver derives it)."""
    x = np.ascontiguousarray(snap.x, dtype="<f8")
    p = np.asarray(snap.p, dtype="<f8")
    head = _STATE_HEAD.pack(
        MAGIC,
        STATE_VERSION,
        _FLAG_SEGMENT if snap.segment_start else 0,
        int(seq) & 0xFFFFFFFFFFFFFFFF,
        int(stamp_ns),
        int(host_ns),
        int(origin_ns),
        int(n_dp),
        int(n_do),
        _FORMULATIONS.index(formulation),
        0,
        x.size,
        p.shape[0],
        0,
    )
    return head + x.tobytes() + p.take(_triangle(p.shape[0])).tobytes()


def _check_version(b: bytes, want: int) -> None:
    if len(b) < 4:
        raise WireError("truncated", f"{len(b)} bytes")
    if b[:2] != MAGIC:
        raise WireError("bad magic", repr(b[:2]))
    if b[2] != want:
        if b[2] in _KNOWN:
            raise WireError("wrong kind", f"version {b[2]} where {want} is expected")
        raise WireError("unknown version", str(b[2]))


def decode_state(buf) -> StateSample:
    """Decode one filter-state message; raises :class:`WireError` (reasons of :func:`decode`,
    plus ``wrong kind`` for a pose message, ``unknown motion model`` and ``state size``)."""
    b = buf if isinstance(buf, bytes) else bytes(buf)
    _check_version(b, STATE_VERSION)
    if len(b) < _STATE_HEAD.size:
        raise WireError("truncated", f"{len(b)} of {_STATE_HEAD.size} header bytes")
    _, _, flags, seq, stamp, host, origin, n_dp, n_do, form, res1, nx, nc, res2 = (
        _STATE_HEAD.unpack_from(b)
    )
    if flags & ~_FLAG_SEGMENT or res1 or res2:
        raise WireError("unknown flags", f"0x{flags:02x}, reserved {res1}, {res2}")
    if not (-1 <= n_dp <= 8 and -1 <= n_do <= 8) or n_dp + n_do == -2 or form > 1:
        raise WireError("unknown motion model", f"n_dp={n_dp}, n_do={n_do}, formulation={form}")
    want_nx, want_nc, qo = _state_layout(n_dp, n_do, form)
    if (nx, nc) != (want_nx, want_nc):
        raise WireError("state size", f"{nx}/{nc} instead of {want_nx}/{want_nc}")
    k = nc * (nc + 1) // 2
    want = _STATE_HEAD.size + 8 * (nx + k)
    if len(b) != want:
        raise WireError(
            "truncated" if len(b) < want else "wrong length", f"{len(b)} of {want} bytes"
        )
    values = np.frombuffer(b, "<f8", offset=_STATE_HEAD.size)
    x = np.empty(nx)
    p = np.empty((nc, nc))
    with np.errstate(over="ignore", invalid="ignore"):  # huge garbage: rejected, not warned
        code = kernels_for(_kernels).unpack_state(values, nx, nc, qo, x, p, np.empty((nc, nc)))
    if code:
        raise WireError(_STATE_ERRORS[code])
    return StateSample(seq, stamp, host, origin, n_dp, n_do, _FORMULATIONS[form], x, p, bool(flags))


def encode_batch(entries) -> bytes:
    """One batch message (version 3; module docstring) of ``entries``, ``(edge name,
    version-2 state message)`` pairs, 1 to :data:`MAX_BATCH` of them."""
    if not 1 <= len(entries) <= MAX_BATCH:
        raise InputError(f"a batch holds 1 to {MAX_BATCH} states, not {len(entries)}")
    parts = [_BATCH_HEAD.pack(MAGIC, BATCH_VERSION, 0, len(entries), 0)]
    for edge, state in entries:
        name = edge.encode("ascii")
        if not 1 <= len(name) <= 255 or not _NAME_BYTES.issuperset(name):
            raise InputError(f"edge name {edge!r} cannot be sent: 1 to 255 of [A-Za-z0-9_-]")
        parts += [bytes((len(name),)), name, _PATH.pack(len(state)), state]
    return b"".join(parts)


def decode_batch(buf) -> list[tuple[str, bytes]]:
    """The ``(edge name, version-2 state message)`` entries of one batch message, the
    states still encoded (a receiver decodes those it uses with :func:`decode_state`).
    Raises :class:`WireError` for the whole message (``bad magic``, ``unknown version``,
    ``wrong kind``, ``unknown flags``, ``empty batch``, ``bad edge name``, ``truncated``,
    ``wrong length``)."""
    b = buf if isinstance(buf, bytes) else bytes(buf)
    _check_version(b, BATCH_VERSION)
    if len(b) < _BATCH_HEAD.size:
        raise WireError("truncated", f"{len(b)} of {_BATCH_HEAD.size} header bytes")
    _, _, flags, count, reserved = _BATCH_HEAD.unpack_from(b)
    if flags or reserved:
        raise WireError("unknown flags", f"0x{flags:02x}, reserved {reserved}")
    if not 1 <= count <= MAX_BATCH:
        raise WireError("empty batch" if count == 0 else "wrong length", f"{count} states")
    out = []
    at = _BATCH_HEAD.size
    for _ in range(count):
        if at >= len(b):
            raise WireError("truncated", f"{len(out)} of {count} states")
        n = b[at]
        name = b[at + 1 : at + 1 + n]
        if n == 0 or len(name) < n:
            raise WireError("bad edge name" if n == 0 else "truncated", f"state {len(out)}")
        if not _NAME_BYTES.issuperset(name):
            raise WireError("bad edge name", repr(name))
        at += 1 + n
        if at + _PATH.size > len(b):
            raise WireError("truncated", f"state {len(out)}")
        size = _PATH.unpack_from(b, at)[0]
        at += _PATH.size
        if at + size > len(b):
            raise WireError("truncated", f"state {len(out)}: {len(b) - at} of {size} bytes")
        out.append((name.decode("ascii"), b[at : at + size]))
        at += size
    if at != len(b):
        raise WireError("wrong length", f"{len(b) - at} bytes after {count} states")
    return out


def decode(buf) -> WireSample:
    """Decode one pose message; raises :class:`WireError` (reason: ``bad magic``, ``unknown
    version``, ``wrong kind`` (a filter state), ``unknown flags``, ``truncated``, ``wrong
    length``, ``non-finite``, ``non-unit quaternion``, ``invalid covariance``)."""
    b = bytes(buf)
    _check_version(b, VERSION)
    flags = b[3]
    if flags & ~(_FLAG_COV | _FLAG_PATH):
        raise WireError("unknown flags", f"0x{flags:02x}")
    n_cov = _COV.size if flags & _FLAG_COV else 0
    want = _HEAD.size + n_cov + (_PATH.size if flags & _FLAG_PATH else 0)
    if len(b) < want:
        raise WireError("truncated", f"{len(b)} of {want} bytes")
    if len(b) != want:
        raise WireError("wrong length", f"{len(b)} instead of {want} bytes")
    _, _, _, seq, exposure, host, origin = _STAMPS.unpack_from(b)
    n_values = (_HEAD.size + n_cov - _STAMPS.size) // 8
    values = np.frombuffer(b, "<f8", count=n_values, offset=_STAMPS.size)
    if not np.isfinite(values).all():
        raise WireError("non-finite")
    cov = values[7 + _SYM] if len(values) > 7 else np.zeros((6, 6))
    path = _PATH.unpack_from(b, _HEAD.size + n_cov)[0] if flags & _FLAG_PATH else None
    with np.errstate(over="ignore", invalid="ignore"):  # finite but huge garbage: rejected
        try:
            pose = Pose(values[:3], values[3:7])
        except ValueError as exc:
            raise WireError("non-unit quaternion", str(exc)) from None
        try:
            up = UncertainPose(pose, cov)
        except ValueError as exc:
            raise WireError("invalid covariance", str(exc)) from None
    return WireSample(seq, exposure, host, origin, up, path)


@dataclass
class Rejections:
    """Counted rejections by reason (thread-safe enough for counters updated under the GIL)."""

    counts: dict[str, int] = field(default_factory=dict)

    def add(self, reason: str) -> None:
        self.counts[reason] = self.counts.get(reason, 0) + 1

    @property
    def total(self) -> int:
        return sum(self.counts.values())
