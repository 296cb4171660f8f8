"""Pose messages of ROS 2 topics as bytes: CDR (the 4-byte encapsulation header, then little
endian), written and read by ``rosbags``' type store, the same one trackflow's ROS bags use
(:func:`trackflow.io.ros_typestore`), and their RIHS01 type hashes computed from its type
descriptions (``docs/ros2.md`` says how they were checked).

Frames and covariance follow the bag readers and writers (:mod:`trackflow.io`): a message's
``header.frame_id`` is the source frame, its ``child_frame_id`` the target; ROS's
``PoseWithCovariance`` perturbs the rotation about the fixed axes of ``frame_id`` and is
converted at this boundary with :func:`trackflow.math.cov_to_ros` /
:func:`trackflow.math.cov_from_ros`. A ROS covariance with ``-1`` first or all zeros means
"unknown".
"""

from __future__ import annotations

import struct
from typing import NamedTuple

import numpy as np

from ..errors import FormatError
from ..io import MESSAGE_TYPES, pose_fields, pose_message, ros_stamp_ns, ros_typestore
from ..math import cov_to_ros
from ..optional import require

__all__ = ["MAX_PAYLOAD", "MessageError", "PoseCodec", "RosPose", "type_hash"]

#: the largest payload decoded (bytes); a larger one is a counted rejection
MAX_PAYLOAD = 1 << 20
_COVARIANCE_TYPES = ("PoseWithCovarianceStamped",)
#: plain CDR, big or little endian (the first two bytes of every payload)
_ENCAPSULATIONS = (b"\x00\x00", b"\x00\x01")


class MessageError(FormatError):
    """A payload that is not a CDR message of the topic's type (a counted rejection)."""


class RosPose(NamedTuple):
    """One pose read from a message, as ROS has it.

    ``stamp_ns`` is ``header.stamp`` [ns]; ``position`` (3,) and ``quaternion`` (4,)
    ``(x, y, z, w)`` as sent (not checked); ``covariance`` the (6, 6) matrix in ROS's order
    and convention, ``None`` when the message has none or marks it unknown.
    """

    stamp_ns: int
    frame_id: str
    child_frame_id: str | None
    position: tuple
    quaternion: tuple
    covariance: np.ndarray | None


def _store():
    require("rosbags", extra="ros", feature="ROS 2 topics")
    return ros_typestore(False)


def type_hash(msgtype: str) -> str:
    """The RIHS01 type hash (REP 2011) of ``msgtype`` (full name, ``pkg/msg/Name``): the
    SHA-256 of its type description, computed by ``rosbags``."""
    return _store().hash_rihs01(msgtype)


def _ros_covariance(cov) -> np.ndarray | None:
    c = np.asarray(cov, dtype=float)
    if c.size != 36 or c[0] == -1.0 or not c.any():
        return None
    return c.reshape(6, 6)


class PoseCodec:
    """Encode and decode the pose messages of one type (a short name of
    :data:`trackflow.io.MESSAGE_TYPES`: ``PoseStamped``, ``PoseWithCovarianceStamped``,
    ``TransformStamped``, ``TFMessage``)."""

    def __init__(self, short: str):
        if short not in MESSAGE_TYPES:
            raise ValueError(f"ROS 2 message type {short!r}: not one of {sorted(MESSAGE_TYPES)}")
        self.short = short
        self.msgtype = MESSAGE_TYPES[short]
        self.store = _store()
        self.type_hash = self.store.hash_rihs01(self.msgtype)
        from rosbags.serde import SerdeError

        # what rosbags' generated deserialisers raise on bytes that are no such message; the
        # oldest supported rosbags (0.10) checks the message's length with an assert
        self._errors = (SerdeError, struct.error, ValueError, IndexError, TypeError,
                        AttributeError, OverflowError, MemoryError, UnicodeDecodeError,
                        AssertionError)  # fmt: skip

    def encode(self, t_ns: int, frame_id: str, child: str, position, quaternion,
               covariance=None) -> bytes:  # fmt: skip
        """The CDR bytes of one message holding the pose ``frame_id`` -> ``child`` at
        ``t_ns``; ``covariance`` (6, 6) over trackflow's ``(dt, dtheta)``, converted to
        ROS's (dropped by the types without one)."""
        ros_cov = None
        if covariance is not None and self.short in _COVARIANCE_TYPES:
            ros_cov = cov_to_ros(np.asarray(covariance, float), np.asarray(quaternion, float))
            ros_cov = 0.5 * (ros_cov + ros_cov.T)  # exactly symmetric, as ROS expects
        msg = pose_message(
            self.store, self.short, t_ns, frame_id, child, position, quaternion, ros_cov
        )
        return bytes(self.store.serialize_cdr(msg, self.msgtype))

    def decode(self, payload) -> list[RosPose]:
        """The poses of one message (one, or a ``TFMessage``'s transforms);
        :class:`MessageError` when the bytes are not a message of this type."""
        if len(payload) > MAX_PAYLOAD:
            raise MessageError(f"{len(payload)} bytes: larger than {MAX_PAYLOAD}")
        if len(payload) < 8 or bytes(payload[:2]) not in _ENCAPSULATIONS:
            raise MessageError("no CDR encapsulation header (00 00 or 00 01)")
        try:
            msg = self.store.deserialize_cdr(bytes(payload), self.msgtype)
            if self.short == "TFMessage":
                pairs = [(m, MESSAGE_TYPES["TransformStamped"]) for m in msg.transforms]
            else:
                pairs = [(msg, self.msgtype)]
            out = []
            for m, kind in pairs:
                p, q, cov, frame_id, child = pose_fields(m, kind)
                out.append(
                    RosPose(
                        ros_stamp_ns(m.header.stamp), frame_id, child, p, q,
                        None if cov is None else _ros_covariance(cov),
                    )
                )  # fmt: skip
            return out
        except self._errors as exc:
            raise MessageError(f"not a CDR {self.msgtype}: {exc}") from None
