"""rmw_zenoh's names, attachment and CDR messages, byte for byte (no sockets).

Golden values: the attachment is written out by hand from the format in
``trackflow/ros2/attachment.py`` and compared with Python Zenoh's own serializer
(``zenoh.ext.z_serialize``); a PoseStamped is assembled by hand from the CDR rules (4-byte
encapsulation header, little endian, each value aligned to its size from the start of the
body) and compared with ``rosbags``' serializer; the RIHS01 type hashes are the values
published for ROS 2 Jazzy (see docs/ros2.md for where they were checked).
"""

from __future__ import annotations

import struct

import numpy as np
import pytest

pytest.importorskip("rosbags", reason="rosbags is not installed (pip install .[ros])")

from trackflow.errors import FormatError
from trackflow.math import cov_from_ros, cov_to_ros, quat_exp
from trackflow.ros2 import (
    AttachmentError,
    MessageError,
    PoseCodec,
    decode_attachment,
    encode_attachment,
    entity_gid,
    entity_token,
    node_token,
    qos_keyexpr,
    topic_keyexpr,
)

T_NS = 1_700_000_000_123_456_789
GID = bytes(range(16))
#: RIHS01 hashes of ROS 2 Jazzy (also Kilted and Rolling: these definitions did not change)
HASHES = {
    "PoseStamped": "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",
    "PoseWithCovarianceStamped": (
        "RIHS01_26432f9803e43727d3c8f668d1fdb3c630f548af631e2f4e31382371bfea3b6e"
    ),
    "TransformStamped": "RIHS01_0a241f87d04668d94099cbb5ba11691d5ad32c2f29682e4eb5653424bd275206",
    "TFMessage": "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
}


# -- attachment -----------------------------------------------------------------------------------
def _golden_attachment(seq: int, stamp: int, gid: bytes) -> bytes:
    return (
        bytes([15]) + b"sequence_number" + struct.pack("<q", seq)
        + bytes([16]) + b"source_timestamp" + struct.pack("<q", stamp)
        + bytes([10]) + b"source_gid" + bytes([16]) + gid
    )  # fmt: skip


def test_attachment_golden_bytes():
    got = encode_attachment(7, T_NS, GID)
    assert got == _golden_attachment(7, T_NS, GID)
    assert got.hex() == (
        "0f73657175656e63655f6e756d6265720700000000000000"
        "10736f757263655f74696d657374616d7015cd853dfe9c9717"
        "0a736f757263655f676964100001020304050607""08090a0b0c0d0e0f"
    )  # fmt: skip
    assert decode_attachment(got) == (7, T_NS, GID)


def test_attachment_matches_zenoh_serializer():
    ext = pytest.importorskip("zenoh.ext", reason="eclipse-zenoh is not installed")
    for seq, stamp in ((1, 0), (7, T_NS), (2**63 - 1, -1)):
        ref = ext.z_serialize(
            ("sequence_number", ext.Int64(seq), "source_timestamp", ext.Int64(stamp),
             "source_gid", GID)
        ).to_bytes()  # fmt: skip
        assert encode_attachment(seq, stamp, GID) == ref
        zenoh = pytest.importorskip("zenoh")
        kinds = tuple[str, ext.Int64, str, ext.Int64, str, bytes]
        back = ext.z_deserialize(kinds, zenoh.ZBytes(encode_attachment(seq, stamp, GID)))
        assert (int(back[1]), int(back[3]), back[5]) == (seq, stamp, GID)


@pytest.mark.parametrize(
    "data",
    [
        b"",
        b"garbage",
        _golden_attachment(1, 2, GID)[:-1],  # cut short
        _golden_attachment(1, 2, GID) + b"\0",  # bytes after the GID
        _golden_attachment(1, 2, GID).replace(b"source_gid", b"source_gix"),
        _golden_attachment(1, 2, GID).replace(b"\x10" + GID, b"\x0f" + GID[:15]),  # 15 bytes
        _golden_attachment(1, 2, GID)[:20],
    ],
)
def test_attachment_malformed(data):
    with pytest.raises(AttachmentError):
        decode_attachment(data)
    assert issubclass(AttachmentError, FormatError)


def test_attachment_refuses_a_short_gid():
    with pytest.raises(ValueError):
        encode_attachment(1, 2, b"\0" * 15)


# -- names ----------------------------------------------------------------------------------------
def test_type_hashes():
    for short, h in HASHES.items():
        assert PoseCodec(short).type_hash == h


def test_topic_key_expression():
    msgtype = "geometry_msgs/msg/PoseWithCovarianceStamped"
    assert topic_keyexpr(0, "/trackflow/head", msgtype, HASHES["PoseWithCovarianceStamped"]) == (
        "0/trackflow/head/geometry_msgs::msg::dds_::PoseWithCovarianceStamped_/"
        + HASHES["PoseWithCovarianceStamped"]
    )
    assert topic_keyexpr(7, "/tf", "tf2_msgs/msg/TFMessage", "*") == (
        "7/tf/tf2_msgs::msg::dds_::TFMessage_/*"
    )


