"""OptiTrack NatNet (Motive) over UDP: a pure decoder and an encoder for versions 2.0-4.1.

Every message is ``u16 id, u16 nbytes, payload`` (little-endian). The version announced by
the server in SERVERINFO decides how a frame is laid out, so a client decodes nothing before
the handshake. Layout of a frame of mocap data (message 7), by version (NatNet SDK
``PacketClient``/``NatNetClient`` samples, read to learn the format):

* frame number i32; marker sets; legacy unlabeled markers; rigid bodies; skeletons (>= 2.1);
  assets (>= 4.1); labeled markers (>= 2.3); force plates (>= 2.9); devices (>= 2.11);
* from 4.1 every section's count is followed by its size in bytes (u32), so an unknown or
  unwanted section is skipped by size;
* rigid body: id i32, position 3 f32 [m], quaternion 4 f32 ``(x, y, z, w)``; before 3.0 its
  markers inline (count, positions, and from 2.0 ids and sizes); mean marker error f32
  [m] (>= 2.0); parameters i16, bit 0 = tracking valid (>= 2.6);
* suffix: software latency f32 (< 3.0), timecode u32, sub-timecode u32, timestamp f64 (f32
  before 2.7) [s], from 3.0 the high-resolution clock ticks of camera mid-exposure, data
  received and transmit (u64, ``HighResClockFrequency`` ticks per second, from
  SERVERINFO), from 4.1 the precision timestamp (u32 seconds, u32 fractional seconds),
  parameters i16, end-of-data tag i32 (optional here).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..errors import InputError
from ._packet import MAX_DATAGRAM, PacketError, Reader
from .wire_checks import (
    ASSET_BYTES,
    CHANNEL_BYTES,
    DEVICE_BYTES,
    MARKER_BYTES,
    MARKER_SET_BYTES,
    SKELETON_BODY_BYTES,
    SKELETON_BYTES,
    labeled_marker_bytes,
    natnet_version_code,
    rigid_body_bytes,
    sized_sections,
)

__all__ = [
    "CONNECT",
    "DISCONNECT",
    "FRAMEOFDATA",
    "KEEPALIVE",
    "MESSAGESTRING",
    "MODELDEF",
    "REQUEST",
    "REQUEST_MODELDEF",
    "RESPONSE",
    "ECHOREQUEST",
    "ECHORESPONSE",
    "SERVERINFO",
    "SUPPORTED_VERSIONS",
    "UNRECOGNIZED",
    "ModelDefinitions",
    "NatNetFrame",
    "NatNetRigidBody",
    "RIGID_BODY_DTYPE",
    "RigidBodyDescription",
    "ServerInfo",
    "decode_echo_response",
    "decode_frame",
    "decode_message",
    "decode_model_definitions",
    "decode_server_info",
    "encode_connect",
    "encode_echo_request",
    "encode_echo_response",
    "encode_frame",
    "encode_message",
    "encode_model_definitions",
    "encode_server_info",
    "exposure_and_latency",
    "latency_ticks",
]

CONNECT, SERVERINFO, REQUEST, RESPONSE = 0, 1, 2, 3
REQUEST_MODELDEF, MODELDEF, FRAMEOFDATA, MESSAGESTRING = 4, 5, 7, 8
DISCONNECT, KEEPALIVE, ECHOREQUEST, ECHORESPONSE, UNRECOGNIZED = 9, 10, 12, 13, 100

#: (major, minor) versions decoded and encoded here (Motive 1.x-3.1+).
SUPPORTED_VERSIONS = ((2, 0), (2, 6), (2, 7), (2, 9), (2, 11), (3, 0), (3, 1), (4, 0), (4, 1))

_HEAD = struct.Struct("<HH")
_RB3 = struct.Struct("<i3f4ffh")  # >= 3.0 rigid body: 38 bytes
#: the same 38 bytes as a NumPy record: the rigid bodies of a frame in one array
RIGID_BODY_DTYPE = np.dtype(
    [
        ("id", "<i4"),
        ("position", "<f4", (3,)),
        ("quaternion", "<f4", (4,)),
        ("mean_error", "<f4"),
        ("params", "<i2"),
    ]
)
assert RIGID_BODY_DTYPE.itemsize == _RB3.size


@dataclass(frozen=True, slots=True)
class ServerInfo:
    """SERVERINFO: application name and version, NatNet version, and (from 3.0) the
    high-resolution clock frequency [ticks/s], data port and multicast settings."""

    app_name: str = "Motive"
    app_version: tuple[int, int, int, int] = (3, 1, 0, 0)
    natnet_version: tuple[int, int, int, int] = (4, 1, 0, 0)
    clock_frequency: int | None = None
    data_port: int = 1511
    multicast: bool = False
    multicast_group: tuple[int, int, int, int] = (239, 255, 42, 99)

    @property
    def version(self) -> tuple[int, int]:
        return self.natnet_version[0], self.natnet_version[1]


class NatNetRigidBody(NamedTuple):
    """A rigid body of a frame: ``position`` [m] (3,), ``quaternion`` ``(x, y, z, w)`` (4,),
    ``mean_error`` [m] (``None`` before 2.0), ``valid`` (``None`` before 2.6)."""

    id: int
    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]
    mean_error: float | None = None
    valid: bool | None = None
    markers: tuple[tuple[float, float, float], ...] = ()


@dataclass(frozen=True, slots=True)
class NatNetFrame:
    """A decoded frame of mocap data. Tick stamps are ``None`` before 3.0; ``precision``
    is ``(seconds, fractional)`` from 4.1. ``other`` holds the raw bytes of the sections
    between rigid bodies and the suffix that the encoder writes back verbatim (tests)."""

    frame: int
    rigid_bodies: tuple[NatNetRigidBody, ...] = ()
    timestamp: float = 0.0
    mid_exposure: int | None = None
    data_received: int | None = None
    transmit: int | None = None
    precision: tuple[int, int] | None = None
    params: int = 0
    timecode: tuple[int, int] = (0, 0)
    marker_sets: tuple[tuple[str, tuple[tuple[float, float, float], ...]], ...] = ()
    labeled_markers: int = 0
    software_latency: float | None = None
    #: from 3.0, with ``decode_frame(..., table=True)``: the rigid bodies as one read-only
    #: array of :data:`RIGID_BODY_DTYPE` records (``rigid_bodies`` is then empty)
    body_table: np.ndarray | None = field(default=None, compare=False)

    def body(self, body_id: int) -> NatNetRigidBody | None:
        for b in self.rigid_bodies:
            if b.id == body_id:
                return b
        return None


@dataclass(frozen=True, slots=True)
class RigidBodyDescription:
    """A rigid body's model definition: name, id, parent id, pivot offset [m]."""

    name: str
    id: int
    parent: int = -1
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True, slots=True)
class ModelDefinitions:
    """MODELDEF: the rigid body descriptions (names <-> ids); ``complete`` is False when a
    description of an unsupported type before 4.1 (no sizes) stopped the decoding;
    ``skipped`` counts the descriptions (4.1+) that were malformed within their declared
    size and were passed over by it."""

    rigid_bodies: tuple[RigidBodyDescription, ...] = ()
    marker_sets: tuple[str, ...] = ()
    complete: bool = True
    skipped: int = 0

    def id_of(self, name: str) -> int | None:
        for d in self.rigid_bodies:
            if d.name == name:
                return d.id
        return None


