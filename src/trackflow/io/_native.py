"""The native recording format (``.tfrec``): a small header, then fixed-size binary records.

Layout (all little-endian; see ``docs/formats.md`` for the byte table):

* header: magic ``b"\\x89TFREC\\r\\n"`` (8 bytes), version (u16), layout (u16: 0 = no covariance,
  1 = covariance), record size (u32), header size (u32), source and target name lengths (u16
  each), the two UTF-8 names, zero padding, and a CRC-32 of everything before it (u32) plus 4
  zero bytes, so that the header size is a multiple of 8;
* records: ``t_ns`` (i8), position (3 f8), quaternion xyzw (4 f8), [covariance upper triangle,
  36 f8, row-major], confidence (f8), flags (u4), check (u4): 80 bytes, or 368 with covariance.

``check`` is a 32-bit hash of the other bytes of the record, computed vectorised, so a
reader can tell a complete record from garbage (for example zero-filled blocks after a power
failure) at memory speed.

Crash safety: the header is written to a temporary file and renamed into place, so a file
either does not exist or has a complete header. Every :meth:`RecordingWriter.append` hands the
complete records to the operating system in one ``os.write`` before returning, so killing the
writing process loses at most the records of the call in progress; a reader reports an
incomplete last record as a truncated tail instead of failing, and reopening with ``mode="a"``
cuts such a tail off before appending.
"""

from __future__ import annotations

import math
import os
import struct
import zlib
from pathlib import Path

import numpy as np

from ..errors import FormatError, InputError
from ..math import check_covariance
from ._clean import TRUNCATED, finish_stream
from ._output import atomic_output
from ._report import ReadReport
from ._stream import (
    FLAG_COVARIANCE,
    FLAG_ORIENTATION,
    FLAG_POSITION,
    PoseStream,
    check_frame_name,
    unit_quaternions,
)

__all__ = ["MAGIC", "VERSION", "RecordingWriter", "read_native", "write_native"]

MAGIC = b"\x89TFREC\r\n"
VERSION = 1
_FIXED = struct.Struct("<8sHHIIHH")  # magic, version, layout, record size, header size, names

#: Bytes of records read per block: blocks stay in the CPU cache while fields are copied out.
_BLOCK_BYTES = 1 << 20


def record_dtype(covariance: bool) -> np.dtype:
    """The numpy structured dtype of one record."""
    fields = [("t_ns", "<i8"), ("position", "<f8", (3,)), ("quaternion", "<f8", (4,))]
    if covariance:
        fields.append(("covariance", "<f8", (6, 6)))
    fields += [("confidence", "<f8"), ("flags", "<u4"), ("check", "<u4")]
    return np.dtype(fields)


def _hash_constants(n: int) -> np.ndarray:
    ks = [((0x9E3779B97F4A7C15 * (2 * j + 1)) ^ (0xC2B2AE3D27D4EB4F >> j)) | 1 for j in range(n)]
    return np.array([k & 0xFFFFFFFFFFFFFFFF for k in ks], dtype=np.uint64)


_K = {False: _hash_constants(10), True: _hash_constants(46)}
_SEED = np.uint64(0x5EED_7F1C_0DE5_A11E)
_SEED_INT = int(_SEED)
_K_INT = {cov: [int(x) for x in k] for cov, k in _K.items()}
_M64 = 0xFFFFFFFFFFFFFFFF