def test_qos_chunk():
    assert qos_keyexpr() == "::,10:,:,:,,"  # reliable, volatile, keep last 10
    assert qos_keyexpr(depth=42) == "::,:,:,:,,"  # rmw_zenoh's defaults
    assert qos_keyexpr(depth=100) == "::,100:,:,:,,"
    assert qos_keyexpr(transient_local=True, depth=1) == ":1:,1:,:,:,,"
    assert qos_keyexpr(reliable=False, keep_all=True) == "2::2,10:,:,:,,"


def test_liveliness_tokens():
    zid = "a346378c976254ee14fe2c719982d1c2"
    assert node_token(0, zid, 1, "trackflow") == f"@ros2_lv/0/{zid}/1/1/NN/%/%/trackflow"
    msgtype = "geometry_msgs/msg/PoseStamped"
    token = entity_token(
        "MP", 0, zid, 1, 2, "trackflow", "/trackflow/head", msgtype, HASHES["PoseStamped"],
        qos_keyexpr(),
    )  # fmt: skip
    assert token == (
        f"@ros2_lv/0/{zid}/1/2/MP/%/%/trackflow/%trackflow%head/"
        f"geometry_msgs::msg::dds_::PoseStamped_/{HASHES['PoseStamped']}/::,10:,:,:,,"
    )
    assert len(entity_gid(token)) == 16
    assert entity_gid(token) != entity_gid(token.replace("/MP/", "/MS/"))
    with pytest.raises(ValueError):
        entity_token("XX", 0, zid, 1, 2, "n", "/t", "a/msg/B", "h", "q")


# -- CDR ------------------------------------------------------------------------------------------
def _golden_pose_stamped(t_ns, frame, p, q) -> bytes:
    """A PoseStamped by the CDR rules: header 00 01 00 00, then little endian, each value
    aligned to its size from the start of the body."""
    body = struct.pack("<iI", t_ns // 10**9, t_ns % 10**9)
    name = frame.encode() + b"\0"
    body += struct.pack("<I", len(name)) + name
    body += b"\0" * (-len(body) % 8)  # the doubles start at a multiple of 8
    body += struct.pack("<7d", *p, *q)
    return b"\x00\x01\x00\x00" + body


def test_pose_stamped_golden_bytes():
    p, q = (1.5, -2.0, 0.25), (0.0, 0.0, 0.6, 0.8)
    golden = _golden_pose_stamped(T_NS, "room", p, q)
    codec = PoseCodec("PoseStamped")
    got = codec.encode(T_NS, "room", "head", p, q)
    assert got == golden
    store = codec.store
    ref = store.serialize_cdr(store.deserialize_cdr(golden, codec.msgtype), codec.msgtype)
    assert bytes(ref) == golden
    (pose,) = codec.decode(golden)
    assert pose.stamp_ns == T_NS and pose.frame_id == "room" and pose.child_frame_id is None
    assert pose.position == p and pose.quaternion == q and pose.covariance is None


def test_covariance_converted_at_the_boundary(rng):
    codec = PoseCodec("PoseWithCovarianceStamped")
    q = quat_exp(np.array([0.3, -0.2, 0.9]))
    a = rng.normal(size=(6, 6))
    cov = a @ a.T * 1e-4
    data = codec.encode(T_NS, "room", "head", (1.0, 2.0, 3.0), q, cov)
    msg = codec.store.deserialize_cdr(data, codec.msgtype)  # rosbags, independently
    ros = np.asarray(msg.pose.covariance).reshape(6, 6)
    np.testing.assert_allclose(ros, cov_to_ros(cov, q), rtol=1e-12, atol=1e-18)
    np.testing.assert_array_equal(ros, ros.T)
    (pose,) = codec.decode(data)
    np.testing.assert_allclose(cov_from_ros(pose.covariance, q), cov, rtol=1e-10, atol=1e-16)
    # unknown covariance (-1 first, or all zeros) reads as None
    unknown = codec.encode(T_NS, "room", "head", (1.0, 2.0, 3.0), q, None)
    assert codec.decode(unknown)[0].covariance is None


def test_tf_message_holds_one_transform():
    codec = PoseCodec("TFMessage")
    data = codec.encode(T_NS, "room", "head", (1.0, 2.0, 3.0), (0.0, 0.0, 0.0, 1.0))
    msg = codec.store.deserialize_cdr(data, "tf2_msgs/msg/TFMessage")
    (tr,) = msg.transforms
    assert (tr.header.frame_id, tr.child_frame_id) == ("room", "head")
    assert (tr.transform.translation.x, tr.transform.rotation.w) == (1.0, 1.0)
    (pose,) = codec.decode(data)
    assert (pose.frame_id, pose.child_frame_id, pose.stamp_ns) == ("room", "head", T_NS)


@pytest.mark.parametrize(
    "data",
    [
        b"",
        b"\x00\x01",
        b"garbage that is no CDR",
        _golden_pose_stamped(T_NS, "room", (0, 0, 0), (0, 0, 0, 1))[:40],
        b"\x00\x01\x00\x00" + b"\xff" * 80,  # a string length of 4 GB
        b"\x00\x01\x00\x00" + b"\0" * (1 << 20),  # larger than MAX_PAYLOAD
    ],
)
def test_malformed_payloads_are_message_errors(data):
    with pytest.raises(MessageError):
        PoseCodec("PoseStamped").decode(data)
