"""NatNet: golden frames of every version packed field by field from the format description,
the handshake messages, model definitions, clock ticks, and the ``natnet`` package as oracle."""

from __future__ import annotations

import struct

import pytest

from trackflow.trackers import PacketError
from trackflow.trackers.natnet import (
    FRAMEOFDATA,
    SUPPORTED_VERSIONS,
    ModelDefinitions,
    NatNetFrame,
    NatNetRigidBody,
    RigidBodyDescription,
    ServerInfo,
    decode_frame,
    decode_message,
    decode_model_definitions,
    decode_server_info,
    encode_frame,
    encode_model_definitions,
    encode_server_info,
    exposure_and_latency,
)

BODIES = (
    NatNetRigidBody(1, (0.5, -0.25, 1.75), (0.0, 0.0, 0.6, 0.8), 0.00025, True),
    NatNetRigidBody(7, (1.0, 2.0, 3.0), (0.5, 0.5, 0.5, 0.5), 0.001, False),
)


def golden(v) -> bytes:
    """A frame with two rigid bodies, one marker set and two labeled markers, written from
    the section list in ``trackflow.trackers.natnet``'s docstring (not with the encoder)."""
    le = "<"
    sized = v >= (4, 1)

    def section(n, body):
        return struct.pack("<i", n) + (struct.pack("<I", len(body)) if sized else b"") + body

    out = struct.pack("<i", 4242)
    out += section(1, b"all\0" + struct.pack("<i3f", 1, 0.1, 0.2, 0.3))
    out += section(0, b"")
    rbs = b""
    for b in BODIES:
        rbs += struct.pack(le + "i3f4f", b.id, *b.position, *b.quaternion)
        if v < (3, 0):
            rbs += struct.pack("<i", 0)  # no inline markers
        if v >= (2, 0):
            rbs += struct.pack("<f", b.mean_error)
        if v >= (2, 6):
            rbs += struct.pack("<h", 1 if b.valid else 0)
    out += section(2, rbs)
    if v >= (2, 1):
        out += section(0, b"")  # skeletons
    if v >= (4, 1):
        out += section(1, b"\x07" * 20)  # an asset the decoder skips by size
    if v >= (2, 3):
        item = 20 + (2 if v >= (2, 6) else 0) + (4 if v >= (3, 0) else 0)
        out += section(2, b"\0" * 2 * item)
    if v >= (2, 9):
        out += section(0, b"")
    if v >= (2, 11):
        out += section(0, b"")
    if v < (3, 0):
        out += struct.pack("<f", 0.0)  # software latency
    out += struct.pack("<II", 0, 0)
    out += struct.pack("<d" if v >= (2, 7) else "<f", 12.5)
    if v >= (3, 0):
        out += struct.pack("<QQQ", 10_000_000, 10_020_000, 10_045_000)
    if v >= (4, 1):
        out += struct.pack("<II", 1712345678, 123)
    out += struct.pack("<h", 0) + struct.pack("<i", 0)
    return struct.pack("<HH", FRAMEOFDATA, len(out)) + out


def frame_for(v) -> NatNetFrame:
    hires = v >= (3, 0)
    return NatNetFrame(
        4242,
        BODIES,
        12.5,
        10_000_000 if hires else None,
        10_020_000 if hires else None,
        10_045_000 if hires else None,
        (1712345678, 123) if v >= (4, 1) else None,
        marker_sets=(("all", ((0.1, 0.2, 0.3),)),),
        labeled_markers=2 if v >= (2, 3) else 0,
        software_latency=0.0 if v < (3, 0) else None,
    )


def _f32(x):
    return struct.unpack("<f", struct.pack("<f", x))[0]


@pytest.mark.parametrize("v", SUPPORTED_VERSIONS)
def test_golden_frame_every_version(v):
    raw = golden(v)
    msg, payload = decode_message(raw)
    assert msg == FRAMEOFDATA
    f = decode_frame(payload, v)
    assert f.frame == 4242 and len(f.rigid_bodies) == 2
    b = f.body(1)
    assert b.position == tuple(_f32(x) for x in BODIES[0].position)
    assert b.quaternion == tuple(_f32(x) for x in BODIES[0].quaternion)
    if v >= (2, 0):
        assert b.mean_error == _f32(0.00025)
    if v >= (2, 6):
        assert b.valid is True and f.body(7).valid is False
    assert f.timestamp == 12.5
    if v >= (3, 0):
        assert (f.mid_exposure, f.data_received, f.transmit) == (10_000_000, 10_020_000, 10_045_000)
    if v >= (4, 1):
        assert f.precision == (1712345678, 123)
    assert f.marker_sets == (("all", ((_f32(0.1), _f32(0.2), _f32(0.3)),)),)