def _checks(records: np.ndarray, covariance: bool) -> np.ndarray:
    """Check values (u4) of records: a hash of every 64-bit word except the check itself.

    ``h = sum_j K_j w_j (mod 2**64)`` over the words (the last one only its flags half) with
    odd constants ``K_j``, then an avalanche mix; an all-zero record does not pass.
    """
    words = records.view("<u8").reshape(len(records), records.dtype.itemsize // 8)
    last = words.shape[1] - 1
    k = _K[covariance]
    with np.errstate(over="ignore"):
        h = np.einsum("ij,j->i", words[:, :last], k[:last])  # wraps modulo 2**64
        h += (words[:, last] & np.uint64(0xFFFFFFFF)) * k[last]  # the flags half
        h += _SEED
        h ^= h >> np.uint64(29)
        h *= np.uint64(0xBF58476D1CE4E5B9)
        h ^= h >> np.uint64(32)
    return (h & np.uint64(0xFFFFFFFF)).astype(np.uint32)


def _check_one(body: bytes, covariance: bool) -> int:
    """:func:`_checks` of one record given its bytes without the check (pure Python)."""
    nw = len(body) // 8
    words = struct.unpack_from(f"<{nw}Q", body)
    (flags,) = struct.unpack_from("<I", body, 8 * nw)
    k = _K_INT[covariance]
    h = (sum(w * kj for w, kj in zip(words, k)) + flags * k[nw] + _SEED_INT) & _M64
    h ^= h >> 29
    h = (h * 0xBF58476D1CE4E5B9) & _M64
    h ^= h >> 32
    return h & 0xFFFFFFFF


def _header(source: str, target: str, covariance: bool) -> bytes:
    s, t = source.encode(), target.encode()
    if len(s) > 0xFFFF or len(t) > 0xFFFF:
        raise InputError("frame names longer than 65535 bytes")
    body_len = _FIXED.size + len(s) + len(t)
    size = (body_len + 8 + 7) // 8 * 8
    rec = record_dtype(covariance).itemsize
    body = _FIXED.pack(MAGIC, VERSION, int(covariance), rec, size, len(s), len(t)) + s + t
    body += b"\0" * (size - 8 - body_len)
    return body + struct.pack("<II", zlib.crc32(body), 0)


def _parse_header(path, raw: bytes) -> tuple[str, str, bool, int]:
    """Return (source, target, has_covariance, header_size) or raise ValueError."""
    if len(raw) < 8 or raw[:8] != MAGIC:
        raise FormatError(f"{path}: not a trackflow recording (magic bytes do not match)")
    if len(raw) < _FIXED.size:
        raise FormatError(f"{path}: header is incomplete ({len(raw)} bytes)")
    _, version, layout, rec, size, ls, lt = _FIXED.unpack_from(raw)
    if version != VERSION:
        raise FormatError(f"{path}: recording format version {version} is not supported (1 is)")
    if layout not in (0, 1) or rec != record_dtype(bool(layout)).itemsize:
        raise FormatError(f"{path}: header has unknown layout {layout} / record size {rec}")
    if len(raw) < size or size < _FIXED.size + ls + lt + 8:
        raise FormatError(f"{path}: header is incomplete or inconsistent ({size} bytes declared)")
    (crc,) = struct.unpack_from("<I", raw, size - 8)
    if crc != zlib.crc32(raw[: size - 8]):
        raise FormatError(f"{path}: header checksum mismatch (corrupt header)")
    o = _FIXED.size
    try:
        source = raw[o : o + ls].decode()
        target = raw[o + ls : o + ls + lt].decode()
    except UnicodeDecodeError as exc:
        raise FormatError(f"{path}: frame names are not UTF-8") from exc
    return source, target, bool(layout), size


def read_native(path, *, clean: bool = False) -> tuple[PoseStream, ReadReport]:
    """Read a ``.tfrec`` recording into a :class:`PoseStream`.

    An incomplete last record (a killed writer) and trailing records whose check value does not
    match (zero-filled or torn blocks after a crash) are dropped as ``"truncated tail"`` and
    reported, never an error. A bad record before valid ones is corruption: ``ValueError``
    naming the file and record, or dropped with ``clean=True``. Locations in the report are
    0-based record indices.
    """
    path = Path(path)
    with open(path, "rb") as f:
        head = f.read(4096)
        source, target, has_cov, hsize = _parse_header(path, head)
        if hsize > len(head):
            head += f.read(hsize - len(head))
        f.seek(0, os.SEEK_END)
        size = f.tell()
        dt = record_dtype(has_cov)
        n_full, tail = divmod(size - hsize, dt.itemsize)
        f.seek(hsize)
        # copy the fields out block by block: one pass over the data instead of one per field
        t_ns = np.empty(n_full, dtype=np.int64)
        pos = np.empty((n_full, 3))
        quat = np.empty((n_full, 4))
        cov = np.empty((n_full, 6, 6)) if has_cov else None
        conf = np.empty(n_full)
        flags = np.empty(n_full, dtype=np.uint32)
        valid = np.empty(n_full, dtype=bool)
        step = max(1, _BLOCK_BYTES // dt.itemsize)
        buf = np.empty(step, dtype=dt)
        raw = buf.view(np.uint8)
        for i in range(0, n_full, step):
            m = min(step, n_full - i)
            got = f.readinto(raw[: m * dt.itemsize])
            if got != m * dt.itemsize:
                raise FormatError(f"{path}: file shrank while being read")
            b = buf[:m]
            t_ns[i : i + m] = b["t_ns"]
            pos[i : i + m] = b["position"]
            quat[i : i + m] = b["quaternion"]
            if has_cov:
                cov[i : i + m] = b["covariance"]
            conf[i : i + m] = b["confidence"]
            flags[i : i + m] = b["flags"]
            valid[i : i + m] = b["check"] == _checks(b, has_cov)
    report = ReadReport(str(path), "native", unit="record", rows_read=n_full + (tail > 0))
    n_ok = n_full
    if not valid.all():
        last_good = np.flatnonzero(valid)
        n_ok = int(last_good[-1]) + 1 if last_good.size else 0
        if n_ok < n_full:  # trailing run of bad records: a crash tail
            report.drop(TRUNCATED, range(n_ok, n_full))
            report.truncated_bytes += (n_full - n_ok) * dt.itemsize
            report.notes.append(f"{n_full - n_ok} trailing record(s) with bad check values")
        bad = np.flatnonzero(~valid[:n_ok])
        if bad.size:
            if not clean:
                i = int(bad[0])
                raise FormatError(
                    f"{path}: record {i} (byte offset {hsize + i * dt.itemsize}): check value "
                    f"mismatch, the record is corrupt ({bad.size} such records; read with "
                    "clean=True to drop them)"
                )
            report.drop("corrupt record (check mismatch)", bad)
    if tail:
        report.drop(TRUNCATED, n_full)
        report.truncated_bytes += tail
    good = valid.copy()
    good[n_ok:] = False
    idx = slice(0, n_ok) if good[:n_ok].all() else np.flatnonzero(good)
    if not (isinstance(idx, slice) and n_ok == n_full):
        t_ns, pos, quat, conf, flags = t_ns[idx], pos[idx], quat[idx], conf[idx], flags[idx]
        cov = None if cov is None else cov[idx]
    report_rows = report.rows_read
    where = np.arange(n_full)[idx]
    stream = finish_stream(
        report,
        where=where,
        t_ns=t_ns,
        position=pos,
        quaternion=quat,
        covariance=cov,
        confidence=conf,
        flags=flags,
        source=source,
        target=target,
        clean=clean,
        check_covariance_psd=False,
    )
    assert report.rows_read == report_rows
    return stream, report


def _pack(t_ns, position, quaternion, covariance, confidence, flags, has_cov: bool) -> np.ndarray:
    n = len(t_ns)
    rec = np.zeros(n, dtype=record_dtype(has_cov))
    rec["t_ns"] = t_ns
    rec["position"] = position
    rec["quaternion"] = quaternion
    if has_cov:
        rec["covariance"] = covariance
    rec["confidence"] = confidence
    rec["flags"] = flags
    rec["check"] = _checks(rec, has_cov)
    return rec


class RecordingWriter:
    """Append-only, crash-safe writer of a ``.tfrec`` recording of ``T_source_target``.

    Parameters
    ----------
    path : str or Path
    source, target : str
        Frames of the recorded relationship.
    covariance : bool
        Whether records carry a 6x6 covariance (fixed for the file).
    mode : {"w", "x", "a"}
        ``"w"`` create or replace, ``"x"`` create and fail if the file exists, ``"a"`` append to
        an existing recording (created if missing); its frames and layout must match, and an
        incomplete or corrupt tail left by a crash is cut off first (``recovered_bytes``).

    Notes
    -----
    Each :meth:`append` writes complete records with a single ``os.write`` (nothing is
    buffered in the process), so a killed writer loses at most the call in progress.
    :meth:`flush` additionally asks the OS to put the data on disk (``fsync``), which only
    matters for power loss. Timestamps must strictly increase across appends.

    Examples
    --------
    >>> with RecordingWriter("run.tfrec", "world", "head", covariance=False) as w:  # doctest: +SKIP
    ...     w.append(stream)
    """

    def __init__(self, path, source: str, target: str, *, covariance: bool, mode: str = "w"):
        self._fd: int | None = None
        if mode not in ("w", "x", "a"):
            raise InputError(f"mode must be 'w', 'x' or 'a', got {mode!r}")
        self.path = Path(path)
        self.source = check_frame_name(source, "source")
        self.target = check_frame_name(target, "target")
        self.has_covariance = bool(covariance)
        self.recovered_bytes = 0
        self.count = 0
        self._last_t: int | None = None
        self._dtype = record_dtype(self.has_covariance)
        if mode == "a" and self.path.exists():
            self._open_existing()
        else:
            if mode == "x" and self.path.exists():
                raise InputError(f"{self.path}: exists already (mode 'x')")
            tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            try:
                _write_all(fd, _header(source, target, self.has_covariance))
                os.fsync(fd)
            finally:
                os.close(fd)
            os.replace(tmp, self.path)
            self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)

    def _open_existing(self) -> None:
        with open(self.path, "rb") as f:
            raw = f.read(4096)
            source, target, has_cov, hsize = _parse_header(self.path, raw)
        if (source, target, has_cov) != (self.source, self.target, self.has_covariance):
            raise InputError(
                f"{self.path}: recording holds T_{source}_{target} "
                f"({'with' if has_cov else 'without'} covariance); cannot append "
                f"T_{self.source}_{self.target} "
                f"({'with' if self.has_covariance else 'without'} covariance)"
            )
        size = self.path.stat().st_size
        rs = self._dtype.itemsize
        n = (size - hsize) // rs
        fd = os.open(self.path, os.O_RDWR)
        try:
            # walk back over a crash tail: records whose check value does not match
            good = n
            while good > 0:
                b = os.pread(fd, rs, hsize + (good - 1) * rs)
                rec = np.frombuffer(b, dtype=self._dtype)
                if rec["check"][0] == _checks(rec, self.has_covariance)[0]:
                    self._last_t = int(rec["t_ns"][0])
                    break
                good -= 1
            end = hsize + good * rs
            if end != size:
                self.recovered_bytes = size - end
                os.ftruncate(fd, end)
                os.fsync(fd)
            self.count = good
        finally:
            os.close(fd)
        self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)

    def append(self, stream: PoseStream) -> None:
        """Append every sample of ``stream`` (same frames; covariance iff the file has one)."""
        if self._fd is None:
            raise InputError(f"{self.path}: writer is closed")
        if (stream.source, stream.target) != (self.source, self.target):
            raise InputError(
                f"{self.path}: cannot append T_{stream.source}_{stream.target} to a recording "
                f"of T_{self.source}_{self.target}"
            )
        if (stream.covariance is not None) != self.has_covariance:
            need = "needs" if self.has_covariance else "does not take"
            raise InputError(f"{self.path}: this recording {need} a covariance per sample")
        if not len(stream):
            return
        if self._last_t is not None and stream.t_ns[0] <= self._last_t:
            raise InputError(
                f"{self.path}: timestamp {int(stream.t_ns[0])} ns is not after the last recorded "
                f"{self._last_t} ns"
            )
        rec = _pack(
            stream.t_ns,
            stream.position,
            stream.quaternion,
            stream.covariance,
            stream.confidence,
            stream.flags,
            self.has_covariance,
        )
        _write_all(self._fd, rec.tobytes())
        self._last_t = int(stream.t_ns[-1])
        self.count += len(stream)

    def append_sample(
        self, t_ns: int, position, quaternion, covariance=None, confidence=None, flags=None
    ) -> None:
        """Append one sample; arguments as one row of :class:`PoseStream`'s fields.

        ``flags`` defaults to position and orientation valid (plus covariance when given).
        This is the per-measurement path of a live recorder, so it avoids numpy overhead.
        """
        if self._fd is None:
            raise InputError(f"{self.path}: writer is closed")
        t = int(t_ns)
        p = [float(x) for x in np.ravel(position)]
        q = [float(x) for x in np.ravel(quaternion)]
        if len(p) != 3 or len(q) != 4:
            raise InputError(f"{self.path}: position needs 3 and quaternion 4 values")
        if not all(math.isfinite(x) for x in p):
            raise InputError(f"{self.path}: position contains NaN or inf")
        if abs(sum(x * x for x in q) - 1.0) > 2e-12:
            q = unit_quaternions(np.array(q)).tolist()  # raises unless unit to 1e-6
        if (covariance is not None) != self.has_covariance:
            need = "needs" if self.has_covariance else "does not take"
            raise InputError(f"{self.path}: this recording {need} a covariance per sample")
        tri = []
        if covariance is not None:
            tri = check_covariance(np.reshape(covariance, (6, 6))).ravel().tolist()
        conf = 1.0 if confidence is None else float(confidence)
        if not 0.0 <= conf <= 1.0:
            raise InputError(f"{self.path}: confidence {conf} not in [0, 1]")
        if flags is None:
            flags = FLAG_POSITION | FLAG_ORIENTATION | (FLAG_COVARIANCE if tri else 0)
        if self._last_t is not None and t <= self._last_t:
            raise InputError(
                f"{self.path}: timestamp {t} ns is not after the last recorded {self._last_t} ns"
            )
        body = struct.pack(f"<q{8 + len(tri)}dI", t, *p, *q, *tri, conf, int(flags))
        _write_all(self._fd, body + struct.pack("<I", _check_one(body, self.has_covariance)))
        self._last_t = t
        self.count += 1

    def flush(self) -> None:
        """Make appended records durable on disk (``fsync``); they already survive a kill."""
        if self._fd is not None:
            os.fsync(self._fd)

    def close(self) -> None:
        """Flush and close; further appends raise ``ValueError``. Safe to call twice."""
        if self._fd is not None:
            try:
                os.fsync(self._fd)
            finally:
                os.close(self._fd)
                self._fd = None

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        fd = getattr(self, "_fd", None)
        if fd is not None:
            os.close(fd)


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        k = os.write(fd, view)
        view = view[k:]


def write_native(path, stream: PoseStream, *, overwrite: bool = False) -> None:
    """Write ``stream`` as a new ``.tfrec`` file under the output policy of
    :func:`trackflow.io.atomic_output` (atomic; an existing file only with ``overwrite``)."""
    with atomic_output(path, overwrite=overwrite) as tmp:
        with RecordingWriter(
            tmp, stream.source, stream.target, covariance=stream.covariance is not None
        ) as w:
            w.append(stream)