def _ver(version) -> tuple[int, int]:
    v = (int(version[0]), int(version[1]))
    if v < (2, 0) or v > (4, 1):
        raise PacketError("wrong version", f"NatNet {v[0]}.{v[1]} is not supported (2.0-4.1)")
    return v


# -- messages -------------------------------------------------------------------------------------
def decode_message(data) -> tuple[int, memoryview]:
    """``(message id, payload)`` of one datagram; the payload length must match."""
    if len(data) > MAX_DATAGRAM:
        raise PacketError("oversized", f"{len(data)} bytes")
    if len(data) < 4:
        raise PacketError("truncated", f"{len(data)} bytes, no NatNet header")
    msg, n = _HEAD.unpack_from(data, 0)
    if 4 + n > len(data):
        raise PacketError("truncated", f"message {msg} announces {n} bytes, has {len(data) - 4}")
    return msg, memoryview(data)[4 : 4 + n]


def encode_message(msg_id: int, payload: bytes = b"") -> bytes:
    if len(payload) > 0xFFFF:
        raise InputError(f"NatNet payload of {len(payload)} bytes does not fit the u16 size")
    return _HEAD.pack(msg_id, len(payload)) + payload


def _name(text: str, size: int = 256) -> bytes:
    raw = text.encode("utf-8")[: size - 1]
    return raw + b"\0" * (size - len(raw))


