"""A.R.T. DTrack2/DTrack3 ASCII output: a pure decoder, an encoder and the pose conversion.

One UDP datagram holds one frame: lines separated by CRLF (a bare LF is accepted), each
starting with an identifier. Lines decoded here (DTrack2 User Manual, Technical Appendix B.2;
ar-tracking/DTrackSDK ``DTrackParser.cpp``):

* ``fr <n>``                           frame counter
* ``ts <s>``                           exposure time, seconds since midnight (UTC) of the
  tracker's clock, microsecond resolution; :class:`DayUnwrapper` removes the midnight jump
* ``ts2 <s> <us> <latency_us>``        exposure time as Unix seconds + microseconds, and the
  latency from exposure to sending the frame [us]
* ``6dcal <n>``                        number of calibrated bodies
* ``6d <n> [id qu][x y z eta theta phi][b0 .. b8]``   bodies: position [mm], Euler angles
  [deg] (ignored: the matrix is exact), rotation matrix **column-wise** (``b0 b1 b2`` is the
  first column); quality ``-1`` means not tracked (dummy zero pose)
* ``6dcov <n> [id crx cry crz][s11 s12 .. s66]``  6x6 covariance of the location of the
  reference point ``cr`` [mm, body coordinates] and of the Euler angles [rad], 21 values of
  the upper triangle row by row (:func:`dtrack_covariance`)
* ``3d <n> [id qu][x y z]``             single markers [mm]
* ``6di <n> [id st err][x y z][b0 .. b8]`` hybrid (inertial) bodies: state 0 not tracked,
  1 inertial only, 2 optical and inertial; drift error estimate [deg]
* ``6df2 <ncal> <n> [id qu nbt njt][x y z][b0 .. b8][bt.. js..]`` Flysticks (ids ``0 ..
  n-1`` in order): ``nbt`` buttons packed 32 to an integer word (bit ``j % 32`` of word
  ``j // 32`` is button ``j``), then ``njt`` joystick values in ``[-1, 1]``
* ``6dmt2 <ncal> <n> [id qu nbt r][x y z][b0 .. b8][bt..][c11 c12 c13 c22 c23 c33]``
  measurement tools (ids in order): tip radius ``r`` [mm], button words as for Flysticks,
  and the 3x3 covariance of the tip position [mm^2] (upper triangle row by row)
* ``gl <n> [id qu lr nf][x y z][b0 .. b8]`` then per finger
  ``[x y z][b0 .. b8][rt l0 a0 l1 a1 l2]``: Fingertracking hands (``lr`` 0 left, 1 right),
  the back of the hand in room coordinates, each finger tip in hand coordinates [mm], tip
  radius, phalanx lengths [mm] and the angles between them [deg]
* ``st <ngrp> [0 nv][cams bodies markers] [1 nv][cam_err cam_warn err warn info]
  [2 ncam nv][id refl used intensity] ..``  system status: general counts, message counts
  and per camera the reflections seen and used and the maximal intensity; unknown groups
  are skipped by their sizes

Any other identifier (``6dj``, ``6dmtr`` ...) is skipped and listed in
:attr:`DTrackFrame.skipped`. Malformed known lines raise :class:`PacketError`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..math import quat_from_matrix
from ._packet import MAX_DATAGRAM, PacketError

__all__ = [
    "DTrackBody",
    "DTrackCovariance",
    "DTrackFrame",
    "DTrackFinger",
    "DTrackFlystick",
    "DTrackHand",
    "DTrackInertial",
    "DTrackMarker",
    "DTrackStatus",
    "DTrackTool",
    "DayUnwrapper",
    "decode_dtrack",
    "dtrack_covariance",
    "dtrack_euler",
    "dtrack_pose",
    "encode_dtrack",
]

_BLOCK = re.compile(rb"\[([^\[\]]*)\]")


class DTrackBody(NamedTuple):
    """A ``6d`` body: ``position_mm`` (3,), ``rotation`` the 3x3 matrix row by row (9,),
    ``R_room_body``; ``quality`` -1 = not tracked."""

    id: int
    quality: float
    position_mm: tuple[float, float, float]
    rotation: tuple[float, ...]
    euler_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)


class DTrackCovariance(NamedTuple):
    """A ``6dcov`` entry: ``reference_mm`` (3,) in body coordinates and the full 6x6
    ``matrix`` (36 values row by row) as sent: position [mm^2], orientation [rad^2]."""

    id: int
    reference_mm: tuple[float, float, float]
    matrix: tuple[float, ...]


class DTrackMarker(NamedTuple):
    """A ``3d`` marker: ``position_mm`` (3,)."""

    id: int
    quality: float
    position_mm: tuple[float, float, float]


class DTrackInertial(NamedTuple):
    """A ``6di`` hybrid body: ``state`` 0/1/2, ``error_deg`` the drift estimate."""

    id: int
    state: int
    error_deg: float
    position_mm: tuple[float, float, float]
    rotation: tuple[float, ...]


class DTrackFlystick(NamedTuple):
    """A ``6df2`` Flystick: pose as :class:`DTrackBody` (quality -1 = not tracked),
    ``buttons`` (one bool per button) and ``joysticks`` (values in [-1, 1])."""

    id: int
    quality: float
    position_mm: tuple[float, float, float]
    rotation: tuple[float, ...]
    buttons: tuple[bool, ...] = ()
    joysticks: tuple[float, ...] = ()


class DTrackTool(NamedTuple):
    """A ``6dmt2`` measurement tool: pose as :class:`DTrackBody`, ``tip_radius_mm``,
    ``buttons`` and ``position_cov_mm2`` the 3x3 covariance of the tip (9 values, row by
    row, room coordinates [mm^2])."""

    id: int
    quality: float
    position_mm: tuple[float, float, float]
    rotation: tuple[float, ...]
    tip_radius_mm: float = 0.0
    buttons: tuple[bool, ...] = ()
    position_cov_mm2: tuple[float, ...] = (0.0,) * 9


class DTrackFinger(NamedTuple):
    """One finger of a ``gl`` hand: the tip's ``position_mm`` and ``rotation`` (row by row)
    in the hand's coordinates, ``tip_radius_mm``, ``phalanx_mm`` (outer, middle, inner
    lengths) and ``angles_deg`` (outer-middle, middle-inner)."""

    position_mm: tuple[float, float, float]
    rotation: tuple[float, ...]
    tip_radius_mm: float
    phalanx_mm: tuple[float, float, float]
    angles_deg: tuple[float, float]


class DTrackHand(NamedTuple):
    """A ``gl`` Fingertracking hand: the back of the hand as :class:`DTrackBody` (quality
    -1 = not tracked), ``right`` (``lr`` 1) and its ``fingers``."""

    id: int
    quality: float
    right: bool
    position_mm: tuple[float, float, float]
    rotation: tuple[float, ...]
    fingers: tuple[DTrackFinger, ...] = ()


class DTrackStatus(NamedTuple):
    """An ``st`` line: general counts, message counts, and per camera ``(id, reflections,
    reflections used, maximal intensity)``; -1 for a group the line did not have."""

    cameras: int = -1
    tracked_bodies: int = -1
    tracked_markers: int = -1
    camera_errors: int = -1
    camera_warnings: int = -1
    other_errors: int = -1
    other_warnings: int = -1
    infos: int = -1
    camera_status: tuple[tuple[int, int, int, int], ...] = ()


@dataclass(frozen=True, slots=True)
class DTrackFrame:
    """One decoded DTrack datagram. ``ts`` [s of day] and ``ts2`` ``(sec, usec,
    latency_us)`` are ``None`` when absent."""

    frame: int | None = None
    ts: float | None = None
    ts2: tuple[int, int, int] | None = None
    calibrated: int | None = None
    bodies: tuple[DTrackBody, ...] = ()
    covariances: tuple[DTrackCovariance, ...] = ()
    markers: tuple[DTrackMarker, ...] = ()
    inertial: tuple[DTrackInertial, ...] = ()
    skipped: tuple[str, ...] = field(default=())
    flysticks: tuple[DTrackFlystick, ...] = ()
    tools: tuple[DTrackTool, ...] = ()
    hands: tuple[DTrackHand, ...] = ()
    status: DTrackStatus | None = None

    def body(self, body_id: int) -> DTrackBody | None:
        for b in self.bodies:
            if b.id == body_id:
                return b
        return None

    def covariance(self, body_id: int) -> DTrackCovariance | None:
        for c in self.covariances:
            if c.id == body_id:
                return c
        return None


def _floats(text: bytes, n: int, what: str) -> list[float]:
    parts = text.split()
    if len(parts) != n:
        raise PacketError("bad line", f"{what}: expected {n} numbers, got {len(parts)}")
    try:
        out = [float(p) for p in parts]
    except ValueError:
        raise PacketError("bad line", f"{what}: not a number in {text[:40]!r}") from None
    if not all(math.isfinite(v) for v in out):
        raise PacketError("bad line", f"{what}: non-finite number")
    return out


def _int(tok: bytes, what: str) -> int:
    try:
        v = int(tok)
    except ValueError:
        raise PacketError("bad line", f"{what}: {tok[:20]!r} is not an integer") from None
    return v


def _blocks(rest: bytes, sizes: tuple[int, ...], what: str) -> tuple[int, list[list[float]]]:
    head, _, _ = rest.partition(b"[")
    toks = head.split()
    if not toks:
        raise PacketError("bad line", f"{what}: missing count")
    n = _int(toks[-1], what)
    blocks = _BLOCK.findall(rest)
    if n < 0 or len(blocks) != n * len(sizes):
        raise PacketError("bad line", f"{what}: count {n} but {len(blocks)} blocks")
    vals = [_floats(b, sizes[i % len(sizes)], what) for i, b in enumerate(blocks)]
    return n, vals


def _as_id(v: float, what: str) -> int:
    if v != int(v) or v < 0:
        raise PacketError("bad line", f"{what}: id {v} is not a non-negative integer")
    return int(v)


#: Our bounds against garbage (DTrack sends far fewer): buttons, joystick values, fingers.
_MAX_BUTTONS, _MAX_JOYSTICKS, _MAX_FINGERS = 128, 16, 5


class _Cursor:
    """The ``[...]`` blocks of one line, taken in order, each with an exact size."""

    def __init__(self, rest: bytes, what: str, counts: int):
        head, _, _ = rest.partition(b"[")
        toks = head.split()
        if len(toks) != counts:
            raise PacketError("bad line", f"{what}: expected {counts} count(s) before the blocks")
        self.counts = [_int(t, what) for t in toks]
        if any(c < 0 for c in self.counts):
            raise PacketError("bad line", f"{what}: negative count")
        self.blocks = _BLOCK.findall(rest)
        self.i = 0
        self.what = what

    def take(self, n: int) -> list[float]:
        if self.i >= len(self.blocks):
            raise PacketError("bad line", f"{self.what}: fewer blocks than announced")
        self.i += 1
        return _floats(self.blocks[self.i - 1], n, self.what)

    def take_any(self) -> list[float]:
        """The next block, whatever its size."""
        if self.i >= len(self.blocks):
            raise PacketError("bad line", f"{self.what}: fewer blocks than announced")
        self.i += 1
        b = self.blocks[self.i - 1]
        return _floats(b, len(b.split()), self.what)

    def done(self) -> None:
        if self.i != len(self.blocks):
            raise PacketError("bad line", f"{self.what}: more blocks than announced")


def _small(v: float, limit: int, what: str) -> int:
    if v != int(v) or not 0 <= v <= limit:
        raise PacketError("bad line", f"{what}: {v} is not an integer in [0, {limit}]")
    return int(v)


def _buttons(words: list[float], n: int, what: str) -> tuple[bool, ...]:
    """``n`` buttons from 32-bit words (bit ``j % 32`` of word ``j // 32``)."""
    ints = [_small(w, 0xFFFFFFFF, what) for w in words]
    return tuple(bool(ints[j // 32] >> (j % 32) & 1) for j in range(n))


def _button_words(buttons: tuple[bool, ...]) -> list[int]:
    words = [0] * (-(-len(buttons) // 32))
    for j, b in enumerate(buttons):
        words[j // 32] |= int(bool(b)) << (j % 32)
    return words


def _in_order(v: float, i: int, what: str) -> int:
    if v != i:
        raise PacketError("bad line", f"{what}: id {v} where {i} was expected (ids in order)")
    return i


def _line_6df2(rest: bytes) -> list[DTrackFlystick]:
    c = _Cursor(rest, "6df2", 2)
    out = []
    for i in range(c.counts[1]):
        a = c.take(4)
        nbt = _small(a[2], _MAX_BUTTONS, "6df2 buttons")
        njt = _small(a[3], _MAX_JOYSTICKS, "6df2 joysticks")
        p, r = c.take(3), c.take(9)
        nw = -(-nbt // 32)
        tail = c.take(nw + njt)
        out.append(
            DTrackFlystick(
                _in_order(a[0], i, "6df2"),
                a[1],
                (p[0], p[1], p[2]),
                _col_to_rows(r),
                _buttons(tail[:nw], nbt, "6df2 buttons"),
                tuple(tail[nw:]),
            )
        )
    c.done()
    return out


def _line_6dmt2(rest: bytes) -> list[DTrackTool]:
    c = _Cursor(rest, "6dmt2", 2)
    out = []
    for i in range(c.counts[1]):
        a = c.take(4)
        nbt = _small(a[2], _MAX_BUTTONS, "6dmt2 buttons")
        p, r = c.take(3), c.take(9)
        words = c.take(-(-nbt // 32))
        t = c.take(6)
        cov = (t[0], t[1], t[2], t[1], t[3], t[4], t[2], t[4], t[5])
        out.append(
            DTrackTool(
                _in_order(a[0], i, "6dmt2"),
                a[1],
                (p[0], p[1], p[2]),
                _col_to_rows(r),
                a[3],
                _buttons(words, nbt, "6dmt2 buttons"),
                cov,
            )
        )
    c.done()
    return out


def _line_gl(rest: bytes) -> list[DTrackHand]:
    c = _Cursor(rest, "gl", 1)
    out = []
    for _ in range(c.counts[0]):
        a = c.take(4)
        if a[2] not in (0.0, 1.0):
            raise PacketError("bad line", f"gl: left/right {a[2]} is neither 0 nor 1")
        nf = _small(a[3], _MAX_FINGERS, "gl fingers")
        p, r = c.take(3), c.take(9)
        fingers = []
        for _ in range(nf):
            fp, fr, d = c.take(3), c.take(9), c.take(6)
            fingers.append(
                DTrackFinger(
                    (fp[0], fp[1], fp[2]), _col_to_rows(fr), d[0], (d[1], d[3], d[5]), (d[2], d[4])
                )
            )
        out.append(
            DTrackHand(
                _as_id(a[0], "gl"),
                a[1],
                a[2] == 1.0,
                (p[0], p[1], p[2]),
                _col_to_rows(r),
                tuple(fingers),
            )
        )
    c.done()
    return out


def _line_st(rest: bytes) -> DTrackStatus:
    c = _Cursor(rest, "st", 1)
    general: list[float] = [-1.0] * 3
    messages: list[float] = [-1.0] * 5
    cams: list[tuple[int, int, int, int]] = []
    for _ in range(c.counts[0]):
        d = c.take_any()  # [id nval] or, for per-camera groups, [id ncam nval]
        if len(d) not in (2, 3):
            raise PacketError("bad line", "st: a group description has 2 or 3 numbers")
        gid = d[0]
        ncam = _small(d[1], 1000, "st cameras") if len(d) == 3 else 0
        nval = _small(d[-1], 1000, "st values")
        if len(d) == 2:
            v = c.take(nval)
            if gid == 0 and nval >= 3:
                general = v[:3]
            elif gid == 1 and nval >= 5:
                messages = v[:5]
            elif gid in (0, 1):
                raise PacketError("bad line", f"st: group {gid:g} has only {nval} values")
        else:
            for _ in range(ncam):
                v = c.take(1 + nval)
                if gid == 2:
                    if nval < 3:
                        raise PacketError("bad line", f"st: camera status has {nval} values")
                    cams.append(tuple(_small(x, 0xFFFFFFFF, "st") for x in v[:4]))
    c.done()
    ints = [-1 if x == -1.0 else _small(x, 0xFFFFFFFF, "st") for x in general + messages]
    return DTrackStatus(*ints, tuple(cams))


def _col_to_rows(b: list[float]) -> tuple[float, ...]:
    # wire: b0 b1 b2 = first column -> R[r][c] = b[3 c + r]
    return (b[0], b[3], b[6], b[1], b[4], b[7], b[2], b[5], b[8])


def _rows_to_col(r: tuple[float, ...]) -> tuple[float, ...]:
    return (r[0], r[3], r[6], r[1], r[4], r[7], r[2], r[5], r[8])


def decode_dtrack(data: bytes) -> DTrackFrame:
    """Decode one DTrack datagram (no I/O).

    Raises
    ------
    PacketError
        ``oversized``, ``not ASCII``, ``bad line`` (a known line that is malformed),
        ``empty`` (no frame line at all).
    """
    if len(data) > MAX_DATAGRAM:
        raise PacketError("oversized", f"{len(data)} bytes")
    raw = bytes(data)
    if not raw.isascii():
        raise PacketError("not ASCII", "DTrack output is ASCII text")
    fr = ts = ts2 = cal = None
    bodies: list[DTrackBody] = []
    covs: list[DTrackCovariance] = []
    markers: list[DTrackMarker] = []
    inertial: list[DTrackInertial] = []
    flysticks: list[DTrackFlystick] = []
    tools: list[DTrackTool] = []
    hands: list[DTrackHand] = []
    status = None
    skipped: list[str] = []
    known = 0
    for line in raw.replace(b"\r\n", b"\n").split(b"\n"):
        line = line.strip()
        if not line:
            continue
        key, _, rest = line.partition(b" ")
        if key == b"fr":
            fr = _int(rest.strip(), "fr")
        elif key == b"ts":
            ts = _floats(rest, 1, "ts")[0]
            if not 0.0 <= ts < 86401.0:
                raise PacketError("bad line", f"ts: {ts} is not a second of the day")
        elif key == b"ts2":
            parts = rest.split()
            if len(parts) != 3:
                raise PacketError("bad line", "ts2: expected sec usec latency")
            sec, usec, lat = (_int(p, "ts2") for p in parts)
            if sec < 0 or not 0 <= usec < 1_000_000 or lat < 0:
                raise PacketError("bad line", f"ts2: out of range {sec} {usec} {lat}")
            ts2 = (sec, usec, lat)
        elif key == b"6dcal":
            cal = _int(rest.strip(), "6dcal")
        elif key == b"6d":
            n, v = _blocks(rest, (2, 6, 9), "6d")
            for i in range(n):
                a, pe, r = v[3 * i], v[3 * i + 1], v[3 * i + 2]
                bodies.append(
                    DTrackBody(
                        _as_id(a[0], "6d"),
                        a[1],
                        (pe[0], pe[1], pe[2]),
                        _col_to_rows(r),
                        (pe[3], pe[4], pe[5]),
                    )
                )
        elif key == b"6dcov":
            n, v = _blocks(rest, (4, 21), "6dcov")
            for i in range(n):
                a, tri = v[2 * i], v[2 * i + 1]
                m = [0.0] * 36
                k = 0
                for r in range(6):
                    for c in range(r, 6):
                        m[6 * r + c] = m[6 * c + r] = tri[k]
                        k += 1
                covs.append(DTrackCovariance(_as_id(a[0], "6dcov"), (a[1], a[2], a[3]), tuple(m)))
        elif key == b"3d":
            n, v = _blocks(rest, (2, 3), "3d")
            for i in range(n):
                a, p = v[2 * i], v[2 * i + 1]
                markers.append(DTrackMarker(_as_id(a[0], "3d"), a[1], (p[0], p[1], p[2])))
        elif key == b"6di":
            n, v = _blocks(rest, (3, 3, 9), "6di")
            for i in range(n):
                a, p, r = v[3 * i], v[3 * i + 1], v[3 * i + 2]
                inertial.append(
                    DTrackInertial(
                        _as_id(a[0], "6di"), int(a[1]), a[2], (p[0], p[1], p[2]), _col_to_rows(r)
                    )
                )
        elif key == b"6df2":
            flysticks.extend(_line_6df2(rest))
        elif key == b"6dmt2":
            tools.extend(_line_6dmt2(rest))
        elif key == b"gl":
            hands.extend(_line_gl(rest))
        elif key == b"st":
            status = _line_st(rest)
        else:
            skipped.append(key.decode("ascii", "replace")[:16])
            continue
        known += 1
    if not known:
        raise PacketError("empty", "no DTrack line in the datagram")
    return DTrackFrame(
        fr,
        ts,
        ts2,
        cal,
        tuple(bodies),
        tuple(covs),
        tuple(markers),
        tuple(inertial),
        tuple(skipped),
        tuple(flysticks),
        tuple(tools),
        tuple(hands),
        status,
    )


def _num(v: float, digits: int | None) -> str:
    return repr(float(v)) if digits is None else f"{v:.{digits}f}"


def encode_dtrack(frame: DTrackFrame, digits: int | None = 3, rot_digits: int | None = 6) -> bytes:
    """Encode a frame as DTrack sends it (CRLF lines, column-wise matrices).

    ``digits`` / ``rot_digits``: decimals of positions [mm] and angles / matrix entries, as
    DTrack writes them (3 and 6); ``None`` writes every float exactly (``repr``), so that
    decoding gives back the very same doubles.
    """
    out: list[str] = []
    if frame.frame is not None:
        out.append(f"fr {int(frame.frame)}")
    if frame.ts is not None:
        out.append(f"ts {frame.ts:.6f}")
    if frame.ts2 is not None:
        out.append("ts2 {} {} {}".format(*(int(x) for x in frame.ts2)))
    if frame.calibrated is not None:
        out.append(f"6dcal {int(frame.calibrated)}")

    def nums(vals, d):
        return " ".join(_num(x, d) for x in vals)

    if frame.bodies:
        parts = [f"6d {len(frame.bodies)}"]
        for b in frame.bodies:
            parts.append(
                f"[{b.id} {_num(b.quality, 3)}][{nums(b.position_mm, digits)} "
                f"{nums(b.euler_deg, 4 if rot_digits is not None else None)}]"
                f"[{nums(_rows_to_col(b.rotation), rot_digits)}]"
            )
        out.append(" ".join(parts))
    if frame.covariances:
        parts = [f"6dcov {len(frame.covariances)}"]
        for c in frame.covariances:
            tri = [c.matrix[6 * r + k] for r in range(6) for k in range(r, 6)]
            cov_digits = None if digits is None else 9
            parts.append(f"[{c.id} {nums(c.reference_mm, digits)}][{nums(tri, cov_digits)}]")
        out.append(" ".join(parts))
    if frame.markers:
        parts = [f"3d {len(frame.markers)}"]
        for m in frame.markers:
            parts.append(f"[{m.id} {_num(m.quality, 3)}][{nums(m.position_mm, digits)}]")
        out.append(" ".join(parts))
    if frame.inertial:
        parts = [f"6di {len(frame.inertial)}"]
        for b in frame.inertial:
            parts.append(
                f"[{b.id} {b.state} {_num(b.error_deg, 3)}][{nums(b.position_mm, digits)}]"
                f"[{nums(_rows_to_col(b.rotation), rot_digits)}]"
            )
        out.append(" ".join(parts))
    out.extend(_encode_devices(frame, nums, digits, rot_digits))
    return ("\r\n".join(out) + "\r\n").encode("ascii")


def _pose_blocks(d, nums, digits, rot_digits) -> str:
    return f"[{nums(d.position_mm, digits)}][{nums(_rows_to_col(d.rotation), rot_digits)}]"


def _encode_devices(frame: DTrackFrame, nums, digits, rot_digits) -> list[str]:
    """The ``6df2``, ``6dmt2``, ``gl`` and ``st`` lines of :func:`encode_dtrack`."""
    out = []
    if frame.flysticks:
        parts = [f"6df2 {len(frame.flysticks)} {len(frame.flysticks)}"]
        for f in frame.flysticks:
            words = " ".join(str(w) for w in _button_words(f.buttons))
            tail = " ".join(x for x in (words, nums(f.joysticks, 2 if digits else None)) if x)
            parts.append(
                f"[{f.id} {_num(f.quality, 3)} {len(f.buttons)} {len(f.joysticks)}]"
                f"{_pose_blocks(f, nums, digits, rot_digits)}[{tail}]"
            )
        out.append(" ".join(parts))
    if frame.tools:
        parts = [f"6dmt2 {len(frame.tools)} {len(frame.tools)}"]
        for t in frame.tools:
            c = t.position_cov_mm2
            tri = (c[0], c[1], c[2], c[4], c[5], c[8])
            words = " ".join(str(w) for w in _button_words(t.buttons))
            parts.append(
                f"[{t.id} {_num(t.quality, 3)} {len(t.buttons)} {_num(t.tip_radius_mm, digits)}]"
                f"{_pose_blocks(t, nums, digits, rot_digits)}[{words}]"
                f"[{nums(tri, None if digits is None else 6)}]"
            )
        out.append(" ".join(parts))
    if frame.hands:
        parts = [f"gl {len(frame.hands)}"]
        for h in frame.hands:
            text = (
                f"[{h.id} {_num(h.quality, 3)} {int(h.right)} {len(h.fingers)}]"
                f"{_pose_blocks(h, nums, digits, rot_digits)}"
            )
            for g in h.fingers:
                ln, an = g.phalanx_mm, g.angles_deg
                vals = (g.tip_radius_mm, ln[0], an[0], ln[1], an[1], ln[2])
                text += f"{_pose_blocks(g, nums, digits, rot_digits)}[{nums(vals, digits)}]"
            parts.append(text)
        out.append(" ".join(parts))
    if frame.status is not None:
        s = frame.status
        groups = []
        if s.cameras != -1:
            groups.append(f"[0 3][{s.cameras} {s.tracked_bodies} {s.tracked_markers}]")
        if s.camera_errors != -1:
            groups.append(
                f"[1 5][{s.camera_errors} {s.camera_warnings} {s.other_errors} "
                f"{s.other_warnings} {s.infos}]"
            )
        if s.camera_status:
            cams = "".join("[{} {} {} {}]".format(*c) for c in s.camera_status)
            groups.append(f"[2 {len(s.camera_status)} 3]{cams}")
        out.append(" ".join([f"st {len(groups)}", *groups]))
    return out


class DayUnwrapper:
    """Turns ``ts`` (seconds of the day, restarting at 0 at midnight) into a continuous
    clock [s]: a jump back by more than half a day is a new day, a jump forward by more than
    half a day (a late packet from before midnight) is the previous one."""

    def __init__(self):
        self.day = 0
        self.last: float | None = None

    def peek(self, ts: float) -> float:
        """What :meth:`__call__` returns for ``ts``, without moving the day."""
        day = self.day
        if self.last is not None:
            if ts < self.last - 43200.0:
                day += 1
            elif ts > self.last + 43200.0:
                day -= 1
        return day * 86400.0 + ts

    def __call__(self, ts: float) -> float:
        if self.last is not None:
            if ts < self.last - 43200.0:
                self.day += 1
            elif ts > self.last + 43200.0:
                self.day -= 1
                t = self.day * 86400.0 + ts
                self.day += 1  # a late packet does not move the current day
                return t
        self.last = ts
        return self.day * 86400.0 + ts


def _skew(v: np.ndarray) -> np.ndarray:
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def dtrack_euler(rotation: np.ndarray) -> tuple[float, float, float]:
    """DTrack's Euler angles ``(eta, theta, phi)`` [rad] of ``R = Rx(eta) Ry(theta) Rz(phi)``
    (DTrack2 manual, appendix B.1; ``R[0, 2] = sin(theta)``)."""
    R = np.asarray(rotation, dtype=float)
    theta = float(np.arcsin(np.clip(R[0, 2], -1.0, 1.0)))
    phi = float(np.arctan2(-R[0, 1], R[0, 0]))
    eta = float(np.arctan2(-R[1, 2], R[2, 2]))
    return eta, theta, phi


def _rot(axis: int, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m = np.eye(3)
    m[i, i] = m[j, j] = c
    m[i, j], m[j, i] = -s, s
    return m


def dtrack_covariance(rotation: np.ndarray, cov: DTrackCovariance) -> np.ndarray:
    """The ``6dcov`` matrix in trackflow's convention (``docs/conventions.md``).

    DTrack's covariance is over ``(dp, da)``: ``dp`` the error of the location of the
    reference point ``p_ref = t + R c`` (``c`` given in body coordinates) in room coordinates
    [mm], and ``da`` the error of DTrack's Euler angles ``(eta, theta, phi)`` [rad] with
    ``R = Rx(eta) Ry(theta) Rz(phi)`` (DTrackSDK ``DTrackDataTypes.hpp``: "3d location in
    [mm], 3d euler angles in [rad]"). A change of the angles is the rotation error on the
    right ``dtheta = E da`` with ``E = [(Ry Rz)^T e_x, Rz^T e_y, e_z]``, and the body origin
    ``t = p_ref - R c`` moves by ``dt = dp + R [c]x dtheta``; so ``C = J C_dtrack J^T`` with
    ``J = [[I / 1000, R [c]x E / 1000], [0, E]]`` (the ``/ 1000`` turns mm into m). Singular at
    ``theta = +-90 deg``, like the Euler angles themselves.

    Parameters
    ----------
    rotation : ndarray (3, 3)
        ``R_room_body``.

    Returns
    -------
    ndarray (6, 6)
    """
    R = np.asarray(rotation, dtype=float)
    _, theta, phi = dtrack_euler(R)
    Rz, Ry = _rot(2, phi), _rot(1, theta)
    E = np.column_stack(
        [(Ry @ Rz).T @ np.array([1.0, 0, 0]), Rz.T @ np.array([0, 1.0, 0]), [0, 0, 1.0]]
    )
    c = np.asarray(cov.reference_mm, dtype=float)
    J = np.zeros((6, 6))
    J[:3, :3] = np.eye(3) * 1e-3
    J[:3, 3:] = R @ _skew(c) @ E * 1e-3
    J[3:, 3:] = E
    C = J @ np.asarray(cov.matrix, dtype=float).reshape(6, 6) @ J.T
    return 0.5 * (C + C.T)


def dtrack_pose(body: DTrackBody) -> tuple[np.ndarray, np.ndarray]:
    """Position [m] (3,) and quaternion ``(x, y, z, w)`` (4,) of a tracked body (or
    Flystick, tool or hand: anything with ``id``, ``quality``, ``position_mm`` and
    ``rotation``).

    Raises
    ------
    PacketError
        ``not tracked`` (quality < 0) or ``bad rotation`` (the matrix is not a rotation to
        1e-4, e.g. the zero dummy matrix).
    """
    if body.quality < 0:
        raise PacketError("not tracked", f"body {body.id}")
    R = np.asarray(body.rotation, dtype=float).reshape(3, 3)
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0.5:
        raise PacketError("bad rotation", f"body {body.id}: not a rotation matrix")
    q = quat_from_matrix(R)
    return np.asarray(body.position_mm, dtype=float) * 1e-3, q / np.linalg.norm(q)
