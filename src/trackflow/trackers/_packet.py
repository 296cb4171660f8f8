"""What every protocol decoder shares: the typed packet error and a bounds-checked reader."""

from __future__ import annotations

import struct

from ..errors import FormatError
from .wire_checks import MAX_COUNT, MAX_NAME_BYTES, count_fits

__all__ = ["MAX_DATAGRAM", "PacketError", "Reader"]

#: The largest UDP payload over IPv4 [bytes]; a longer "datagram" is refused as oversized.
MAX_DATAGRAM = 65507


class PacketError(FormatError):
    """A packet that cannot be decoded.

    ``reason`` is a short, stable text used to count rejections per sensor (for example
    ``"truncated"``, ``"wrong version"``); the message adds the details (offset, field).
    """

    def __init__(self, reason: str, detail: str = ""):
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


#: compiled struct formats by byte order, shared by every reader (at most _MAX_FORMATS each)
_STRUCTS: dict[str, dict[str, struct.Struct]] = {}
_MAX_FORMATS = 256


class Reader:
    """Sequential reads from a bytes-like object; every read is bounds-checked.

    Parameters
    ----------
    data : bytes-like
    endian : str
        ``"<"`` (NatNet) or ``">"`` (VRPN).
    """

    __slots__ = ("data", "pos", "end", "endian", "_cache")

    def __init__(self, data, endian: str = "<", pos: int = 0, end: int | None = None):
        self.data = memoryview(data).cast("B") if not isinstance(data, bytes) else data
        self.pos = pos
        self.end = len(data) if end is None else end
        self.endian = endian
        self._cache = _STRUCTS.setdefault(endian, {})  # formats shared by every reader

    def remaining(self) -> int:
        return self.end - self.pos

    def need(self, n: int, what: str) -> None:
        if n < 0 or self.pos + n > self.end:
            raise PacketError("truncated", f"{what} needs {n} bytes at offset {self.pos}")

    def unpack(self, fmt: str, what: str) -> tuple:
        s = self._cache.get(fmt)
        if s is None:
            s = struct.Struct(self.endian + fmt)
            if len(self._cache) < _MAX_FORMATS:  # counted formats ("60f") vary per packet
                self._cache[fmt] = s
        pos = self.pos
        if pos + s.size > self.end:
            raise PacketError("truncated", f"{what} needs {s.size} bytes at offset {pos}")
        self.pos = pos + s.size
        return s.unpack_from(self.data, pos)

    def skip(self, n: int, what: str) -> None:
        self.need(n, what)
        self.pos += n

    def cstring(self, what: str, limit: int = MAX_NAME_BYTES) -> str:
        """A NUL-terminated UTF-8 string of at most ``limit`` bytes (plus the NUL)."""
        stop = min(self.end, self.pos + limit + 1)
        raw = bytes(self.data[self.pos : stop])
        k = raw.find(b"\0")
        if k < 0:
            raise PacketError("bad string", f"{what} at offset {self.pos} is not terminated")
        try:
            text = raw[:k].decode("utf-8")
        except UnicodeDecodeError:
            raise PacketError("bad string", f"{what} at offset {self.pos} is not UTF-8") from None
        self.pos += k + 1
        return text

    def count(self, what: str, item_bytes: int, limit: int = MAX_COUNT) -> int:
        """A u32/i32 element count, checked against the bytes left (no huge allocations;
        :func:`~trackflow.trackers.wire_checks.count_fits`)."""
        (n,) = self.unpack("i", what)
        if not count_fits(n, item_bytes, self.remaining(), limit):
            raise PacketError("bad count", f"{what} = {n} at offset {self.pos - 4}")
        return n