def encode_connect(version: tuple[int, int, int, int] = (4, 1, 0, 0)) -> bytes:
    """CONNECT: ``"Ping"`` padded to 265 bytes, then the NatNet version the client speaks
    (4 bytes) and a NUL, 270 bytes, as the NatNet SDK's 4.1 sample client sends it; older
    servers read only the leading string."""
    return encode_message(CONNECT, b"Ping" + b"\0" * 261 + bytes(version) + b"\0")


_ECHO = struct.Struct("<QQ")


def encode_echo_request(token: int) -> bytes:
    """ECHOREQUEST (NatNet 3.0+ clock synchronisation): a u64 the server echoes back; the
    client sends its own send time [host ns], so the answer needs no bookkeeping."""
    return encode_message(ECHOREQUEST, struct.pack("<Q", token))


def encode_echo_response(token: int, server_ticks: int) -> bytes:
    """ECHORESPONSE: the request's u64, then the server's high-resolution clock [ticks]
    when it answered."""
    return encode_message(ECHORESPONSE, _ECHO.pack(token, server_ticks))


def decode_echo_response(payload) -> tuple[int, int]:
    """``(token, server ticks)`` of an ECHORESPONSE payload (16 bytes; more are ignored)."""
    if len(payload) < _ECHO.size:
        raise PacketError("truncated", f"ECHORESPONSE of {len(payload)} bytes, needs 16")
    return _ECHO.unpack_from(payload, 0)


def decode_server_info(payload) -> ServerInfo:
    """Decode a SERVERINFO payload (the clock fields only from NatNet 3.0 on)."""
    r = Reader(payload)
    r.need(264, "SERVERINFO")
    raw = bytes(r.data[0:256])
    name = raw.split(b"\0", 1)[0].decode("utf-8", "replace")
    r.pos = 256
    app = r.unpack("4B", "app version")
    nn = r.unpack("4B", "NatNet version")
    if (nn[0], nn[1]) < (2, 0) or (nn[0], nn[1]) > (4, 1):
        raise PacketError("wrong version", f"server speaks NatNet {nn[0]}.{nn[1]}")
    if r.remaining() >= 15 and nn[0] >= 3:
        freq, port, mc = r.unpack("QH?", "clock")
        group = r.unpack("4B", "multicast group")
        if freq <= 0:
            raise PacketError("bad field", "HighResClockFrequency is 0")
        return ServerInfo(name, app, nn, freq, port, mc, group)
    return ServerInfo(name, app, nn, None)


def encode_server_info(info: ServerInfo) -> bytes:
    body = _name(info.app_name) + bytes(info.app_version) + bytes(info.natnet_version)
    if info.clock_frequency is not None:
        body += struct.pack("<QH?", info.clock_frequency, info.data_port, info.multicast)
        body += bytes(info.multicast_group)
    return encode_message(SERVERINFO, body)


# -- frames ---------------------------------------------------------------------------------------
def _section(r: Reader, v, what: str, item_bytes: int) -> tuple[int, int | None]:
    n = r.count(f"{what} count", item_bytes)
    size = None
    if sized_sections(natnet_version_code(*v)):
        (size,) = r.unpack("I", f"{what} size")
        r.need(size, what)
    return n, size


def _rigid_body(r: Reader, v) -> NatNetRigidBody:
    bid, px, py, pz, qx, qy, qz, qw = r.unpack("i3f4f", "rigid body")
    markers: tuple = ()
    if v < (3, 0):
        nm = r.count("rigid body marker count", MARKER_BYTES)
        flat = r.unpack(f"{3 * nm}f", "rigid body markers")
        markers = tuple(tuple(flat[3 * i : 3 * i + 3]) for i in range(nm))
        if v >= (2, 0):
            r.skip(8 * nm, "rigid body marker ids and sizes")
    err = r.unpack("f", "mean error")[0] if v >= (2, 0) else None
    valid = bool(r.unpack("h", "rigid body params")[0] & 1) if v >= (2, 6) else None
    return NatNetRigidBody(bid, (px, py, pz), (qx, qy, qz, qw), err, valid, markers)


