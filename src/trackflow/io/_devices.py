"""Device logs from ``../shared/data``: Meta Quest pose logs and BROAD ``.mat`` trials.

Quest (Unity) logs
------------------
CSV without header, 16 columns: local .NET ticks, UTC .NET ticks, year, month, day, hour,
minute, second, millisecond, x, y, z, qx, qy, qz, qw. Time is taken from the UTC ticks:
``t_ns = (ticks - 621355968000000000) * 100`` (Unix epoch, exact).

Unity's world and object frames are left-handed with x right, y up, z forward. trackflow is
right-handed, so both frames are mirrored in z (``S = diag(1, 1, -1)``)::

    t' = S t = (x, y, -z)          R' = S R S   <=>   q' = (-qx, -qy, qz, qw)

which gives right-handed frames with x right, y up, z backward (the OpenGL camera convention).
The pose is Unity's ``transform`` of the headset, i.e. ``T_world_headset``; the frames default
to ``"quest_world"`` and ``"quest_headset"``. The writer applies the inverse mirror.

BROAD trials
------------
MATLAB v5 files with ``opt_quat`` (N, 4) scalar first and ``opt_pos`` (N, 3) in metres from
OptiTrack, sampled at 285.714 Hz without timestamps: ``t_ns = round(i * 1e9 / 285.714)``.
Mocap dropouts are stored as NaN rows; they are the format's way of saying "no sample", so they
are dropped and counted in the report (``"mocap dropout (NaN row)"``) rather than being an
error. The pose is ``T_optitrack_imu`` (the IMU box in the OptiTrack frame).
"""

from __future__ import annotations

import datetime as _dt
from pathlib import Path

import numpy as np

from ..errors import FormatError, InputError
from ._clean import finish_stream
from ._output import atomic_output
from ._report import ReadReport
from ._stream import PoseStream
from ._table import parse_rows

__all__ = [
    "BROAD_RATE_HZ",
    "DOTNET_UNIX_EPOCH_TICKS",
    "read_broad",
    "read_quest",
    "write_broad",
    "write_quest",
]

#: .NET ticks (100 ns) at 1970-01-01T00:00:00Z.
DOTNET_UNIX_EPOCH_TICKS = 621355968000000000
#: BROAD's sampling rate.
BROAD_RATE_HZ = 285.714

_MIRROR_P = np.array([1.0, 1.0, -1.0])
_MIRROR_Q = np.array([-1.0, -1.0, 1.0, 1.0])


def read_quest(
    path, *, clean: bool = False, source: str | None = None, target: str | None = None
) -> tuple[PoseStream, ReadReport]:
    """Read a Quest/Unity pose log (see module docstring for columns and the frame mirror)."""
    path = Path(path)
    report = ReadReport(str(path), "quest")
    table, _ = parse_rows(
        path,
        report,
        delimiter=",",
        ncols=16,
        time_col=1,
        time_exponent=2,  # 1 tick = 100 ns = 10**2 ns
        value_cols=range(9, 16),
        clean=clean,
        time_offset_ns=DOTNET_UNIX_EPOCH_TICKS * 100,
        quat_cols=range(12, 16),
        split_at=(3,),
    )
    report.notes.append(
        "Unity left-handed y-up frames mirrored in z: t=(x,y,-z), q=(-qx,-qy,qz,qw)"
    )
    position, quaternion = table.columns
    position *= _MIRROR_P  # sign changes: exact, in place
    quaternion *= _MIRROR_Q
    stream = finish_stream(
        report,
        where=table.where,
        t_ns=table.t_ns,
        position=position,
        quaternion=quaternion,
        owned=True,
        source=source or table.meta.get("source") or "quest_world",
        target=target or table.meta.get("target") or "quest_headset",
        clean=clean,
        quat_tolerance=table.quat_tolerance,
        tail_unterminated=table.tail_unterminated,
    )
    return stream, report


