"""``read_stream`` / ``write_stream``: one entry point for every recording format."""

from __future__ import annotations

import inspect
import shutil
import sys
import tempfile
from pathlib import Path

from ..errors import FormatError, InputError
from ._devices import read_broad, read_quest, write_broad, write_quest
from ._imu import ImuStream, read_broad_imu, read_euroc_imu
from ._kitti import read_kitti, write_kitti
from ._native import MAGIC, read_native, write_native
from ._output import STDIO
from ._report import ReadReport
from ._rosbag import read_rosbag, write_rosbag
from ._rosimu import read_rosbag_imu
from ._stream import PoseStream
from ._text import read_csv, read_euroc, read_tum, write_csv, write_euroc, write_tum

__all__ = ["FORMATS", "IMU_FORMATS", "guess_format", "read_imu", "read_stream", "write_stream"]

_READERS = {
    "native": read_native,
    "tum": read_tum,
    "euroc": read_euroc,
    "csv": read_csv,
    "rosbag": read_rosbag,
    "quest": read_quest,
    "broad": read_broad,
    "kitti": read_kitti,
}
_WRITERS = {
    "native": write_native,
    "tum": write_tum,
    "euroc": write_euroc,
    "csv": write_csv,
    "rosbag": write_rosbag,
    "quest": write_quest,
    "broad": write_broad,
    "kitti": write_kitti,
}
#: Names accepted by ``format=``.
FORMATS = tuple(_READERS)
#: IMU recording formats :func:`read_imu` understands.
IMU_FORMATS = ("euroc_imu", "broad", "rosbag")


def _is_bag(path: Path) -> bool:
    """A ROS bag by name: ``.bag``, ``.mcap``/``.db3``, or a directory with ``metadata.yaml``."""
    return path.suffix.lower() in (".bag", ".mcap", ".db3") or (
        path.is_dir() and (path / "metadata.yaml").exists()
    )


def _head(path: Path) -> bytes:
    """The first 64 KiB of a file, without a UTF-8 byte order mark."""
    with open(path, "rb") as f:
        chunk = f.read(65536)
    return chunk[3:] if chunk.startswith(b"\xef\xbb\xbf") else chunk


def _first_data_line(path: Path) -> str | None:
    chunk = _head(path)
    for raw in chunk.split(b"\n")[:50]:
        line = raw.decode("utf-8", errors="replace").strip()
        if line and not line.startswith("#"):
            return line
    return None


def _is_quest_line(line: str) -> bool:
    toks = line.split(",")
    if len(toks) < 16:
        return False
    try:
        return int(toks[1]) > 600_000_000_000_000_000  # .NET ticks (year > 1902)
    except ValueError:
        return False


