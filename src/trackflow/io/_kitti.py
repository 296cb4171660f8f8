"""KITTI odometry poses: one line per frame, the 3x4 matrix ``[R | t]`` row-major (12 numbers).

Each line is ``T_source_target`` (KITTI: camera 0 at frame ``i`` in the frame of camera 0 at
frame 0), metres. The format holds no timestamps: frame ``i`` is at ``i / rate_hz`` seconds
(KITTI's cameras run at 10 Hz), or at the times of a ``times.txt`` (one time in seconds per
line, as in the KITTI odometry sequences) given as ``times=``. Writing drops the timestamps
(the frames must be evenly spaced at ``rate_hz`` for a reader to recover them) and the
covariance.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import FormatError, InputError
from ..math import quat_from_matrix, quat_to_matrix
from ._clean import finish_stream
from ._output import atomic_output
from ._report import ReadReport
from ._stream import PoseStream
from ._table import TIME_EXPONENTS, parse_rows, parse_time_ns
from ._textfile import read_lines

__all__ = ["KITTI_RATE_HZ", "read_kitti", "write_kitti"]

#: Frame rate of the KITTI odometry cameras [Hz].
KITTI_RATE_HZ = 10.0
#: Largest accepted ``|R^T R - I|`` (max abs entry) of a rotation printed as decimal text.
ORTHONORMAL_TOLERANCE = 1e-4


def _times_ns(path: Path, times, n_lines: int, rate_hz: float) -> np.ndarray:
    """Timestamps [ns] of the ``n_lines`` pose lines (from ``times`` or the frame rate)."""
    if times is None:
        if not (np.isfinite(rate_hz) and rate_hz > 0):
            raise InputError(f"rate_hz must be > 0, got {rate_hz!r}")
        return np.rint(np.arange(n_lines) * (1e9 / rate_hz)).astype(np.int64)
    lines = [s.strip() for s in read_lines(Path(times))[0]]
    where = [i + 1 for i, s in enumerate(lines) if s and not s.startswith("#")]
    if len(where) != n_lines:
        raise FormatError(f"{times}: {len(where)} times for the {n_lines} poses of {path}")
    out = np.empty(n_lines, dtype=np.int64)
    for k, i in enumerate(where):
        try:
            out[k] = parse_time_ns(lines[i - 1].split()[0], TIME_EXPONENTS["s"])
        except ValueError as exc:
            raise FormatError(f"{times}:{i}: {exc}") from None
    return out


def read_kitti(
    path,
    *,
    clean: bool = False,
    rate_hz: float = KITTI_RATE_HZ,
    times=None,
    source: str | None = None,
    target: str | None = None,
) -> tuple[PoseStream, ReadReport]:
    """Read KITTI poses (12 numbers per line: ``r11 r12 r13 tx r21 r22 r23 ty r31 r32 r33 tz``).

    Rotations must be orthonormal to ``1e-4`` (``ValueError`` naming the line, or dropped with
    ``clean``). Frames default to ``"world"``/``"camera"``.
    """
    path = Path(path)
    report = ReadReport(str(path), "kitti")
    table, _ = parse_rows(
        path, report, delimiter=None, ncols=12, time_col=0, time_exponent=0,
        value_cols=range(12), clean=clean,
    )  # fmt: skip
    # frame index of each kept row among all data lines (parse drops keep their frame slot)
    lines = np.sort(np.concatenate([table.where, *map(np.asarray, report.dropped.values())]))
    frame = np.searchsorted(lines, table.where)
    m = table.values.reshape(-1, 3, 4)
    rot = m[:, :, :3]
    err = np.abs(np.einsum("nji,njk->nik", rot, rot) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(rot) if len(rot) else np.zeros(0)
    bad = ~(err <= ORTHONORMAL_TOLERANCE) | ~(det > 0)
    keep = ~bad
    if np.any(bad):
        k = int(np.argmax(bad))
        if not clean:
            raise FormatError(
                f"{path}:{table.where[k]}: rotation is not orthonormal (|R^T R - I| = "
                f"{err[k]:.3g}, det {det[k]:.6g})"
            )
        report.drop("rotation not orthonormal", table.where[bad])
    t_all = _times_ns(path, times, report.rows_read, rate_hz)
    report.notes.append(
        f"KITTI has no timestamps: {'times from ' + str(times) if times else f'{rate_hz:g} Hz'}"
    )
    stream = finish_stream(
        report,
        where=table.where[keep],
        t_ns=t_all[frame][keep],
        position=m[keep, :, 3],
        quaternion=quat_from_matrix(rot[keep]),
        source=source or table.meta.get("source") or "world",
        target=target or table.meta.get("target") or "camera",
        clean=clean,
        tail_unterminated=table.tail_unterminated,
    )
    return stream, report


def write_kitti(path, stream: PoseStream, *, overwrite: bool = False) -> None:
    """Write one ``[R | t]`` row-major line per sample (timestamps and covariances dropped)."""
    r = quat_to_matrix(stream.quaternion)
    m = np.concatenate([r, stream.position[:, :, None]], axis=2).reshape(-1, 12)
    text = "".join(" ".join(repr(v) for v in row) + "\n" for row in m.tolist())
    with atomic_output(path, overwrite=overwrite) as tmp:
        tmp.write_text(text, encoding="utf-8")
