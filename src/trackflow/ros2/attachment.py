"""The attachment rmw_zenoh sends with every message of a topic.

It is written with Zenoh's serializer (``zenoh::ext::Serializer``): three key-value pairs in
this order, each key a string (its length as LEB128, then UTF-8), ``sequence_number`` and
``source_timestamp`` as int64 little endian, ``source_gid`` as a sequence of 16 bytes (its
length 16 as LEB128, then the bytes)::

    0f "sequence_number"  <int64 LE>
    10 "source_timestamp" <int64 LE>   (the publisher's clock when it sent, ns)
    0a "source_gid"       10 <16 bytes>

``tests/ros2/test_ros2_codec.py`` checks these bytes against Python Zenoh's own
``zenoh.ext.z_serialize``.
"""

from __future__ import annotations

import struct
from typing import NamedTuple

from ..errors import FormatError

__all__ = ["Attachment", "AttachmentError", "decode_attachment", "encode_attachment"]

_INT64 = struct.Struct("<q")
_KEYS = (b"sequence_number", b"source_timestamp", b"source_gid")
GID_SIZE = 16


class AttachmentError(FormatError):
    """An attachment that is not rmw_zenoh's (counted as a rejection by the receiver)."""


class Attachment(NamedTuple):
    """What rmw_zenoh attaches to a message."""

    sequence_number: int
    source_timestamp: int
    source_gid: bytes


def _key(name: bytes) -> bytes:
    return bytes((len(name),)) + name  # every key is shorter than 128 bytes: one LEB128 byte


_PREFIX = [_key(k) for k in _KEYS]


def encode_attachment(sequence_number: int, source_timestamp: int, source_gid: bytes) -> bytes:
    """The attachment of one message (module docstring)."""
    if len(source_gid) != GID_SIZE:
        raise ValueError(f"source_gid has {len(source_gid)} bytes, not {GID_SIZE}")
    return b"".join((
        _PREFIX[0], _INT64.pack(sequence_number),
        _PREFIX[1], _INT64.pack(source_timestamp),
        _PREFIX[2], bytes((GID_SIZE,)), bytes(source_gid),
    ))  # fmt: skip


def decode_attachment(data: bytes) -> Attachment:
    """Read an attachment; :class:`AttachmentError` when it is not exactly one of rmw_zenoh's
    (wrong keys, order or lengths, or bytes left over)."""
    data = bytes(data)
    pos, values = 0, []
    for k, prefix in enumerate(_PREFIX):
        if data[pos : pos + len(prefix)] != prefix:
            raise AttachmentError(f"attachment: no {_KEYS[k].decode()!r} at byte {pos}")
        pos += len(prefix)
        if k < 2:
            if len(data) < pos + 8:
                raise AttachmentError(f"attachment: {_KEYS[k].decode()} cut short")
            values.append(_INT64.unpack_from(data, pos)[0])
            pos += 8
        else:
            if data[pos : pos + 1] != bytes((GID_SIZE,)) or len(data) < pos + 1 + GID_SIZE:
                raise AttachmentError("attachment: source_gid is not 16 bytes")
            values.append(data[pos + 1 : pos + 1 + GID_SIZE])
            pos += 1 + GID_SIZE
    if pos != len(data):
        raise AttachmentError(f"attachment: {len(data) - pos} bytes after source_gid")
    return Attachment(*values)
