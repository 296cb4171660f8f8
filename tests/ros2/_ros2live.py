"""Helpers for the ROS 2 tests on real loopback sockets: a Zenoh router standing in for the
ROS 2 system's ``rmw_zenohd``, a ROS 2 style publisher and an independent decoder (rosbags'
own type store and Zenoh's own deserializer, not trackflow's code)."""

from __future__ import annotations

import json
import socket
import threading
import time

import numpy as np
import zenoh
import zenoh.ext as ext
from rosbags.typesys import Stores, get_typestore

STORE = get_typestore(Stores.LATEST)  # (rosbags 0.10, the oldest supported, has no JAZZY)
HASH = {
    "geometry_msgs/msg/PoseStamped": STORE.hash_rihs01("geometry_msgs/msg/PoseStamped"),
    "geometry_msgs/msg/PoseWithCovarianceStamped": STORE.hash_rihs01(
        "geometry_msgs/msg/PoseWithCovarianceStamped"
    ),
    "tf2_msgs/msg/TFMessage": STORE.hash_rihs01("tf2_msgs/msg/TFMessage"),
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def key(domain: int, topic: str, msgtype: str) -> str:
    pkg, kind, name = msgtype.split("/")
    return f"{domain}/{topic.strip('/')}/{pkg}::{kind}::dds_::{name}_/{HASH[msgtype]}"


class Router:
    """A Zenoh router on ``tcp/127.0.0.1:<port>`` (a free one by default; no multicast) that
    records every sample of ``watch`` key expressions and every ROS 2 graph token."""

    def __init__(self, port: int | None = None):
        self.endpoint = f"tcp/127.0.0.1:{port or free_port()}"
        c = zenoh.Config()
        c.insert_json5("mode", '"router"')
        c.insert_json5("listen/endpoints", json.dumps([self.endpoint]))
        c.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(c)
        self.samples: dict[str, list] = {}
        self.tokens: list[tuple[str, str]] = []
        self._lock = threading.Lock()
        self._subs = [
            self.session.liveliness().declare_subscriber(
                "@ros2_lv/**", self._on_token, history=True
            )
        ]

    def _on_token(self, sample) -> None:
        with self._lock:
            self.tokens.append((str(sample.kind).rsplit(".", 1)[-1], str(sample.key_expr)))

    def watch(self, keyexpr: str) -> list:
        """Record ``(key, payload, attachment, arrival_ns)`` of every sample on ``keyexpr``."""
        got = self.samples.setdefault(keyexpr, [])

        def on(sample) -> None:
            att = sample.attachment
            with self._lock:
                got.append((str(sample.key_expr), sample.payload.to_bytes(),
                            None if att is None else att.to_bytes(), time.time_ns()))  # fmt: skip

        self._subs.append(self.session.declare_subscriber(keyexpr, on))
        return got

    def live_tokens(self) -> set[str]:
        with self._lock:
            alive: set[str] = set()
            for kind, k in self.tokens:
                (alive.add if kind == "PUT" else alive.discard)(k)
            return alive

    def wait_token(self, part: str, timeout: float = 300.0) -> str:
        """The first live graph token containing ``part`` (waits for it)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            hits = [t for t in self.live_tokens() if part in t]
            if hits:
                return hits[0]
            time.sleep(0.05)
        raise AssertionError(f"no token with {part!r}; have {sorted(self.live_tokens())}")

    def publisher(self, keyexpr: str, timeout: float = 60.0):
        """A publisher on ``keyexpr`` once a subscriber has matched it (a subscriber's
        declaration reaches the router a moment after it is made; a message put before then
        reaches nobody, as with any ROS 2 topic)."""
        pub = self.session.declare_publisher(keyexpr)
        deadline = time.monotonic() + timeout
        while not pub.matching_status.matching:
            if time.monotonic() > deadline:
                pub.undeclare()
                raise AssertionError(f"no subscriber matched {keyexpr!r} in {timeout} s")
            time.sleep(0.02)
        return pub

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
        self.session.close()


def attachment(seq: int, stamp: int, gid: bytes) -> bytes:
    """An rmw_zenoh attachment written by Zenoh's own serializer."""
    return ext.z_serialize(
        ("sequence_number", ext.Int64(seq), "source_timestamp", ext.Int64(stamp),
         "source_gid", gid)
    ).to_bytes()  # fmt: skip


def read_attachment(data: bytes) -> tuple[int, int, bytes]:
    """``(sequence number, source timestamp, gid)`` read by Zenoh's own deserializer."""
    kinds = tuple[str, ext.Int64, str, ext.Int64, str, bytes]
    k1, seq, k2, stamp, k3, gid = ext.z_deserialize(kinds, zenoh.ZBytes(data))
    assert (k1, k2, k3) == ("sequence_number", "source_timestamp", "source_gid")
    return int(seq), int(stamp), gid


def pose_message(msgtype: str, t_ns: int, frame_id: str, p, q, ros_cov=None) -> bytes:
    """CDR bytes of a PoseStamped or PoseWithCovarianceStamped built with rosbags alone."""
    T = STORE.types
    stamp = T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
    hdr = T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)
    pose = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
        orientation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
    )
    if msgtype.endswith("PoseStamped") and "Covariance" not in msgtype:
        msg = T[msgtype](header=hdr, pose=pose)
    else:
        cov = np.zeros(36) if ros_cov is None else np.asarray(ros_cov, float).ravel()
        pwc = T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov)
        msg = T[msgtype](header=hdr, pose=pwc)
    return bytes(STORE.serialize_cdr(msg, msgtype))
