"""Recordings: pose streams, the native ``.tfrec`` format and readers/writers for common formats.

``read_stream(path, format=None, clean=False, **options) -> (PoseStream, ReadReport)`` and
``write_stream(path, stream, format=None, overwrite=False, **options)`` cover every format; the
per-format functions are exported too. Every writer follows one output policy
(``atomic_output``: temporary file in the target directory, rename when complete, no silent
overwrite, nothing left behind on failure); ``"-"`` is standard input/output. Formats,
conversions and quirks: ``docs/formats.md``.
IMU recordings: ``read_imu(path) -> (ImuStream, ReadReport)`` (EuRoC IMU csv, BROAD ``.mat``,
``sensor_msgs/Imu`` in ROS bags); ``write_rosbag_imu`` writes one.
"""

from ._api import FORMATS, IMU_FORMATS, guess_format, read_imu, read_stream, write_stream
from ._devices import (
    BROAD_RATE_HZ,
    DOTNET_UNIX_EPOCH_TICKS,
    read_broad,
    read_quest,
    write_broad,
    write_quest,
)
from ._imu import ImuStream, read_broad_imu, read_euroc_imu
from ._kitti import KITTI_RATE_HZ, read_kitti, write_kitti
from ._native import RecordingWriter, read_native, write_native
from ._output import STDIO, atomic_output, remove_stale_temporaries
from ._report import ReadReport
from ._rosbag import MESSAGE_TYPES, pose_fields, pose_message, read_rosbag, write_rosbag
from ._roscommon import stamp_ns as ros_stamp_ns
from ._roscommon import typestore as ros_typestore
from ._rosimu import read_rosbag_imu, write_rosbag_imu
from ._rostf import FrameLookupError
from ._stream import FLAG_CONFIDENCE, FLAG_COVARIANCE, FLAG_ORIENTATION, FLAG_POSITION, PoseStream
from ._text import read_csv, read_euroc, read_tum, write_csv, write_euroc, write_tum

__all__ = [
    "BROAD_RATE_HZ",
    "DOTNET_UNIX_EPOCH_TICKS",
    "FLAG_CONFIDENCE",
    "FLAG_COVARIANCE",
    "FLAG_ORIENTATION",
    "FLAG_POSITION",
    "FORMATS",
    "FrameLookupError",
    "IMU_FORMATS",
    "ImuStream",
    "KITTI_RATE_HZ",
    "MESSAGE_TYPES",
    "PoseStream",
    "ReadReport",
    "STDIO",
    "RecordingWriter",
    "atomic_output",
    "guess_format",
    "pose_fields",
    "pose_message",
    "read_broad",
    "read_broad_imu",
    "read_csv",
    "read_euroc",
    "read_euroc_imu",
    "read_imu",
    "read_kitti",
    "read_native",
    "read_quest",
    "read_rosbag",
    "read_rosbag_imu",
    "read_stream",
    "read_tum",
    "remove_stale_temporaries",
    "ros_stamp_ns",
    "ros_typestore",
    "write_broad",
    "write_csv",
    "write_euroc",
    "write_kitti",
    "write_native",
    "write_quest",
    "write_rosbag",
    "write_rosbag_imu",
    "write_stream",
    "write_tum",
]