@pytest.mark.parametrize("v", SUPPORTED_VERSIONS)
def test_encoder_writes_the_golden_bytes(v):
    assets = (b"\x07" * 20, 1) if v >= (4, 1) else None
    assert encode_frame(frame_for(v), v, assets=assets) == golden(v)


@pytest.mark.parametrize("v", [(3, 0), (3, 1), (4, 0)])
def test_natnet_package_oracle_agrees(v):
    natnet = pytest.importorskip("natnet")
    from natnet.data_frame import DataFrame
    from natnet.packet_buffer import PacketBuffer
    from natnet.version import Version

    payload = golden(v)[4:]
    theirs = DataFrame.read_from_buffer(PacketBuffer(payload), Version(*v))
    ours = decode_frame(payload, v)
    assert natnet is not None and theirs.prefix.frame_number == ours.frame
    for a, b in zip(theirs.rigid_bodies, ours.rigid_bodies, strict=True):
        assert a.id_num == b.id and tuple(a.pos) == b.position and tuple(a.rot) == b.quaternion
        assert a.tracking_valid == b.valid and a.marker_error == b.mean_error
    s = theirs.suffix
    assert s.timestamp == ours.timestamp
    assert (s.stamp_camera_mid_exposure, s.stamp_transmit) == (ours.mid_exposure, ours.transmit)


def test_natnet_package_misreads_4_1_flags():
    """The reason the package is only an oracle: it ignores the 4.1 precision timestamp,
    so it reads the frame flags from the wrong bytes (ours come out right)."""
    pytest.importorskip("natnet")
    from natnet.data_frame import DataFrame
    from natnet.packet_buffer import PacketBuffer
    from natnet.version import Version

    fr = frame_for((4, 1))
    fr = NatNetFrame(**{**{k: getattr(fr, k) for k in fr.__slots__}, "params": 2})
    payload = encode_frame(fr, (4, 1))[4:]
    assert decode_frame(payload, (4, 1)).params == 2
    theirs = DataFrame.read_from_buffer(PacketBuffer(payload), Version(4, 1))
    assert theirs.suffix.param != 2


def test_server_info_and_clock():
    info = ServerInfo("Motive", (3, 1, 0, 0), (4, 1, 0, 0), 10_000_000, 1511, False)
    raw = encode_server_info(info)
    # SERVERINFO: u16 id 1, u16 size, name[256], app version, NatNet version, u64 frequency,
    # u16 data port, bool multicast, 4 group bytes
    expect = struct.pack("<HH", 1, 279) + b"Motive" + b"\0" * 250 + bytes((3, 1, 0, 0, 4, 1, 0, 0))
    expect += struct.pack("<QH?", 10_000_000, 1511, False) + bytes((239, 255, 42, 99))
    assert raw == expect
    msg, payload = decode_message(raw)
    assert msg == 1 and decode_server_info(payload) == info
    old = ServerInfo("Motive", (1, 10, 0, 0), (2, 9, 0, 0))
    assert decode_server_info(decode_message(encode_server_info(old))[1]).clock_frequency is None
    with pytest.raises(PacketError, match="wrong version"):
        decode_server_info(
            decode_message(encode_server_info(ServerInfo(natnet_version=(9, 0, 0, 0))))[1]
        )


def test_exposure_and_latency_from_ticks():
    f = frame_for((4, 1))
    tx, exp, lat = exposure_and_latency(f, 10_000_000)
    assert (
        tx == pytest.approx(1.0045) and exp == pytest.approx(1.0) and lat == pytest.approx(0.0045)
    )
    assert exposure_and_latency(frame_for((2, 9)), 10_000_000) is None
    bad = NatNetFrame(1, (), 0.0, 100, 0, 50)
    with pytest.raises(PacketError, match="bad stamps"):
        exposure_and_latency(bad, 10_000_000)


@pytest.mark.parametrize("v", [(2, 9), (3, 1), (4, 0), (4, 1)])
def test_model_definitions(v):
    defs = ModelDefinitions((RigidBodyDescription("head", 1), RigidBodyDescription("hand", 7, 1)))
    got = decode_model_definitions(decode_message(encode_model_definitions(defs, v))[1], v)
    assert got.id_of("head") == 1 and got.id_of("hand") == 7 and got.id_of("foot") is None


