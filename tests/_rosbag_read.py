"""Reading a ROS bag with rosbags alone (the independent reader the bag tests compare with)."""

from __future__ import annotations

import numpy as np

from trackflow.math import cov_to_ros


def bag_messages(bag) -> list:
    """Every message of a bag as (topic, msgtype, bag time, message), read by rosbags alone."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        return [
            (c.topic, c.msgtype, t, reader.deserialize(raw, c.msgtype))
            for c, t, raw in reader.messages()
        ]


def assert_bag_holds(msgs: list, stream, msgtype: str) -> None:
    """``msgs`` (:func:`bag_messages`) are ``stream``'s samples one for one: stamps, frames,
    positions and rotations bit for bit; for PoseWithCovarianceStamped the covariance in ROS's
    convention (a /tf message has none)."""
    assert len(msgs) == len(stream.t_ns)
    cov_ros = cov_to_ros(stream.covariance, stream.quaternion).reshape(-1, 36)
    for k, (_, _, t_bag, m) in enumerate(msgs):
        assert t_bag == stream.t_ns[k]
        if msgtype == "TFMessage":
            (tf,) = m.transforms
            assert (tf.header.frame_id, tf.child_frame_id) == (stream.source, stream.target)
            p, q = tf.transform.translation, tf.transform.rotation
        else:
            assert m.header.frame_id == stream.source
            p, q = m.pose.pose.position, m.pose.pose.orientation
            assert np.array_equal(m.pose.covariance, cov_ros[k])
        assert [p.x, p.y, p.z] == stream.position[k].tolist()
        assert [q.x, q.y, q.z, q.w] == stream.quaternion[k].tolist()