def guess_format(path, for_writing: bool = False) -> str:
    """Format name from content (when reading an existing file) and extension.

    Rules: native magic bytes; ``.bag``, ``.mcap``, ``.db3`` or a directory with
    ``metadata.yaml`` -> ``rosbag``;
    ``.mat`` -> ``broad``; ``.tfrec`` -> ``native``; a text file with a leading comment line
    ``#timestamp,...`` -> ``euroc``; 16 comma-separated columns with .NET ticks ->
    ``quest``; other comma-separated text -> ``csv``; whitespace-separated with 12 columns ->
    ``kitti``, else ``tum``; ``.kitti`` -> ``kitti``.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if not for_writing and path.is_file():
        with open(path, "rb") as f:
            if f.read(len(MAGIC)) == MAGIC:
                return "native"
    if _is_bag(path):
        return "rosbag"
    if suffix == ".mat":
        return "broad"
    if suffix == ".tfrec":
        return "native"
    if suffix == ".kitti":
        return "kitti"
    if for_writing or not path.is_file():
        if suffix == ".csv":
            return "csv"
        if suffix in (".txt", ".tum"):
            return "tum"
        if for_writing and suffix == "":
            return "rosbag"
        raise FormatError(f"{path}: cannot tell the format from the name; pass format=")
    chunk = _head(path)
    if b"\0" in chunk:
        line = chunk[: chunk.index(b"\0")].count(b"\n") + 1
        raise FormatError(
            f"{path}:{line}: binary data that is not a recognised recording (NUL byte); "
            "pass format= if it is one"
        )
    head = chunk.decode("utf-8", errors="replace").split("\n")[:20]
    for first in head:
        first = first.strip().lower()
        if not first.startswith("#"):
            break
        if first.startswith("#timestamp") and "," in first:
            return "euroc"
    line = _first_data_line(path)
    if line is None:
        raise FormatError(f"{path}: no data lines; pass format=")
    if "," in line:
        return "quest" if _is_quest_line(line) else "csv"
    return "kitti" if len(line.split()) == 12 else "tum"


def _call(func, path, fmt: str, kwargs: dict):
    params = inspect.signature(func).parameters
    unknown = [k for k in kwargs if k not in params or k in ("path", "stream")]
    if unknown:
        accepted = [k for k in params if k not in ("path", "stream", "clean")]
        raise InputError(
            f"format {fmt!r} does not take option(s) {unknown}; it accepts {accepted or 'none'}"
        )
    return func(path, **kwargs)


def read_stream(
    path, format: str | None = None, clean: bool = False, **options
) -> tuple[PoseStream, ReadReport]:
    """Read a pose recording into a :class:`PoseStream` and a :class:`ReadReport`.

    Parameters
    ----------
    path : str or Path
    format : {"native", "tum", "euroc", "csv", "rosbag", "quest", "broad"}, optional
        Guessed from the content and extension when omitted (see :func:`guess_format`).
    clean : bool
        Without it, malformed rows (short, unparsable, NaN, non-unit quaternion, duplicated or
        non-increasing timestamps) raise ``ValueError`` naming file and line. With it they are
        dropped or repaired and listed in the report; quaternion signs are made continuous.
    **options
        Format-specific options, e.g. ``source=``/``target=`` frame names for most formats,
        ``columns=``/``time_unit=``/``delimiter=`` for ``csv``, ``topic=``/``stamp=`` for
        ``rosbag``, ``rate_hz=`` for ``broad``. Unknown options raise ``ValueError``.

    Returns
    -------
    stream : PoseStream
    report : ReadReport
        Counts of every row read, kept, dropped (with reasons and lines) or changed.
    """
    if str(path) == STDIO:
        return _read_stdin(format, clean, options)
    fmt = format or guess_format(path)
    if fmt not in _READERS:
        raise InputError(f"unknown format {fmt!r}; known: {', '.join(FORMATS)}")
    return _call(_READERS[fmt], Path(path), fmt, {"clean": bool(clean), **options})


def _read_stdin(format, clean, options) -> tuple[PoseStream, ReadReport]:
    """Read standard input (``path="-"``): buffered to a private file, named ``<stdin>``."""
    if format == "rosbag":
        raise InputError("<stdin>: ROS bags cannot be read from standard input")
    with tempfile.TemporaryDirectory(prefix="trackflow-") as d:
        tmp = Path(d) / "stdin"
        with open(tmp, "wb") as f:  # copied in pieces: never the whole input in memory
            if hasattr(sys.stdin, "buffer"):
                shutil.copyfileobj(sys.stdin.buffer, f)
            else:
                f.write(sys.stdin.read().encode())
        try:
            stream, report = read_stream(tmp, format=format, clean=clean, **options)
        except ValueError as exc:
            raise FormatError(str(exc).replace(str(tmp), "<stdin>")) from None
    report.path = "<stdin>"
    return stream, report


def write_stream(
    path, stream: PoseStream, format: str | None = None, *, overwrite: bool = False, **options
) -> Path | None:
    """Write ``stream`` in ``format`` (guessed from the extension when omitted).

    Every format follows one output policy (:func:`trackflow.io.atomic_output`): the file is
    written to a temporary name in the target directory and renamed into place when complete,
    an existing ``path`` is an error (``FileExistsError``) unless ``overwrite``, and nothing is
    left behind when writing fails. ``path="-"`` writes to standard output (format default
    ``tum``).

    Extensions: ``.tfrec`` native, ``.txt``/``.tum`` TUM, ``.csv`` generic CSV, ``.bag`` ROS 1,
    ``.mcap``/``.db3`` ROS 2 bag directory named without the suffix (``run.mcap`` writes
    ``run/run.mcap`` and ``run/metadata.yaml``), no extension ROS 2 bag directory (SQLite),
    ``.mat`` BROAD. Options: ``msgtype=``/``topic=``/``storage=`` for ``rosbag``,
    ``delimiter=``/``time_unit=`` for ``csv``, ``rate_hz=`` for ``broad``. What each format can
    hold is listed in ``docs/formats.md``; fields it cannot hold are not written.

    Returns the path of a ROS bag written (``run.mcap`` -> ``run``), else ``None``.
    """
    if not isinstance(stream, PoseStream):
        raise InputError(f"stream must be a PoseStream, got {type(stream).__name__}")
    fmt = format or ("tum" if str(path) == STDIO else guess_format(path, for_writing=True))
    if fmt not in _WRITERS:
        raise InputError(f"unknown format {fmt!r}; known: {', '.join(FORMATS)}")
    func = _WRITERS[fmt]
    params = inspect.signature(func).parameters
    unknown = [k for k in options if k not in params or k in ("path", "stream", "overwrite")]
    if unknown:
        accepted = [k for k in params if k not in ("path", "stream", "overwrite")]
        raise InputError(
            f"format {fmt!r} does not take option(s) {unknown}; it accepts {accepted or 'none'}"
        )
    return func(path if str(path) == STDIO else Path(path), stream, overwrite=overwrite, **options)


def read_imu(
    path, format: str | None = None, *, clean: bool = False, **options
) -> tuple[ImuStream, ReadReport]:
    """Read an IMU recording; the format is guessed from the name.

    Parameters
    ----------
    path : path-like
    format : {"euroc_imu", "broad", "rosbag"}, optional
        Default: ``broad`` for ``.mat``; ``rosbag`` for ``.bag``, ``.mcap``, ``.db3`` or a
        directory with ``metadata.yaml`` (``sensor_msgs/Imu``); else ``euroc_imu``.
    clean : bool
        Drop malformed rows (counted in the report) instead of raising ``ValueError``.
    **options
        ``rate_hz=`` for ``broad``; ``topic=``/``stamp=`` for ``rosbag``; ``frame=`` names the
        sensor frame.

    Returns
    -------
    ImuStream, ReadReport
    """
    path = Path(path)
    if format is None:
        if path.suffix.lower() == ".mat":
            format = "broad"
        else:
            format = "rosbag" if _is_bag(path) else "euroc_imu"
    readers = {"broad": read_broad_imu, "euroc_imu": read_euroc_imu, "rosbag": read_rosbag_imu}
    if format not in readers:
        raise InputError(f"unknown IMU format {format!r}; expected one of {IMU_FORMATS}")
    return readers[format](path, clean=clean, **options)
