"""VRPN: golden cookie and messages, stream cutting at any split, bad streams."""

from __future__ import annotations

import struct

import pytest

from trackflow.trackers import PacketError
from trackflow.trackers.vrpn import (
    POS_QUAT,
    StreamDecoder,
    check_cookie,
    encode_description,
    encode_message,
    encode_pos_quat,
    make_cookie,
)

COOKIE = b"vrpn: ver. 07.38  0\0\0\0\0\0"  # VRPN's version since 2025 (vrpn_Connection.C)


def _golden_stream() -> bytes:
    """Cookie, sender 0 = "Tracker0", type 3 = Pos_Quat, one report of sensor 2 at
    1712345678.5 s, written field by field (big-endian, 24-byte header, 8-byte padding)."""
    out = COOKIE
    name = b"Tracker0\0"
    body = struct.pack(">I", len(name)) + name  # 13 bytes -> padded to 16
    out += struct.pack(">IIIiiI", 24 + len(body), 0, 0, 0, -1, 0) + body + b"\0" * 3
    tname = b"vrpn_Tracker Pos_Quat\0"
    body = struct.pack(">I", len(tname)) + tname  # 26 -> 32
    out += struct.pack(">IIIiiI", 24 + len(body), 0, 0, 3, -2, 0) + body + b"\0" * 6
    rep = struct.pack(">ii3d4d", 2, 0, 0.5, -1.25, 2.0, 0.0, 0.0, 0.6, 0.8)  # 64 bytes
    out += struct.pack(">IIIiiI", 24 + 64, 1712345678, 500000, 0, 3, 0) + rep
    return out


def _encoded_stream() -> bytes:
    return (
        make_cookie()
        + encode_description(-1, 0, "Tracker0")
        + encode_description(-2, 3, POS_QUAT)
        + encode_message(
            1712345678, 500000, 0, 3, encode_pos_quat(2, (0.5, -1.25, 2.0), (0, 0, 0.6, 0.8))
        )
    )


def test_encoder_writes_golden_bytes():
    assert make_cookie() == COOKIE
    assert _encoded_stream() == _golden_stream()


def test_golden_stream_decodes():
    d = StreamDecoder()
    (r,) = d.feed(_golden_stream())
    assert r.device == "Tracker0" and r.sensor == 2
    assert r.position == (0.5, -1.25, 2.0) and r.quaternion == (0.0, 0.0, 0.6, 0.8)
    assert (r.sec, r.usec) == (1712345678, 500000)


def test_any_split_gives_the_same_reports():
    raw = _golden_stream() * 1
    raw += encode_message(5, 6, 0, 3, encode_pos_quat(0, (1, 2, 3), (0, 0, 0, 1)))
    for cut in range(0, len(raw), 7):
        d = StreamDecoder()
        got = d.feed(raw[:cut]) + d.feed(raw[cut:])
        assert [(r.sensor, r.sec) for r in got] == [(2, 1712345678), (0, 5)]


def test_other_messages_are_counted_not_decoded():
    d = StreamDecoder()
    d.feed(_golden_stream() + encode_description(-2, 4, "vrpn_Tracker Velocity"))
    assert d.feed(encode_message(0, 0, 0, 4, b"\0" * 72)) == [] and d.other == 1


@pytest.mark.parametrize(
    "data, reason",
    [
        (b"vrpn: ver. 06.00  0\0\0\0\0\0", "wrong version"),
        (b"HTTP/1.1 200 OK\r\n\r\nxxxxxxxx", "wrong version"),
        (COOKIE + struct.pack(">IIIiiI", 3, 0, 0, 0, 0, 0), "bad length"),
        (COOKIE + struct.pack(">IIIiiI", 1 << 30, 0, 0, 0, 0, 0), "bad length"),
        (COOKIE + encode_message(0, 0, 9, -1, b"\0\0"), "truncated"),
        (COOKIE + encode_message(0, 0, 9, -2, struct.pack(">I", 99) + b"x"), "bad length"),
    ],
)
def test_bad_streams_are_typed(data, reason):
    with pytest.raises(PacketError) as e:
        StreamDecoder().feed(data)
    assert e.value.reason == reason


