"""Reading a ROS bag with rosbags alone (the independent reader the bag tests compare with)."""

from __future__ import annotations


def bag_messages(bag) -> list:
    """Every message of a bag as (topic, msgtype, bag time, message), read by rosbags alone."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        return [
            (c.topic, c.msgtype, t, reader.deserialize(raw, c.msgtype))
            for c, t, raw in reader.messages()
        ]