def write_quest(path, stream: PoseStream, *, overwrite: bool = False) -> None:
    """Write a Quest/Unity log (frames mirrored back to Unity's left-handed convention).

    Timestamps must be multiples of 100 ns. The local-time ticks column repeats the UTC ticks
    and the calendar columns are UTC (the original time zone is not known).
    """
    t = stream.t_ns
    if np.any(t % 100):
        i = int(np.argmax(t % 100 != 0))
        raise InputError(f"Quest logs store 100 ns ticks; sample {i} has t_ns={int(t[i])}")
    ticks = t // 100 + DOTNET_UNIX_EPOCH_TICKS
    p = stream.position * _MIRROR_P
    q = stream.quaternion * _MIRROR_Q
    epoch = _dt.datetime(1970, 1, 1, tzinfo=_dt.UTC)
    out = []
    for k, tick in enumerate(ticks.tolist()):
        d = epoch + _dt.timedelta(microseconds=(tick - DOTNET_UNIX_EPOCH_TICKS) // 10)
        cal = f"{d.year},{d.month},{d.day},{d.hour},{d.minute},{d.second},{d.microsecond // 1000}"
        vals = ",".join(repr(x) for x in p[k].tolist() + q[k].tolist())
        out.append(f"{tick},{tick},{cal},{vals}\n")
    with atomic_output(path, overwrite=overwrite) as tmp:
        tmp.write_text("".join(out), encoding="utf-8")


def _broad_times(n: int, rate_hz: float) -> np.ndarray:
    return np.rint(np.arange(n) * (1e9 / rate_hz)).astype(np.int64)


def read_broad(
    path,
    *,
    clean: bool = False,
    rate_hz: float = BROAD_RATE_HZ,
    source: str = "optitrack",
    target: str = "imu",
) -> tuple[PoseStream, ReadReport]:
    """Read the OptiTrack pose of a BROAD trial (see module docstring); rows are 0-based."""
    from scipy.io import loadmat

    path = Path(path)
    try:
        mat = loadmat(path)
    except (ValueError, OSError, TypeError, IndexError) as exc:  # scipy 1.13 raises IndexError
        raise FormatError(f"{path}: not a readable MATLAB file ({exc})") from exc
    for key in ("opt_quat", "opt_pos"):
        if key not in mat:
            raise FormatError(f"{path}: no variable {key!r} (not a BROAD trial?)")
    q_wxyz = np.asarray(mat["opt_quat"], dtype=float)
    pos = np.asarray(mat["opt_pos"], dtype=float)
    if q_wxyz.ndim != 2 or q_wxyz.shape[1] != 4 or pos.shape != (len(q_wxyz), 3):
        raise FormatError(
            f"{path}: opt_quat {q_wxyz.shape} and opt_pos {pos.shape} must be (N, 4) and (N, 3)"
        )
    n = len(pos)
    report = ReadReport(str(path), "broad", unit="row", rows_read=n)
    nan_row = np.isnan(pos).all(axis=1) | np.isnan(q_wxyz).all(axis=1)
    report.drop("mocap dropout (NaN row)", np.flatnonzero(nan_row))
    keep = ~nan_row
    report.notes.append(f"t = row / {rate_hz} Hz; opt_quat reordered from (w, x, y, z)")
    stream = finish_stream(
        report,
        where=np.flatnonzero(keep),
        t_ns=_broad_times(n, rate_hz)[keep],
        position=pos[keep],
        quaternion=q_wxyz[keep][:, [1, 2, 3, 0]],
        source=source,
        target=target,
        clean=clean,
    )
    return stream, report


def write_broad(
    path, stream: PoseStream, *, rate_hz: float = BROAD_RATE_HZ, overwrite: bool = False
) -> None:
    """Write ``opt_pos``/``opt_quat`` on BROAD's sample grid, NaN rows where samples are missing.

    Every timestamp must lie on the grid ``round(i * 1e9 / rate_hz)`` with ``i >= 0``.
    """
    from scipy.io import savemat

    t = stream.t_ns
    idx = np.rint(t * (rate_hz / 1e9)).astype(np.int64)
    n = int(idx[-1]) + 1 if len(idx) else 0
    if n > 4 * len(t) + 1000:  # Unix-time stamps would need years of NaN rows
        raise InputError(
            f"a BROAD trial starts at t = 0 and holds one row per {1e3 / rate_hz:g} ms: these "
            f"{len(t)} samples would need {n} rows (first sample at {t[0] * 1e-9:.9g} s); "
            "shift the recording to start near 0 first (trackflow shift --offset)"
        )
    grid = _broad_times(n, rate_hz)
    off = (idx < 0) | (grid[np.clip(idx, 0, max(n - 1, 0))] != t) if n else idx < 0
    if np.any(off):
        i = int(np.argmax(off))
        raise InputError(
            f"sample {i} (t_ns={int(t[i])}) is not on the {rate_hz} Hz grid of a BROAD trial"
        )
    pos = np.full((n, 3), np.nan)
    quat = np.full((n, 4), np.nan)
    pos[idx] = stream.position
    quat[idx] = stream.quaternion[:, [3, 0, 1, 2]]
    with atomic_output(path, overwrite=overwrite) as tmp:
        with open(tmp, "wb") as f:
            savemat(f, {"opt_pos": pos, "opt_quat": quat})