def _vec_floats(r: Reader, what: str) -> None:
    """Skip channels: count, then per channel a frame count and that many f32."""
    nch = r.count(f"{what} channels", CHANNEL_BYTES)
    for _ in range(nch):
        nf = r.count(f"{what} frames", CHANNEL_BYTES)
        r.skip(4 * nf, what)


def decode_frame(payload, version, *, table: bool = False) -> NatNetFrame:
    """Decode the payload of a FRAMEOFDATA message for NatNet ``version`` (major, minor).

    ``table=True`` (NatNet 3.0+): the rigid bodies come as one array of
    :data:`RIGID_BODY_DTYPE` records in ``body_table`` (the bytes of the packet, not copied)
    instead of one :class:`NatNetRigidBody` each; before 3.0 the option changes nothing.

    Raises
    ------
    PacketError
        ``wrong version``, ``truncated``, ``bad count``, ``bad string``, ``bad size`` (a 4.1
        section whose content does not fill its announced size).
    """
    v = _ver(version)
    r = Reader(payload)
    (frame,) = r.unpack("i", "frame number")
    # marker sets
    code = natnet_version_code(*v)
    n, size = _section(r, v, "marker sets", MARKER_SET_BYTES)
    start = r.pos
    msets = []
    for _ in range(n):
        name = r.cstring("marker set name")
        nm = r.count("marker count", MARKER_BYTES)
        flat = r.unpack(f"{3 * nm}f", "marker set")
        msets.append((name, tuple(tuple(flat[3 * i : 3 * i + 3]) for i in range(nm))))
    _check_size(r, start, size, "marker sets")
    # legacy unlabeled markers
    n, size = _section(r, v, "unlabeled markers", MARKER_BYTES)
    r.skip(MARKER_BYTES * n, "unlabeled markers")
    # rigid bodies
    n, size = _section(r, v, "rigid bodies", rigid_body_bytes(code))
    start = r.pos
    tab = None
    if v >= (3, 0) and table:
        r.need(38 * n, "rigid bodies")
        tab = np.frombuffer(r.data, RIGID_BODY_DTYPE, n, r.pos)
        bodies = ()
        r.pos += 38 * n
    elif v >= (3, 0):
        r.need(38 * n, "rigid bodies")
        bodies = tuple(
            NatNetRigidBody(t[0], t[1:4], t[4:8], t[8], t[9] & 1 == 1)
            for t in _RB3.iter_unpack(r.data[r.pos : r.pos + 38 * n])
        )
        r.pos += 38 * n
    else:
        bodies = tuple(_rigid_body(r, v) for _ in range(n))
    _check_size(r, start, size, "rigid bodies")
    if v >= (2, 1):  # skeletons: id, rigid bodies
        n, size = _section(r, v, "skeletons", SKELETON_BYTES)
        start = r.pos
        for _ in range(n):
            r.unpack("i", "skeleton id")
            for _ in range(r.count("skeleton bodies", SKELETON_BODY_BYTES)):
                _rigid_body(r, v)
        _check_size(r, start, size, "skeletons")
    if v >= (4, 1):  # assets: skipped by size
        n, size = _section(r, v, "assets", ASSET_BYTES)
        r.skip(size, "assets")
    nlab = 0
    if v >= (2, 3):
        item = labeled_marker_bytes(code)
        nlab, size = _section(r, v, "labeled markers", item)
        if size is not None and size != nlab * item:
            raise PacketError("bad size", f"labeled markers: {size} bytes for {nlab}")
        r.skip(item * nlab, "labeled markers")
    for minv, what in (((2, 9), "force plates"), ((2, 11), "devices")):
        if v >= minv:
            n, size = _section(r, v, what, DEVICE_BYTES)
            start = r.pos
            for _ in range(n):
                r.unpack("i", f"{what} id")
                _vec_floats(r, what)
            _check_size(r, start, size, what)
    lat = r.unpack("f", "software latency")[0] if v < (3, 0) else None
    tc = r.unpack("II", "timecode")
    ts = r.unpack("d" if v >= (2, 7) else "f", "timestamp")[0]
    mid = recv = tx = None
    if v >= (3, 0):
        mid, recv, tx = r.unpack("QQQ", "clock ticks")
    prec = r.unpack("II", "precision timestamp") if v >= (4, 1) else None
    (params,) = r.unpack("h", "frame params")
    if r.remaining() >= 4:
        r.skip(4, "end of data")
    return NatNetFrame(
        frame, bodies, ts, mid, recv, tx, prec, params & 0xFFFF, tc, tuple(msets), nlab, lat, tab
    )


