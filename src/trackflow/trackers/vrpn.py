"""VRPN (Virtual-Reality Peripheral Network) over TCP: cookies, messages, tracker reports.

A connection starts with each side sending a 24-byte cookie (``"vrpn: ver. 07.38  0"``,
NUL-padded, the version of VRPN since 2025); the major version must match, a different minor
version is accepted as VRPN itself does. Then messages flow, big-endian, each a 24-byte
header ``u32 length (header + payload, unpadded), u32 tv_sec, u32 tv_usec, i32 sender,
i32 type, u32 0`` and the payload padded to a multiple of 8 bytes. Sender and type ids are
per side and announced by description messages: type -1 (sender description, the header's
sender field is the new id) and -2 (type description, the sender field is the type id), both
with payload ``u32 length, name, NUL``. A tracker report ``"vrpn_Tracker Pos_Quat"`` carries
``i32 sensor, i32 pad, 3 f64 position, 4 f64 quaternion`` with the quaternion **x, y, z, w**
on the wire (vrpn_Tracker.C ``encode_to``); the header time is the source timestamp
(vrpn/vrpn-rs ``Protocol.md``; vrpn/vrpn ``vrpn_Connection.C``).

Liveness: a client's device sends ``"vrpn_Base ping_message"`` (empty body) on the device's
sender once a second until the server answers ``"vrpn_Base pong_message"`` on the same
sender; without an answer it warns after 3 s (vrpn/vrpn ``vrpn_BaseClass.C``).

:class:`StreamDecoder` cuts a TCP byte stream into messages and keeps the id tables, so it
has no I/O and can be fed any split of the bytes.
"""

from __future__ import annotations

import struct
from typing import NamedTuple

from ._packet import PacketError

__all__ = [
    "COOKIE",
    "COOKIE_SIZE",
    "PING",
    "PONG",
    "POS_QUAT",
    "SENDER_DESCRIPTION",
    "TYPE_DESCRIPTION",
    "Message",
    "PoseReport",
    "StreamDecoder",
    "check_cookie",
    "decode_pos_quat",
    "encode_description",
    "encode_message",
    "encode_pos_quat",
    "make_cookie",
]

COOKIE_SIZE = 24
COOKIE = b"vrpn: ver. 07.38"
POS_QUAT = "vrpn_Tracker Pos_Quat"
PING, PONG = "vrpn_Base ping_message", "vrpn_Base pong_message"
SENDER_DESCRIPTION, TYPE_DESCRIPTION = -1, -2
_HEADER = struct.Struct(">IIIiiI")
_POSQUAT = struct.Struct(">ii3d4d")
#: the longest message accepted [bytes]; longer announcements are garbage
MAX_MESSAGE = 1 << 16


def make_cookie(log_mode: int = 0) -> bytes:
    """The 24-byte cookie each side sends first."""
    raw = COOKIE + b"  " + str(int(log_mode)).encode()
    return raw + b"\0" * (COOKIE_SIZE - len(raw))


def check_cookie(data: bytes) -> None:
    """Accept a peer's cookie (same major version ``07``) or raise ``PacketError``."""
    if len(data) < COOKIE_SIZE:
        raise PacketError("truncated", "VRPN cookie")
    if data[:11] != COOKIE[:11] or data[11:13] != COOKIE[11:13]:
        raise PacketError("wrong version", f"VRPN cookie {bytes(data[:16])!r}")


class Message(NamedTuple):
    """One VRPN message: header time (``sec``, ``usec``), sender id, type id, payload."""

    sec: int
    usec: int
    sender: int
    type: int
    payload: bytes


class PoseReport(NamedTuple):
    """A decoded Pos_Quat report: ``position`` (3,), ``quaternion`` ``(x, y, z, w)`` (4,),
    source time ``sec`` + ``usec`` (the sender's clock)."""

    device: str
    sensor: int
    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]
    sec: int
    usec: int


def _pad8(n: int) -> int:
    return (n + 7) & ~7


def encode_message(sec: int, usec: int, sender: int, mtype: int, payload: bytes) -> bytes:
    head = _HEADER.pack(24 + len(payload), sec, usec, sender, mtype, 0)
    return head + payload + b"\0" * (_pad8(len(payload)) - len(payload))