def test_model_definitions_skip_unknown_types_by_size():
    # one camera description (type 5, unknown here) then a rigid body, NatNet 4.1
    cam = struct.pack("<i", 5) + struct.pack("<I", 8) + b"\x01" * 8
    rb = b"head\0" + struct.pack("<ii3fi", 3, -1, 0, 0, 0, 0)
    payload = struct.pack("<i", 2) + cam + struct.pack("<iI", 1, len(rb)) + rb
    got = decode_model_definitions(payload, (4, 1))
    assert got.complete and got.id_of("head") == 3
    older = struct.pack("<i", 2) + struct.pack("<i", 5) + b"\x01" * 8
    assert decode_model_definitions(older, (3, 1)).complete is False


@pytest.mark.parametrize("bad_size", [3, 30])
def test_one_bad_description_is_skipped_not_the_definitions(bad_size):
    """NatNet 4.1: a rigid body description whose declared size does not fit its content
    (too short: the name runs past it; too long: bytes left over) is skipped by that size
    and counted; the descriptions around it still give their names."""

    def rb(name, bid, size=None):
        body = name + b"\0" + struct.pack("<ii3fi", bid, -1, 0, 0, 0, 0)
        return (
            struct.pack("<iI", 1, len(body) if size is None else size)
            + body.ljust(size or len(body), b"\0")[: size or len(body)]
        )

    payload = struct.pack("<i", 3) + rb(b"head", 3) + rb(b"hand", 5, bad_size) + rb(b"foot", 9)
    got = decode_model_definitions(payload, (4, 1))
    assert got.id_of("head") == 3 and got.id_of("foot") == 9 and got.id_of("hand") is None
    assert got.skipped == 1 and got.complete


@pytest.mark.parametrize(
    "data, version, reason",
    [
        (b"\x07\x00", (4, 1), "truncated"),
        (struct.pack("<HH", 7, 100) + b"\0" * 10, (4, 1), "truncated"),
        (golden((3, 1))[:-40], (3, 1), "truncated"),
        (golden((4, 1)), (5, 0), "wrong version"),
        (golden((4, 1)), (1, 4), "wrong version"),
    ],
)
def test_bad_frames_are_typed(data, version, reason):
    with pytest.raises(PacketError) as e:
        decode_frame(decode_message(data)[1], version)
    assert e.value.reason == reason


def test_4_1_section_size_mismatch_is_rejected():
    raw = bytearray(golden((4, 1)))
    # the rigid body section size sits after: header 4, frame 4, marker sets 8+20,
    # unlabeled 8, then the rigid body count (4) and size (4)
    off = 4 + 4 + 8 + 20 + 8 + 4
    assert struct.unpack_from("<I", raw, off)[0] == 76
    struct.pack_into("<I", raw, off, 70)
    with pytest.raises(PacketError) as e:
        decode_frame(decode_message(bytes(raw))[1], (4, 1))
    assert e.value.reason in ("bad size", "truncated", "bad count")


def test_connect_request_bytes():
    from trackflow.trackers.natnet import encode_connect

    raw = encode_connect((4, 1, 0, 0))
    assert raw[:8] == b"\x00\x00\x0e\x01Ping" and len(raw) == 4 + 270
    assert raw[4 + 265 : 4 + 269] == bytes((4, 1, 0, 0)) and raw[-1:] == b"\0"
    assert decode_message(raw)[0] == 0


def test_natnet_package_skips_the_2x_software_latency():
    """Before 3.0 the suffix starts with the software latency (f32), as the SDK's packet
    clients read it; the package skips it, so its timestamp is wrong (its bodies agree)."""
    pytest.importorskip("natnet")
    from natnet.data_frame import DataFrame
    from natnet.packet_buffer import PacketBuffer
    from natnet.version import Version

    payload = golden((2, 9))[4:]
    theirs = DataFrame.read_from_buffer(PacketBuffer(payload), Version(2, 9))
    ours = decode_frame(payload, (2, 9))
    assert [tuple(b.pos) for b in theirs.rigid_bodies] == [b.position for b in ours.rigid_bodies]
    assert ours.timestamp == 12.5 and theirs.suffix.timestamp != 12.5
