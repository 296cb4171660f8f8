"""``sensor_msgs/msg/Imu`` in ROS 1 and ROS 2 bags (SQLite or MCAP), read and written.

Fields and conversions at this boundary (``docs/conventions.md``), ROS ``Imu`` -> ``ImuStream``:

* ``header.stamp`` -> ``t_ns`` (``sec * 1e9 + nanosec``); ``header.frame_id`` -> ``frame``;
* ``angular_velocity`` -> ``gyro`` [rad/s] and ``linear_acceleration`` -> ``accel`` [m/s^2,
  specific force], both in the sensor frame, unchanged;
* ``orientation`` ``(x, y, z, w)`` -> ``orientation`` ``R_ref_sensor``, unchanged;
* ``angular_velocity_covariance`` -> ``gyro_covariance`` and
  ``linear_acceleration_covariance`` -> ``accel_covariance``: 9 values row-major -> (3, 3),
  unchanged (both in the sensor frame);
* ``orientation_covariance`` -> ``orientation_covariance``: ``C = R^T C_ros R``.

ROS states the orientation covariance about fixed axes (``R_true = Exp(dphi) R``), like the
rotation block of a ``PoseWithCovariance``; trackflow's error is on the right in the sensor
frame, ``dtheta = R^T dphi``. The conversion is the rotation block of
``trackflow.math.cov_from_ros`` / ``cov_to_ros``.

REP 145 markers: ``-1`` in element 0 of a covariance means that field was not measured. An
orientation marked so is left out (``orientation`` is ``None`` unless every kept message has
one); angular velocity or linear acceleration marked so makes the message unusable: an error
naming it, or with ``clean`` dropped and counted. A covariance of all zeros means "unknown" in
both worlds; a field whose covariances are all unknown is ``None``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import FormatError, InputError
from ..math import UNIT_TOLERANCE, cov_from_ros, cov_to_ros
from ._imu import ImuStream, check_rows
from ._report import ReadReport
from ._roscommon import (
    bag_write_path,
    bag_writer,
    check_stamp_mode,
    header,
    open_bag,
    pick_topic,
    serializer,
    stamp_ns,
)
from ._stream import unit_quaternions

__all__ = ["IMU_MSGTYPE", "read_rosbag_imu", "write_rosbag_imu"]

#: Full type name of ROS's IMU message.
IMU_MSGTYPE = "sensor_msgs/msg/Imu"


def _rotation_block(cov3: np.ndarray, quaternion: np.ndarray, to_ros: bool) -> np.ndarray:
    """Orientation covariances (N, 3, 3) between ROS's and trackflow's convention."""
    c6 = np.zeros(cov3.shape[:-2] + (6, 6))
    c6[..., 3:, 3:] = cov3
    out = (cov_to_ros if to_ros else cov_from_ros)(c6, quaternion)
    return out[..., 3:, 3:]


def _pick_topic(path, reader, topic: str | None) -> str:
    topics = sorted({c.topic for c in reader.connections if c.msgtype == IMU_MSGTYPE})
    return pick_topic(path, reader, topic, topics, IMU_MSGTYPE)


def read_rosbag_imu(
    path,
    *,
    clean: bool = False,
    topic: str | None = None,
    stamp: str = "header",
    frame: str | None = None,
) -> tuple[ImuStream, ReadReport]:
    """Read one ``sensor_msgs/Imu`` topic of a ROS 1 ``.bag`` or a ROS 2 bag.

    Parameters
    ----------
    path : path-like
        As for :func:`trackflow.io.read_rosbag` (``.bag``, ROS 2 directory, storage file).
    clean : bool
        Drop messages that are unusable (non-finite, time not increasing, angular velocity or
        acceleration marked missing) and count them, instead of raising ``FormatError``.
    topic : str, optional
        Required when the bag has several IMU topics.
    stamp : {"header", "receive"}
        ``header.stamp`` or the time the bag recorded the message.
    frame : str, optional
        Name of the sensor frame (default ``header.frame_id``, else ``"imu"``).

    Returns
    -------
    ImuStream, ReadReport
        Conversions in the module docstring; locations are 0-based message indices.
    """
    check_stamp_mode(stamp)
    reader, path = open_bag(path)
    from rosbags.highlevel import AnyReaderError

    try:
        topic = _pick_topic(path, reader, topic)
        conns = [c for c in reader.connections if c.topic == topic and c.msgtype == IMU_MSGTYPE]
        rows = []
        frames = set()
        for conn, t_recv, raw in reader.messages(connections=conns):
            m = reader.deserialize(raw, conn.msgtype)
            w, a, q = m.angular_velocity, m.linear_acceleration, m.orientation
            t = stamp_ns(m.header.stamp) if stamp == "header" else int(t_recv)
            frames.add(m.header.frame_id)
            rows.append(
                (
                    t,
                    (w.x, w.y, w.z, a.x, a.y, a.z, q.x, q.y, q.z, q.w),
                    np.concatenate(
                        [
                            np.asarray(m.angular_velocity_covariance, dtype=float),
                            np.asarray(m.linear_acceleration_covariance, dtype=float),
                            np.asarray(m.orientation_covariance, dtype=float),
                        ]
                    ),
                )
            )
    except (AnyReaderError, KeyError, IndexError, EOFError) as exc:
        raise FormatError(f"{path}: cannot read topic {topic!r} ({exc})") from None
    except InputError:
        raise
    except ValueError as exc:
        raise FormatError(f"{path}: {exc}") from None
    finally:
        reader.close()
    n = len(rows)
    report = ReadReport(str(path), "rosbag", unit="message", rows_read=n)
    report.notes.append(f"topic {topic} ({IMU_MSGTYPE}), time from {stamp} stamps")
    if len(frames) > 1:
        raise FormatError(f"{path}: topic {topic} changes frames mid-recording: {sorted(frames)}")
    t_ns = np.array([r[0] for r in rows], dtype=np.int64)
    values = np.array([r[1] for r in rows], dtype=float).reshape(n, 10)
    covs = np.array([r[2] for r in rows], dtype=float).reshape(n, 3, 3, 3)
    stream = _build(
        path, report, t_ns, values, covs, clean, frame or next(iter(frames), "") or "imu"
    )
    return stream, report


def _build(path, report, t_ns, values, covs, clean, frame) -> ImuStream:
    """The stream from the raw rows: REP 145 markers, row checks, covariance conversion."""
    n = len(t_ns)
    where = np.arange(n)
    missing = (covs[:, 0, 0, 0] == -1.0) | (covs[:, 1, 0, 0] == -1.0)
    if np.any(missing):
        k = int(np.flatnonzero(missing)[0])
        if not clean:
            raise FormatError(
                f"{path}: message {k}: angular velocity or linear acceleration marked missing "
                "(covariance[0] = -1)"
            )
        report.drop("angular velocity or acceleration marked missing (-1)", where[missing])
    has_q = covs[:, 2, 0, 0] != -1.0
    rowvals = np.concatenate([values[:, :6], covs[:, :2].reshape(n, 18)], axis=1)
    q_vals = np.where(
        has_q[:, None], np.concatenate([values[:, 6:], covs[:, 2].reshape(n, 9)], 1), 0
    )
    ok = ~missing
    ok[ok] = check_rows(
        report,
        where[ok],
        t_ns[ok],
        np.concatenate([rowvals, q_vals], axis=1)[ok],
        clean,
        f"{path}: message ",
        "message",
    )
    report.rows_kept = int(ok.sum())
    t_ns, values, covs, has_q = t_ns[ok], values[ok], covs[ok], has_q[ok]
    orientation = ocov = None
    if len(t_ns) and np.all(has_q):
        orientation = values[:, 6:10]
        norm = np.linalg.norm(orientation, axis=1)
        off = np.abs(norm - 1.0) > UNIT_TOLERANCE
        if np.any(off):
            k = int(where[ok][np.flatnonzero(off)[0]])
            if not clean or np.any(norm == 0.0):
                raise FormatError(
                    f"{path}: message {k}: orientation of length {norm[off][0]:.9g} (pass "
                    "clean=True to normalise it)"
                )
            orientation = orientation / norm[:, None]
            report.normalized.extend(int(w) for w in where[ok][off])
        orientation = unit_quaternions(orientation)
        ocov = _known(_rotation_block(covs[:, 2], orientation, to_ros=False))
    elif np.any(has_q):
        report.notes.append(
            f"orientation in only {int(has_q.sum())} of {len(has_q)} messages: left out"
        )
    return ImuStream(
        t_ns,
        values[:, 0:3],
        values[:, 3:6],
        None,
        frame,
        orientation,
        ocov,
        _known(covs[:, 0]),
        _known(covs[:, 1]),
    )


def _known(cov: np.ndarray) -> np.ndarray | None:
    """``cov`` (N, 3, 3), or ``None`` when every matrix is zero (ROS's "unknown")."""
    return cov if np.any(cov != 0.0) else None


def write_rosbag_imu(
    path,
    imu: ImuStream,
    *,
    topic: str = "/imu",
    storage: str | None = None,
    overwrite: bool = False,
) -> Path:
    """Write an IMU stream as ``sensor_msgs/Imu`` messages on one topic of a new bag.

    Parameters
    ----------
    path : path-like
        As for :func:`trackflow.io.write_rosbag`: ``.bag`` ROS 1; ``run.mcap`` / ``run.db3``
        the ROS 2 directory ``run/`` in MCAP / SQLite; else a ROS 2 directory.
    imu : ImuStream
        ``frame`` becomes ``header.frame_id``. Without ``orientation`` the messages carry the
        identity with ``orientation_covariance[0] = -1`` (REP 145: not measured). A missing
        covariance is written as zeros (unknown). ``mag`` has no place in the message.
    topic : str
    storage : {"sqlite3", "mcap"}, optional
        ROS 2 storage of a path without ``.mcap``/``.db3`` suffix (default ``"sqlite3"``).

    Returns
    -------
    Path
        The bag written.
    """
    if not isinstance(imu, ImuStream):
        raise InputError(f"imu must be an ImuStream, got {type(imu).__name__}")
    if len(imu) and imu.t_ns[0] < 0:
        raise InputError("ROS time cannot be negative")
    n = len(imu)
    zeros = np.zeros((n, 3, 3))
    q = imu.orientation if imu.orientation is not None else np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    if imu.orientation is None:
        ocov = zeros.copy()
        ocov[:, 0, 0] = -1.0
    elif imu.orientation_covariance is None:
        ocov = zeros
    else:
        ocov = _rotation_block(imu.orientation_covariance, imu.orientation, to_ros=True)
    gcov = zeros if imu.gyro_covariance is None else imu.gyro_covariance
    acov = zeros if imu.accel_covariance is None else imu.accel_covariance
    with bag_writer(path, overwrite=overwrite, storage=storage) as (writer, store, ros1):
        T = store.types
        Vec3, Quat = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
        serialize = serializer(store, ros1)
        conn = writer.add_connection(topic, IMU_MSGTYPE, typestore=store)
        for k in range(n):
            t = int(imu.t_ns[k])
            w, a = imu.gyro[k], imu.accel[k]
            msg = T[IMU_MSGTYPE](
                header=header(store, ros1, k, t, imu.frame),
                orientation=Quat(
                    x=float(q[k, 0]), y=float(q[k, 1]), z=float(q[k, 2]), w=float(q[k, 3])
                ),
                orientation_covariance=ocov[k].reshape(9).copy(),
                angular_velocity=Vec3(x=float(w[0]), y=float(w[1]), z=float(w[2])),
                angular_velocity_covariance=np.ascontiguousarray(gcov[k]).reshape(9).copy(),
                linear_acceleration=Vec3(x=float(a[0]), y=float(a[1]), z=float(a[2])),
                linear_acceleration_covariance=np.ascontiguousarray(acov[k]).reshape(9).copy(),
            )
            writer.write(conn, t, serialize(msg, IMU_MSGTYPE))
    return bag_write_path(path, storage)[0]
