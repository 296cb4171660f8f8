"""ROS 1 (``.bag``) and ROS 2 (bag directory, SQLite or MCAP) pose recordings via ``rosbags``.

Supported message types (one topic per stream): ``geometry_msgs/PoseStamped``,
``geometry_msgs/PoseWithCovarianceStamped``, ``geometry_msgs/TransformStamped``,
``nav_msgs/Odometry`` (its pose part) and ``tf2_msgs/TFMessage`` (``/tf`` with ``/tf_static``,
chained for a frame pair as tf2 does: :mod:`trackflow.io._rostf`). Bag paths and storages:
:mod:`trackflow.io._roscommon`.

Frames: ``source`` is ``header.frame_id``; ``target`` is ``child_frame_id`` where the message has
one, else the topic name without its leading slash. For ``TFMessage`` topics ``source`` and
``target`` are required and choose the pair. Time: ``header.stamp`` by default, or the bag's
receive time with ``stamp="receive"``.

Covariance: ROS's ``PoseWithCovariance`` perturbs the rotation on the left about the fixed axes
of ``frame_id`` (``R_true = Exp(dphi) R``); it is converted with
``trackflow.math.cov_from_ros`` on reading and ``cov_to_ros`` on writing, so the stream holds
trackflow's ``(dt, dtheta)`` with ``R_true = R Exp(dtheta)``. ROS marks an unknown covariance
with ``-1`` in the first element or all zeros; such samples get a zero matrix and a cleared
``FLAG_COVARIANCE`` bit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import FormatError, InputError
from ..math import cov_from_ros, cov_to_ros
from ._clean import finish_stream
from ._report import ReadReport
from ._roscommon import (
    bag_write_path,
    bag_writer,
    check_stamp_mode,
    header,
    open_bag,
    pick_topic,
    require_rosbags,
    serializer,
    stamp_ns,
)
from ._rostf import TF_MSGTYPE, is_static_topic, read_tf, tf_message
from ._stream import FLAG_COVARIANCE, FLAG_ORIENTATION, FLAG_POSITION, PoseStream

__all__ = [
    "MESSAGE_TYPES",
    "pose_fields",
    "pose_message",
    "read_rosbag",
    "require_rosbags",
    "write_rosbag",
]

#: Short name -> full ROS 2 style type name of the supported messages.
MESSAGE_TYPES = {
    "PoseStamped": "geometry_msgs/msg/PoseStamped",
    "PoseWithCovarianceStamped": "geometry_msgs/msg/PoseWithCovarianceStamped",
    "TransformStamped": "geometry_msgs/msg/TransformStamped",
    "Odometry": "nav_msgs/msg/Odometry",
    "TFMessage": TF_MSGTYPE,
}
_SUPPORTED = set(MESSAGE_TYPES.values())


def _extract(msg, msgtype: str):
    """(position, quaternion xyzw, ROS covariance 36 or None, frame_id, child or None)."""
    child = getattr(msg, "child_frame_id", None)
    if msgtype.endswith("TransformStamped"):
        tr = msg.transform
        p, q, cov = tr.translation, tr.rotation, None
    elif msgtype.endswith("PoseStamped") and not msgtype.endswith("CovarianceStamped"):
        p, q, cov = msg.pose.position, msg.pose.orientation, None
    else:  # PoseWithCovarianceStamped, Odometry: msg.pose is a PoseWithCovariance
        p, q, cov = msg.pose.pose.position, msg.pose.pose.orientation, msg.pose.covariance
    return (p.x, p.y, p.z), (q.x, q.y, q.z, q.w), cov, msg.header.frame_id, child


def pose_fields(msg, msgtype: str):
    """The pose of a deserialised message of ``msgtype`` (full name; not ``TFMessage``, whose
    transforms are ``TransformStamped`` each): ``(position, quaternion xyzw, ROS covariance
    (36,) or None, header.frame_id, child_frame_id or None)``."""
    return _extract(msg, msgtype)


def pose_message(store, msgtype: str, t_ns: int, frame_id: str, child: str, position,
                 quaternion, ros_covariance=None):  # fmt: skip
    """A ROS 2 message of ``msgtype`` (a short name of :data:`MESSAGE_TYPES`) holding the pose
    ``frame_id`` -> ``child`` stamped ``t_ns``; ``ros_covariance`` (36,) is in ROS's order and
    convention (:func:`trackflow.math.cov_to_ros`), zeros where not given."""
    cov = np.zeros(36) if ros_covariance is None else np.asarray(ros_covariance, float).ravel()
    hdr = header(store, False, 0, int(t_ns), frame_id)
    return _pose_message(store, msgtype, hdr, child, position, quaternion, cov)


def _pick_topic(path, reader, topic: str | None) -> str:
    """The pose topic to read: ``topic``, or the bag's only one (all TFMessage topics but the
    static ones count as one candidate each; ``/tf_static`` is read along with them)."""
    candidates = sorted(
        {
            c.topic
            for c in reader.connections
            if c.msgtype in _SUPPORTED
            and not (c.msgtype == TF_MSGTYPE and is_static_topic(c.topic))
        }
    )
    return pick_topic(path, reader, topic, candidates, "pose")


def read_rosbag(
    path,
    *,
    clean: bool = False,
    topic: str | None = None,
    stamp: str = "header",
    source: str | None = None,
    target: str | None = None,
) -> tuple[PoseStream, ReadReport]:
    """Read one pose topic of a ROS 1 ``.bag`` or a ROS 2 bag (SQLite or MCAP storage).

    Parameters
    ----------
    path : path-like
        ``.bag`` file, ROS 2 bag directory, its ``.db3``/``.mcap`` storage file, or the name
        a ROS 2 bag was written under (``run.mcap`` for the directory ``run/``).
    topic : str, optional
        Required when the bag has more than one topic of a supported type (``/tf`` counts as
        one, ``/tf_static`` is read with it).
    stamp : {"header", "receive"}
        Use ``header.stamp`` or the time the bag recorded the message.
    source, target : str, optional
        Override the frame names taken from the messages; for ``TFMessage`` topics required:
        the frame pair of ``T_source_target`` chained through the transform tree (rules in
        :mod:`trackflow.io._rostf`; a pair the tree cannot give raises
        :class:`~trackflow.io.FrameLookupError`).

    Locations in the report and in errors are 0-based message indices on the topic.
    """
    check_stamp_mode(stamp)
    reader, path = open_bag(path)
    from rosbags.highlevel import AnyReaderError

    tf = None
    try:
        topic = _pick_topic(path, reader, topic)
        conns = [c for c in reader.connections if c.msgtype in _SUPPORTED and c.topic == topic]
        if not conns:
            raise FormatError(f"{path}: no supported pose messages on topic {topic!r}")
        msgtype = conns[0].msgtype
        report = ReadReport(str(path), "rosbag", unit="message")
        if msgtype == TF_MSGTYPE:
            statics = [
                c
                for c in reader.connections
                if c.msgtype == TF_MSGTYPE and is_static_topic(c.topic) and c.topic != topic
            ]
            tf = read_tf(
                reader,
                conns + statics,
                path,
                source=source,
                target=target,
                stamp=stamp,
                clean=clean,
                report=report,
            )
            if statics:
                report.notes.append(f"static transforms from {sorted({c.topic for c in statics})}")
        else:
            ts, ps, qs, covs, frames = _read_poses(reader, conns, stamp)
    except (AnyReaderError, KeyError, IndexError, EOFError) as exc:
        raise FormatError(f"{path}: cannot read topic {topic!r} ({exc})") from None
    except InputError:  # trackflow's own (FormatError, FrameLookupError ...) as they are
        raise
    except ValueError as exc:
        raise FormatError(f"{path}: {exc}" if str(path) not in str(exc) else str(exc)) from None
    finally:
        reader.close()
    report.notes.insert(0, f"topic {topic} ({msgtype}), time from {stamp} stamps")
    if tf is not None:
        where, t_ns, position, quaternion = tf
        return finish_stream(
            report,
            where=where,
            t_ns=t_ns,
            position=position,
            quaternion=quaternion,
            source=source,
            target=target,
            clean=clean,
        ), report
    n = len(ts)
    report.rows_read = n
    if len(frames) > 1:
        raise FormatError(f"{path}: topic {topic} changes frames mid-recording: {sorted(frames)}")
    frame_id, child = frames.pop() if frames else ("", None)
    src = source or frame_id or "world"
    tgt = target or child or topic.lstrip("/") or "body"
    quat = np.array(qs, dtype=float).reshape(n, 4)
    cov = None
    flags = None
    if covs and len(covs) == n:
        c_ros = np.array(covs).reshape(n, 6, 6)
        unknown = (c_ros[:, 0, 0] == -1.0) | np.all(c_ros == 0.0, axis=(1, 2))
        c_ros[unknown] = 0.0
        with np.errstate(invalid="ignore"):
            qn = quat / np.linalg.norm(quat, axis=1, keepdims=True)
        qn = np.where(np.isfinite(qn), qn, [0.0, 0.0, 0.0, 1.0])
        cov = cov_from_ros(c_ros, qn)
        flags = np.where(
            unknown,
            FLAG_POSITION | FLAG_ORIENTATION,
            FLAG_POSITION | FLAG_ORIENTATION | FLAG_COVARIANCE,
        ).astype(np.uint32)
        if np.any(unknown):
            report.notes.append(f"{int(unknown.sum())} message(s) with unknown covariance")
    stream = finish_stream(
        report,
        where=np.arange(n),
        t_ns=np.array(ts, dtype=np.int64),
        position=np.array(ps, dtype=float).reshape(n, 3),
        quaternion=quat,
        covariance=cov,
        flags=flags,
        source=src,
        target=tgt,
        clean=clean,
    )
    return stream, report


def _read_poses(reader, conns, stamp: str):
    """Stamps, positions, quaternions, ROS covariances and (frame_id, child) pairs of a topic."""
    ts, ps, qs, covs, frames = [], [], [], [], set()
    for conn, t_recv, raw in reader.messages(connections=conns):
        msg = reader.deserialize(raw, conn.msgtype)
        p, q, cov, frame_id, child = _extract(msg, conn.msgtype)
        ts.append(stamp_ns(msg.header.stamp) if stamp == "header" else t_recv)
        ps.append(p)
        qs.append(q)
        if cov is not None:
            covs.append(np.asarray(cov, dtype=float))
        frames.add((frame_id, child))
    return ts, ps, qs, covs, frames


def _pose_message(store, msgtype: str, hdr, child: str, position, quaternion, cov):
    """One message of ``msgtype`` (short name) holding the pose ``hdr.frame_id`` -> ``child``."""
    T = store.types
    full = MESSAGE_TYPES[msgtype]
    if msgtype == "TFMessage":
        return tf_message(store, hdr, child, position, quaternion)
    Point, Quat = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"]
    Vec3 = T["geometry_msgs/msg/Vector3"]
    Pose_, PWC = T["geometry_msgs/msg/Pose"], T["geometry_msgs/msg/PoseWithCovariance"]
    x, y, z = (float(v) for v in position)
    qx, qy, qz, qw = (float(v) for v in quaternion)
    pose = Pose_(position=Point(x=x, y=y, z=z), orientation=Quat(x=qx, y=qy, z=qz, w=qw))
    if msgtype == "PoseStamped":
        return T[full](header=hdr, pose=pose)
    if msgtype == "PoseWithCovarianceStamped":
        return T[full](header=hdr, pose=PWC(pose=pose, covariance=cov))
    if msgtype == "TransformStamped":
        tr = T["geometry_msgs/msg/Transform"](
            translation=Vec3(x=x, y=y, z=z), rotation=Quat(x=qx, y=qy, z=qz, w=qw)
        )
        return T[full](header=hdr, child_frame_id=child, transform=tr)
    zero = Vec3(x=0.0, y=0.0, z=0.0)  # Odometry
    twist = T["geometry_msgs/msg/TwistWithCovariance"](
        twist=T["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36)
    )
    return T[full](
        header=hdr, child_frame_id=child, pose=PWC(pose=pose, covariance=cov), twist=twist
    )


def write_rosbag(
    path,
    stream: PoseStream,
    *,
    msgtype: str | None = None,
    topic: str | None = None,
    storage: str | None = None,
    overwrite: bool = False,
) -> Path:
    """Write a stream as one topic of a new ROS 1 or ROS 2 bag.

    Parameters
    ----------
    path : path-like
        ``run.bag``: ROS 1 bag. ``run.mcap`` / ``run.db3``: ROS 2 bag directory ``run/`` holding
        ``run/run.mcap`` (MCAP) or ``run/run.db3`` (SQLite) and ``run/metadata.yaml``. Any other
        path: a ROS 2 bag directory of that name (storage from ``storage``).
    msgtype : {"PoseStamped", "PoseWithCovarianceStamped", "TransformStamped", "Odometry", \
"TFMessage"}
        Default: ``PoseWithCovarianceStamped`` when the stream has a covariance, else
        ``PoseStamped``. Types without covariance drop it; types with one write zeros (ROS's
        "unknown") when the stream has none. ``TFMessage`` writes one ``TransformStamped`` per
        message, as a tf2 broadcaster does.
    topic : str, optional
        Default ``"/tf"`` for ``TFMessage``, else ``"/" + stream.target`` (so a ``PoseStamped``
        bag reads back with its target).
    storage : {"sqlite3", "mcap"}, optional
        ROS 2 storage of a path without ``.mcap``/``.db3`` suffix (default ``"sqlite3"``).

    Returns
    -------
    Path
        The bag written (the ROS 2 directory, or the ``.bag`` file).

    ``header.frame_id`` is ``stream.source`` (the parent, ``T_source_target``);
    ``child_frame_id`` is ``stream.target``; the bag time of each message is its stamp.
    Confidence and flags have no place in these messages. The bag is written under the output
    policy of :func:`trackflow.io.atomic_output` (atomic; an existing bag is replaced only with
    ``overwrite``).
    """
    require_rosbags()
    if msgtype is None:
        msgtype = "PoseWithCovarianceStamped" if stream.covariance is not None else "PoseStamped"
    if msgtype not in MESSAGE_TYPES:
        raise InputError(f"msgtype must be one of {sorted(MESSAGE_TYPES)}, got {msgtype!r}")
    if len(stream) and stream.t_ns[0] < 0:
        raise InputError("ROS time cannot be negative")
    full = MESSAGE_TYPES[msgtype]
    topic = topic or ("/tf" if msgtype == "TFMessage" else "/" + stream.target)
    cov_ros = None
    if stream.covariance is not None:
        cov_ros = cov_to_ros(stream.covariance, stream.quaternion).reshape(-1, 36)
        cov_ros[(stream.flags & FLAG_COVARIANCE) == 0] = 0.0
    with bag_writer(path, overwrite=overwrite, storage=storage) as (writer, store, ros1):
        serialize = serializer(store, ros1)
        conn = writer.add_connection(topic, full, typestore=store)
        for k in range(len(stream)):
            t = int(stream.t_ns[k])
            msg = _pose_message(
                store,
                msgtype,
                header(store, ros1, k, t, stream.source),
                stream.target,
                stream.position[k],
                stream.quaternion[k],
                np.zeros(36) if cov_ros is None else cov_ros[k],
            )
            writer.write(conn, t, serialize(msg, full))
    return bag_write_path(path, storage)[0]