def _check_size(r: Reader, start: int, size: int | None, what: str) -> None:
    if size is not None and r.pos - start != size:
        raise PacketError("bad size", f"{what}: announced {size} bytes, content {r.pos - start}")


def _pack_rigid_body(b: NatNetRigidBody, v) -> bytes:
    out = struct.pack("<i3f4f", b.id, *b.position, *b.quaternion)
    if v < (3, 0):
        nm = len(b.markers)
        out += struct.pack(f"<i{3 * nm}f", nm, *(x for m in b.markers for x in m))
        if v >= (2, 0):
            out += struct.pack(f"<{nm}i{nm}f", *range(1, nm + 1), *([0.01] * nm))
    if v >= (2, 0):
        out += struct.pack("<f", 0.0 if b.mean_error is None else b.mean_error)
    if v >= (2, 6):
        out += struct.pack("<h", 1 if b.valid is None or b.valid else 0)
    return out


def _pack_section(v, count: int, body: bytes) -> bytes:
    head = struct.pack("<i", count)
    if v >= (4, 1):
        head += struct.pack("<I", len(body))
    return head + body


def encode_frame(
    frame: NatNetFrame, version, *, assets: tuple[bytes, int] | None = None, eod: bool = True
) -> bytes:
    """Encode a FRAMEOFDATA message (header included) for NatNet ``version``.

    ``assets`` ``(raw bytes, count)`` fills the 4.1 asset section (opaque: decoders skip it by
    size). Labeled markers are written as ``frame.labeled_markers`` zero markers.
    """
    v = _ver(version)
    out = [struct.pack("<i", frame.frame)]
    ms = b"".join(
        _name(name, len(name.encode()) + 1)
        + struct.pack(f"<i{3 * len(m)}f", len(m), *(x for p in m for x in p))
        for name, m in frame.marker_sets
    )
    out.append(_pack_section(v, len(frame.marker_sets), ms))
    out.append(_pack_section(v, 0, b""))
    rb = b"".join(_pack_rigid_body(b, v) for b in frame.rigid_bodies)
    out.append(_pack_section(v, len(frame.rigid_bodies), rb))
    if v >= (2, 1):
        out.append(_pack_section(v, 0, b""))
    if v >= (4, 1):
        raw, n = assets if assets is not None else (b"", 0)
        out.append(_pack_section(v, n, raw))
    if v >= (2, 3):
        item = labeled_marker_bytes(natnet_version_code(*v))
        out.append(_pack_section(v, frame.labeled_markers, b"\0" * item * frame.labeled_markers))
    if v >= (2, 9):
        out.append(_pack_section(v, 0, b""))
    if v >= (2, 11):
        out.append(_pack_section(v, 0, b""))
    if v < (3, 0):
        out.append(struct.pack("<f", frame.software_latency or 0.0))
    out.append(struct.pack("<II", *frame.timecode))
    out.append(struct.pack("<d" if v >= (2, 7) else "<f", frame.timestamp))
    if v >= (3, 0):
        out.append(
            struct.pack(
                "<QQQ", frame.mid_exposure or 0, frame.data_received or 0, frame.transmit or 0
            )
        )
    if v >= (4, 1):
        out.append(struct.pack("<II", *(frame.precision or (0, 0))))
    out.append(struct.pack("<h", frame.params))
    if eod:
        out.append(struct.pack("<i", 0))
    return encode_message(FRAMEOFDATA, b"".join(out))


