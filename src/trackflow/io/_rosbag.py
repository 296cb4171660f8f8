"""ROS 1 (``.bag``) and ROS 2 (bag directory) recordings through the ``rosbags`` library.

Supported message types (one topic per stream): ``geometry_msgs/PoseStamped``,
``geometry_msgs/PoseWithCovarianceStamped``, ``geometry_msgs/TransformStamped`` and
``nav_msgs/Odometry`` (its pose part).

Frames: ``source`` is ``header.frame_id``; ``target`` is ``child_frame_id`` where the message has
one, else the topic name without its leading slash. Time: ``header.stamp`` by default, or the
bag's receive time with ``stamp="receive"``.

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
from ..optional import require
from ._clean import finish_stream
from ._output import atomic_output
from ._report import ReadReport
from ._stream import FLAG_COVARIANCE, FLAG_ORIENTATION, FLAG_POSITION, PoseStream

__all__ = ["MESSAGE_TYPES", "read_rosbag", "write_rosbag"]

#: Short name -> full ROS 2 style type name of the supported messages.
MESSAGE_TYPES = {
    "PoseStamped": "geometry_msgs/msg/PoseStamped",
    "PoseWithCovarianceStamped": "geometry_msgs/msg/PoseWithCovarianceStamped",
    "TransformStamped": "geometry_msgs/msg/TransformStamped",
    "Odometry": "nav_msgs/msg/Odometry",
}
_SUPPORTED = set(MESSAGE_TYPES.values())


def _is_ros1(path: Path) -> bool:
    return path.suffix == ".bag"


def require_rosbags() -> None:
    """Raise :class:`~trackflow.errors.MissingExtraError` (an ``ImportError``) naming the
    extra to install when ``rosbags`` is missing."""
    require("rosbags", extra="ros", feature="ROS bags")


def _typestore(ros1: bool):
    require_rosbags()
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)


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


def read_rosbag(
    path,
    *,
    clean: bool = False,
    topic: str | None = None,
    stamp: str = "header",
    source: str | None = None,
    target: str | None = None,
) -> tuple[PoseStream, ReadReport]:
    """Read one pose topic of a ROS 1 ``.bag`` or a ROS 2 bag directory.

    Parameters
    ----------
    topic : str, optional
        Required when the bag has more than one topic of a supported type.
    stamp : {"header", "receive"}
        Use ``header.stamp`` or the time the bag recorded the message.
    source, target : str, optional
        Override the frame names taken from the messages.

    Locations in the report and in errors are 0-based message indices on the topic.
    """
    require_rosbags()
    from rosbags.highlevel import AnyReader, AnyReaderError

    path = Path(path)
    if path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").exists():
        path = path.parent  # a ROS 2 storage file: read its bag directory
    if stamp not in ("header", "receive"):
        raise InputError(f"stamp must be 'header' or 'receive', got {stamp!r}")
    ros1 = _is_ros1(path)
    try:
        reader = AnyReader([path], default_typestore=_typestore(ros1))
        reader.open()
    except (AnyReaderError, ValueError, KeyError, IndexError, EOFError) as exc:
        # garbage files fail deep inside the bag parsers (codec, struct, key errors)
        raise FormatError(f"{path}: cannot open as a ROS bag ({exc})") from None
    try:
        conns = [c for c in reader.connections if c.msgtype in _SUPPORTED]
        topics = sorted({c.topic for c in conns})
        if topic is None:
            if len(topics) != 1:
                all_topics = sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})
                raise FormatError(
                    f"{path}: {'no' if not topics else 'several'} pose topics; pass topic= one "
                    f"of: {', '.join(all_topics) or 'none'}"
                )
            topic = topics[0]
        conns = [c for c in conns if c.topic == topic]
        if not conns:
            raise FormatError(f"{path}: no supported pose messages on topic {topic!r}")
        ts, ps, qs, covs, frames = [], [], [], [], set()
        msgtype = conns[0].msgtype
        for conn, t_recv, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            p, q, cov, frame_id, child = _extract(msg, conn.msgtype)
            st = msg.header.stamp
            ts.append(
                int(st.sec) * 1_000_000_000 + int(st.nanosec) if stamp == "header" else t_recv
            )
            ps.append(p)
            qs.append(q)
            if cov is not None:
                covs.append(np.asarray(cov, dtype=float))
            frames.add((frame_id, child))
    except (AnyReaderError, KeyError, IndexError, EOFError) as exc:
        raise FormatError(f"{path}: cannot read topic {topic!r} ({exc})") from None
    except ValueError as exc:
        raise FormatError(f"{path}: {exc}" if str(path) not in str(exc) else str(exc)) from None
    finally:
        reader.close()
    n = len(ts)
    report = ReadReport(str(path), "rosbag", unit="message", rows_read=n)
    report.notes.append(f"topic {topic} ({msgtype}), time from {stamp} stamps")
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


def write_rosbag(
    path,
    stream: PoseStream,
    *,
    msgtype: str | None = None,
    topic: str | None = None,
    overwrite: bool = False,
) -> None:
    """Write a stream as one topic of a new ROS 1 ``.bag`` (suffix ``.bag``) or ROS 2 bag
    directory (any other path).

    Parameters
    ----------
    msgtype : {"PoseStamped", "PoseWithCovarianceStamped", "TransformStamped", "Odometry"}
        Default: ``PoseWithCovarianceStamped`` when the stream has a covariance, else
        ``PoseStamped``. Types without covariance drop it; types with one write zeros (ROS's
        "unknown") when the stream has none.
    topic : str, optional
        Default ``"/" + stream.target`` (so a ``PoseStamped`` bag reads back with its target).

    ``header.frame_id`` is ``stream.source``; ``child_frame_id`` is ``stream.target``; the bag
    time of each message is its stamp. Confidence and flags have no place in these messages.
    The bag is written under the output policy of :func:`trackflow.io.atomic_output` (atomic;
    an existing bag is replaced only with ``overwrite``).
    """
    require_rosbags()
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import Writer as Writer2

    path = Path(path)
    if msgtype is None:
        msgtype = "PoseWithCovarianceStamped" if stream.covariance is not None else "PoseStamped"
    if msgtype not in MESSAGE_TYPES:
        raise InputError(f"msgtype must be one of {sorted(MESSAGE_TYPES)}, got {msgtype!r}")
    if len(stream) and stream.t_ns[0] < 0:
        raise InputError("ROS time cannot be negative")
    full = MESSAGE_TYPES[msgtype]
    topic = topic or "/" + stream.target
    ros1 = _is_ros1(path)
    store = _typestore(ros1)
    T = store.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Point, Quat = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"]
    Vec3 = T["geometry_msgs/msg/Vector3"]
    Pose_, PWC = T["geometry_msgs/msg/Pose"], T["geometry_msgs/msg/PoseWithCovariance"]
    cov_ros = None
    if stream.covariance is not None:
        cov_ros = cov_to_ros(stream.covariance, stream.quaternion).reshape(-1, 36)
        cov_ros[(stream.flags & FLAG_COVARIANCE) == 0] = 0.0
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    with atomic_output(path, overwrite=overwrite, directory=not ros1) as tmp:
        writer = Writer1(tmp) if ros1 else Writer2(tmp, version=8)
        with writer:
            conn = writer.add_connection(topic, full, typestore=store)
            for k in range(len(stream)):
                t = int(stream.t_ns[k])
                stamp = Time(sec=t // 1_000_000_000, nanosec=t % 1_000_000_000)
                hdr = (
                    Header(seq=k, stamp=stamp, frame_id=stream.source)
                    if ros1
                    else Header(stamp=stamp, frame_id=stream.source)
                )
                x, y, z = (float(v) for v in stream.position[k])
                qx, qy, qz, qw = (float(v) for v in stream.quaternion[k])
                cov = np.zeros(36) if cov_ros is None else cov_ros[k]
                pose = Pose_(
                    position=Point(x=x, y=y, z=z), orientation=Quat(x=qx, y=qy, z=qz, w=qw)
                )
                if msgtype == "PoseStamped":
                    msg = T[full](header=hdr, pose=pose)
                elif msgtype == "PoseWithCovarianceStamped":
                    msg = T[full](header=hdr, pose=PWC(pose=pose, covariance=cov))
                elif msgtype == "TransformStamped":
                    tr = T["geometry_msgs/msg/Transform"](
                        translation=Vec3(x=x, y=y, z=z), rotation=Quat(x=qx, y=qy, z=qz, w=qw)
                    )
                    msg = T[full](header=hdr, child_frame_id=stream.target, transform=tr)
                else:  # Odometry
                    zero = Vec3(x=0.0, y=0.0, z=0.0)
                    twist = T["geometry_msgs/msg/TwistWithCovariance"](
                        twist=T["geometry_msgs/msg/Twist"](linear=zero, angular=zero),
                        covariance=np.zeros(36),
                    )
                    msg = T[full](
                        header=hdr,
                        child_frame_id=stream.target,
                        pose=PWC(pose=pose, covariance=cov),
                        twist=twist,
                    )
                writer.write(conn, t, serialize(msg, full))
