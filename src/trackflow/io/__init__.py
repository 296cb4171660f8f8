"""Recordings: pose streams, the native ``.tfrec`` format and readers/writers for common formats.

``read_stream(path, format=None, clean=False, **options) -> (PoseStream, ReadReport)`` and
``write_stream(path, stream, format=None, **options)`` cover every format; the per-format
functions are exported too. Formats, conversions and quirks: ``docs/formats.md``.
"""

from ._api import FORMATS, guess_format, read_stream, write_stream
from ._devices import (
    BROAD_RATE_HZ,
    DOTNET_UNIX_EPOCH_TICKS,
    read_broad,
    read_quest,
    write_broad,
    write_quest,
)
from ._native import RecordingWriter, read_native, write_native
from ._report import ReadReport
from ._rosbag import MESSAGE_TYPES, read_rosbag, write_rosbag
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
    "MESSAGE_TYPES",
    "PoseStream",
    "ReadReport",
    "RecordingWriter",
    "guess_format",
    "read_broad",
    "read_csv",
    "read_euroc",
    "read_native",
    "read_quest",
    "read_rosbag",
    "read_stream",
    "read_tum",
    "write_broad",
    "write_csv",
    "write_euroc",
    "write_native",
    "write_quest",
    "write_rosbag",
    "write_stream",
    "write_tum",
]
