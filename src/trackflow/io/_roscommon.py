"""What the ROS bag readers and writers share: ``rosbags``, type stores, bag paths and storage.

Paths
-----
ROS 1 bags are single ``.bag`` files. ROS 2 bags are *directories* holding ``metadata.yaml`` and
one storage file, SQLite (``.db3``) or MCAP (``.mcap``); ``rosbags`` reads and writes them only
as such directories. The names a user gives map to bags like this:

=====================  =====================================================================
path                   bag
=====================  =====================================================================
``run.bag``            ROS 1 bag file ``run.bag``
``run.mcap``           ROS 2 bag directory ``run/`` holding ``run/run.mcap`` (MCAP)
``run.db3``            ROS 2 bag directory ``run/`` holding ``run/run.db3`` (SQLite)
``run`` (no suffix)    ROS 2 bag directory ``run/`` in the storage asked for (default SQLite)
=====================  =====================================================================

Reading accepts the bag directory, its storage file, or the name it was written under (so
``run.mcap`` reads ``run/`` when there is no file ``run.mcap``). A bare MCAP or SQLite file
without its ``metadata.yaml`` is refused with a hint: ``rosbags`` needs the directory (``ros2 bag
reindex`` writes a missing ``metadata.yaml``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

from ..errors import FormatError, InputError
from ..optional import require
from ._output import atomic_output

__all__ = [
    "ROS2_STORAGES",
    "bag_read_path",
    "bag_write_path",
    "bag_writer",
    "check_stamp_mode",
    "header",
    "is_ros1",
    "open_bag",
    "pick_topic",
    "require_rosbags",
    "serializer",
    "stamp_ns",
    "typestore",
]

#: ROS 2 storage plugin name -> suffix of its storage file.
ROS2_STORAGES = {"sqlite3": ".db3", "mcap": ".mcap"}
_STORAGE_OF_SUFFIX = {v: k for k, v in ROS2_STORAGES.items()}

#: ``tf2_msgs/TFMessage`` as ROS 1 defines it (the ROS 1 type store of rosbags lacks it).
_TF_MESSAGE_DEF = "geometry_msgs/TransformStamped[] transforms"


def require_rosbags() -> None:
    """Raise :class:`~trackflow.errors.MissingExtraError` (an ``ImportError``) naming the
    extra to install when ``rosbags`` is missing."""
    require("rosbags", extra="ros", feature="ROS bags")


def is_ros1(path: Path) -> bool:
    """True for a ROS 1 bag (suffix ``.bag``)."""
    return Path(path).suffix == ".bag"


def typestore(ros1: bool):
    """The ``rosbags`` type store of ROS 1 Noetic or ROS 2 Humble (with ``TFMessage`` in both)."""
    require_rosbags()
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if "tf2_msgs/msg/TFMessage" not in store.types:
        store.register(get_types_from_msg(_TF_MESSAGE_DEF, "tf2_msgs/msg/TFMessage"))
    return store


def bag_read_path(path) -> Path:
    """The path ``rosbags`` opens for ``path`` (module docstring, "Paths").

    Raises
    ------
    FormatError
        ``path`` is an MCAP or SQLite file without ``metadata.yaml`` beside it.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in _STORAGE_OF_SUFFIX:
        return path
    if path.is_file():
        if (path.parent / "metadata.yaml").is_file():
            return path.parent  # a storage file: read its bag directory
        raise FormatError(
            f"{path}: a bare {_STORAGE_OF_SUFFIX[suffix]} file without metadata.yaml; ROS 2 "
            "bags are read as directories (put it in a folder with its metadata.yaml, or "
            "run 'ros2 bag reindex' on that folder to write one)"
        )
    written = path.with_suffix("")
    if not path.exists() and (written / "metadata.yaml").is_file():
        return written  # the name the bag was written under (run.mcap -> run/)
    return path


