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

Any other identifier (``6df2``, ``gl``, ``st`` ...) is skipped and listed in
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
    "DTrackInertial",
    "DTrackMarker",
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
    return ("\r\n".join(out) + "\r\n").encode("ascii")


class DayUnwrapper:
    """Turns ``ts`` (seconds of the day, restarting at 0 at midnight) into a continuous
    clock [s]: a jump back by more than half a day is a new day, a jump forward by more than
    half a day (a late packet from before midnight) is the previous one."""

    def __init__(self):
        self.day = 0
        self.last: float | None = None

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
    """Position [m] (3,) and quaternion ``(x, y, z, w)`` (4,) of a tracked body.

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
