"""ROS 2 topics over Zenoh, as the ROS 2 middleware ``rmw_zenoh_cpp`` has them
(``docs/ros2.md``): a push query's answers published as a topic
(:class:`~.publisher.AnswerPublisher`), and a sensor fed by a topic (the live input
``input: {ros2: ...}``, :class:`trackflow.trackers.ros2_input.Ros2Input`).

The parts: key expressions and liveliness tokens (:mod:`.names`), the attachment of every
message (:mod:`.attachment`), CDR pose messages (:mod:`.messages`, on ``rosbags``) and the
shared Zenoh session (:mod:`.session`, configured by :mod:`trackflow.zenohconf`). Needs the
``distributed`` extra (Zenoh) and the ``ros`` extra (``rosbags``).
"""

from .attachment import Attachment, AttachmentError, decode_attachment, encode_attachment
from .messages import MessageError, PoseCodec, RosPose, type_hash
from .names import (
    dds_type_name,
    entity_gid,
    entity_token,
    mangle,
    node_token,
    qos_keyexpr,
    topic_keyexpr,
)
from .publisher import AnswerPublisher, close_publishers, open_publishers
from .session import Ros2Session, Subscription, TopicPublisher

__all__ = [
    "AnswerPublisher",
    "Attachment",
    "AttachmentError",
    "MessageError",
    "PoseCodec",
    "Ros2Session",
    "RosPose",
    "Subscription",
    "TopicPublisher",
    "close_publishers",
    "dds_type_name",
    "decode_attachment",
    "encode_attachment",
    "entity_gid",
    "entity_token",
    "mangle",
    "node_token",
    "open_publishers",
    "qos_keyexpr",
    "topic_keyexpr",
    "type_hash",
]