def bag_write_path(path, storage: str | None = None) -> tuple[Path, bool, str | None]:
    """Where a bag written to ``path`` goes: ``(bag path, ROS 1?, ROS 2 storage or None)``.

    Parameters
    ----------
    path : path-like
        ``.bag`` (ROS 1), ``.mcap`` / ``.db3`` (ROS 2 directory named without the suffix, in
        that storage) or anything else (ROS 2 directory of that name).
    storage : {"sqlite3", "mcap"}, optional
        ROS 2 storage; must agree with a ``.mcap``/``.db3`` suffix. Default from the suffix,
        else ``"sqlite3"``.
    """
    path = Path(path)
    if storage is not None and storage not in ROS2_STORAGES:
        raise InputError(f"storage must be one of {sorted(ROS2_STORAGES)}, got {storage!r}")
    if is_ros1(path):
        if storage is not None:
            raise InputError(f"{path}: a ROS 1 bag has no storage choice (storage={storage!r})")
        return path, True, None
    implied = _STORAGE_OF_SUFFIX.get(path.suffix.lower())
    if implied is not None:
        if storage is not None and storage != implied:
            raise InputError(f"{path}: the suffix says {implied}, storage= says {storage}")
        return path.with_suffix(""), False, implied
    return path, False, storage or "sqlite3"


@contextlib.contextmanager
def bag_writer(path, *, overwrite: bool, storage: str | None = None) -> Iterator[tuple]:
    """Open a new bag at ``path`` (see :func:`bag_write_path`) under the output policy.

    Yields ``(writer, store, ros1)``: an open ``rosbags`` writer, the type store to build and
    serialise messages with, and whether it is a ROS 1 bag. The bag is published (atomically)
    when the block ends without an exception.
    """
    require_rosbags()
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2

    bag, ros1, storage = bag_write_path(path, storage)
    store = typestore(ros1)
    with atomic_output(bag, overwrite=overwrite, directory=not ros1) as tmp:
        if ros1:
            writer = Writer1(tmp)
        else:
            plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
            writer = Writer2(tmp, version=8, storage_plugin=plugin)
        with writer:
            yield writer, store, ros1


def open_bag(path):
    """Open a bag for reading: ``(rosbags AnyReader, the path opened)``; close the reader.

    Raises
    ------
    FormatError
        The path is not a readable bag (garbage files fail deep inside the bag parsers).
    """
    require_rosbags()
    from rosbags.highlevel import AnyReader, AnyReaderError

    path = bag_read_path(path)
    try:
        reader = AnyReader([path], default_typestore=typestore(is_ros1(path)))
        reader.open()
    except (AnyReaderError, ValueError, KeyError, IndexError, EOFError) as exc:
        raise FormatError(f"{path}: cannot open as a ROS bag ({exc})") from None
    return reader, path


def check_stamp_mode(stamp: str) -> None:
    """``stamp=`` of the bag readers: ``"header"`` or ``"receive"``."""
    if stamp not in ("header", "receive"):
        raise InputError(f"stamp must be 'header' or 'receive', got {stamp!r}")


def stamp_ns(stamp) -> int:
    """A ROS ``Time`` (``sec``, ``nanosec``) as integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def header(store, ros1: bool, seq: int, t_ns: int, frame_id: str):
    """A ``std_msgs/Header`` stamped ``t_ns`` (ROS 1 headers carry ``seq`` too)."""
    T = store.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    stamp = Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)
    if ros1:
        return Header(seq=seq, stamp=stamp, frame_id=frame_id)
    return Header(stamp=stamp, frame_id=frame_id)


def serializer(store, ros1: bool):
    """``serialize(msg, msgtype) -> bytes`` of the bag's encoding (ROS 1 or CDR)."""
    return store.serialize_ros1 if ros1 else store.serialize_cdr


def pick_topic(path, reader, topic: str | None, candidates: list[str], kind: str) -> str:
    """The topic to read: ``topic`` (it must be one of ``candidates`` when they are given in
    full), or the bag's only candidate; else a ``FormatError`` listing every topic of the bag.

    ``candidates`` are the sorted topics carrying ``kind`` (a message type or "pose").
    """
    if topic is None:
        if len(candidates) != 1:
            all_topics = sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})
            raise FormatError(
                f"{path}: {'no' if not candidates else 'several'} {kind} topics; pass topic= "
                f"one of: {', '.join(all_topics) or 'none'}"
            )
        return candidates[0]
    if topic not in candidates:
        raise FormatError(f"{path}: no supported {kind} messages on topic {topic!r}")
    return topic