# -- model definitions ----------------------------------------------------------------------------
def decode_model_definitions(payload, version) -> ModelDefinitions:
    """Decode MODELDEF: marker sets (type 0), rigid bodies (1) and skeletons' bodies (2);
    other types are skipped by size from 4.1 on and end the decoding before. From 4.1 on, a
    description that is malformed within its declared size is skipped by that size and
    counted (:attr:`ModelDefinitions.skipped`): one bad description loses only itself."""
    v = _ver(version)
    r = Reader(payload)
    n = r.count("descriptions", 4)
    bodies: list[RigidBodyDescription] = []
    msets: list[str] = []
    skipped = 0
    for _ in range(n):
        (kind,) = r.unpack("i", "description type")
        if v < (4, 1):
            if not _description(r, kind, v, bodies, msets):
                return ModelDefinitions(tuple(bodies), tuple(msets), complete=False)
            continue
        size = r.unpack("I", "description size")[0]
        start = r.pos
        r.need(size, "description")
        sub = Reader(r.data, "<", start, start + size)  # reads cannot pass its end
        got_b, got_m = len(bodies), len(msets)
        try:
            if not _description(sub, kind, v, bodies, msets):
                sub.pos = start + size  # a kind not decoded here: skipped by its size
            if sub.pos != start + size:
                raise PacketError("bad size", f"description type {kind}: size {size}")
        except PacketError:
            del bodies[got_b:], msets[got_m:]
            skipped += 1
        r.pos = start + size
    return ModelDefinitions(tuple(bodies), tuple(msets), skipped=skipped)


def _description(r: Reader, kind: int, v, bodies: list, msets: list) -> bool:
    """Read one description of ``kind`` into ``bodies`` / ``msets``; False for a kind this
    decoder does not know (the caller skips it by size, or stops without sizes)."""
    if kind == 0:
        msets.append(r.cstring("marker set name"))
        for _ in range(r.count("marker names", 1)):
            r.cstring("marker name")
    elif kind == 1:
        bodies.append(_rb_description(r, v))
    elif kind == 2:
        r.cstring("skeleton name")
        r.unpack("i", "skeleton id")
        for _ in range(r.count("skeleton bodies", 20)):
            bodies.append(_rb_description(r, v))
    else:
        return False
    return True


def _rb_description(r: Reader, v) -> RigidBodyDescription:
    name = r.cstring("rigid body name") if v >= (2, 0) else ""
    bid, parent, ox, oy, oz = r.unpack("ii3f", "rigid body description")
    if v >= (3, 0):
        nm = r.count("rigid body markers", 16)
        r.skip(16 * nm, "rigid body marker offsets and labels")
        if v >= (4, 0):
            for _ in range(nm):
                r.cstring("marker name")
    return RigidBodyDescription(name, bid, parent, (ox, oy, oz))


def encode_model_definitions(defs: ModelDefinitions, version) -> bytes:
    """MODELDEF message with rigid body descriptions (no markers) for ``version``."""
    v = _ver(version)
    items = []
    for d in defs.rigid_bodies:
        body = (_name(d.name, len(d.name.encode()) + 1) if v >= (2, 0) else b"") + struct.pack(
            "<ii3f", d.id, d.parent, *d.offset
        )
        if v >= (3, 0):
            body += struct.pack("<i", 0)
        head = struct.pack("<i", 1) + (struct.pack("<I", len(body)) if v >= (4, 1) else b"")
        items.append(head + body)
    return encode_message(MODELDEF, struct.pack("<i", len(items)) + b"".join(items))


def exposure_and_latency(frame: NatNetFrame, clock_frequency: int | None):
    """``(transmit time, exposure time, system latency)`` in seconds of the tracker's
    high-resolution clock, from the mid-exposure and transmit ticks; ``None`` before 3.0 or
    without a clock frequency.

    Raises
    ------
    PacketError
        ``bad stamps``: transmit before mid-exposure, or a latency above 10 s.
    """
    if frame.mid_exposure is None or frame.transmit is None or not clock_frequency:
        return None
    lat_ticks = latency_ticks(frame.mid_exposure, frame.transmit, clock_frequency)
    f = float(clock_frequency)
    tx_s = frame.transmit // clock_frequency + (frame.transmit % clock_frequency) / f
    return tx_s, tx_s - lat_ticks / f, lat_ticks / f


def latency_ticks(mid_exposure: int, transmit: int, clock_frequency: int) -> int:
    """The system latency ``transmit - mid_exposure`` [ticks] of a frame's stamps.

    Raises
    ------
    PacketError
        ``bad stamps``: transmit before mid-exposure, or a latency above 10 s.
    """
    lat_ticks = transmit - mid_exposure
    if lat_ticks < 0 or lat_ticks > 10 * clock_frequency:
        raise PacketError("bad stamps", f"transmit - mid-exposure = {lat_ticks} ticks")
    return lat_ticks