def encode_description(kind: int, local_id: int, name: str, sec: int = 0, usec: int = 0) -> bytes:
    """Sender (``kind=-1``) or type (``kind=-2``) description announcing ``local_id``."""
    raw = name.encode("ascii") + b"\0"
    return encode_message(sec, usec, local_id, kind, struct.pack(">I", len(raw)) + raw)


def encode_pos_quat(sensor: int, position, quaternion) -> bytes:
    """The Pos_Quat payload (quaternion ``(x, y, z, w)``)."""
    return _POSQUAT.pack(int(sensor), 0, *map(float, position), *map(float, quaternion))


def decode_pos_quat(payload: bytes) -> tuple[int, tuple, tuple]:
    """``(sensor, position, quaternion xyzw)`` of a Pos_Quat payload."""
    if len(payload) < _POSQUAT.size:
        raise PacketError("truncated", f"Pos_Quat payload of {len(payload)} bytes")
    t = _POSQUAT.unpack_from(payload, 0)
    return t[0], t[2:5], t[5:9]


class StreamDecoder:
    """Cuts a VRPN TCP stream into messages and decodes tracker reports.

    ``feed(bytes)`` returns the :class:`PoseReport` s completed by the new bytes; id
    descriptions update the tables; other messages are counted in ``other`` (and passed to
    ``on_other``). The first 24
    bytes must be the peer's cookie. Garbage raises ``PacketError`` (the stream cannot be
    resynchronised: the caller closes the connection and counts it).
    """

    def __init__(self, expect_cookie: bool = True, on_other=None):
        self.buf = bytearray()
        self.cookie_ok = not expect_cookie
        self.senders: dict[int, str] = {}
        self.types: dict[int, str] = {}
        self.other = 0
        #: called as ``on_other(sender name, type name, message)`` for every other message
        #: (names ``None`` when never described)
        self.on_other = on_other

    def feed(self, data: bytes) -> list[PoseReport]:
        self.buf += data
        out: list[PoseReport] = []
        if not self.cookie_ok:
            if len(self.buf) < COOKIE_SIZE:
                return out
            check_cookie(bytes(self.buf[:COOKIE_SIZE]))
            del self.buf[:COOKIE_SIZE]
            self.cookie_ok = True
        while len(self.buf) >= 24:
            length, sec, usec, sender, mtype, _ = _HEADER.unpack_from(self.buf, 0)
            if length < 24 or length > MAX_MESSAGE:
                raise PacketError("bad length", f"VRPN message length {length}")
            total = 24 + _pad8(length - 24)
            if len(self.buf) < total:
                break
            payload = bytes(self.buf[24:length])
            del self.buf[:total]
            r = self.handle(Message(sec, usec, sender, mtype, payload))
            if r is not None:
                out.append(r)
        return out

    def handle(self, m: Message) -> PoseReport | None:
        if m.type in (SENDER_DESCRIPTION, TYPE_DESCRIPTION):
            if len(m.payload) < 4:
                raise PacketError("truncated", "VRPN description")
            (n,) = struct.unpack_from(">I", m.payload, 0)
            if n < 1 or 4 + n > len(m.payload):
                raise PacketError("bad length", f"VRPN description name of {n} bytes")
            name = m.payload[4 : 4 + n].split(b"\0", 1)[0].decode("ascii", "replace")
            (self.senders if m.type == SENDER_DESCRIPTION else self.types)[m.sender] = name
            return None
        if self.types.get(m.type) == POS_QUAT:
            if m.sender not in self.senders:
                raise PacketError("unknown sender", f"sender id {m.sender} was never described")
            if m.usec >= 1_000_000:
                raise PacketError("bad stamp", f"tv_usec {m.usec}")
            sensor, p, q = decode_pos_quat(m.payload)
            return PoseReport(self.senders[m.sender], sensor, p, q, m.sec, m.usec)
        self.other += 1
        if self.on_other is not None:
            self.on_other(self.senders.get(m.sender), self.types.get(m.type), m)
        return None