def test_report_from_undescribed_sender_is_rejected():
    d = StreamDecoder()
    d.feed(COOKIE + encode_description(-2, 3, POS_QUAT))
    with pytest.raises(PacketError, match="unknown sender"):
        d.feed(encode_message(0, 0, 5, 3, encode_pos_quat(0, (0, 0, 0), (0, 0, 0, 1))))
    with pytest.raises(PacketError, match="truncated"):
        check_cookie(b"vrpn")


@pytest.mark.parametrize(
    "cookie, ok",
    [
        (b"vrpn: ver. 07.35  0\0\0\0\0\0", True),  # an older minor version: accepted
        (b"vrpn: ver. 07.38  1\0\0\0\0\0", True),  # a logging peer
        (b"vrpn: ver. 08.00  0\0\0\0\0\0", False),  # another major version
        (b"vrpn: ver. 04.00  0\0\0\0\0\0", False),  # VRPN's log-file cookie
    ],
)
def test_cookie_versions(cookie, ok):
    if ok:
        check_cookie(cookie)
    else:
        with pytest.raises(PacketError, match="wrong version"):
            check_cookie(cookie)


def _read_exactly(conn, n: int) -> bytes:
    out = b""
    while len(out) < n:
        chunk = conn.recv(n - len(out))
        assert chunk, f"the server closed after {len(out)} of {n} bytes"
        out += chunk
    return out


def _description_bytes(kind: int, local_id: int, name: bytes) -> bytes:
    """A description written from the protocol: header (length = 24 + 4 + name + NUL),
    u32 name length, the name and its NUL, padded to 8."""
    body = struct.pack(">I", len(name) + 1) + name + b"\0"
    pad = b"\0" * (-len(body) % 8)
    return struct.pack(">IIIiiI", 24 + len(body), 0, 0, local_id, kind, 0) + body + pad


def test_the_server_answers_a_ping_with_a_pong_on_the_device_sender():
    """Golden bytes of the exchange a VRPN client's device makes (vrpn_BaseClass.C): the
    client describes its sender ``Tracker0`` (id 5) and the type ``vrpn_Base ping_message``
    (id 7) and pings; the server's greeting is its cookie and descriptions (sender 0, types
    0 Pos_Quat and 1 pong), and its answer a 24-byte header of type 1 on sender 0, no body,
    stamped now."""
    import socket
    import time

    from trackflow.trackers.vrpn_server import VrpnTrackerServer

    with VrpnTrackerServer("Tracker0", "127.0.0.1", 0) as server:
        with socket.create_connection(("127.0.0.1", server.port), timeout=10) as c:
            assert _read_exactly(c, 24) == COOKIE
            c.sendall(b"vrpn: ver. 07.38  0\0\0\0\0\0")  # the server waits for it
            greeting = (
                _description_bytes(-1, 0, b"Tracker0")
                + _description_bytes(-2, 0, b"vrpn_Tracker Pos_Quat")
                + _description_bytes(-2, 1, b"vrpn_Base pong_message")
            )
            assert _read_exactly(c, len(greeting)) == greeting
            c.sendall(
                _description_bytes(-1, 5, b"Tracker0")
                + _description_bytes(-2, 7, b"vrpn_Base ping_message")
                + _description_bytes(-1, 6, b"Other0")
            )
            before = time.time()
            c.sendall(struct.pack(">IIIiiI", 24, 1, 2, 5, 7, 0))  # ping Tracker0
            c.sendall(struct.pack(">IIIiiI", 24, 1, 2, 6, 7, 0))  # ping another device
            c.sendall(struct.pack(">IIIiiI", 24, 1, 2, 5, 7, 0))  # ping again
            first, second = _read_exactly(c, 24), _read_exactly(c, 24)
            after = time.time()
    for pong in (first, second):
        length, sec, usec, sender, kind, zero = struct.unpack(">IIIiiI", pong)
        assert (length, sender, kind, zero) == (24, 0, 1, 0)
        assert int(before) <= sec + usec * 1e-6 <= after + 1 and usec < 1_000_000
    assert server.pongs == 2 and server.rejections == {"ping for another device": 1}
