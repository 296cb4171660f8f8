"""Text trajectory formats: TUM, EuRoC ground-truth csv and generic CSV with a column mapping.

All three keep time exactly: timestamps are parsed from their decimal text into integer
nanoseconds and written back the same way, and floats are written with ``repr`` (shortest text
that reads back to the same double), so write -> read reproduces a stream bit for bit.
Frame names are kept in a ``# trackflow: source=.. target=..`` comment line.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import FormatError, InputError
from ._clean import finish_stream
from ._output import atomic_output
from ._report import ReadReport
from ._stream import PoseStream
from ._table import (
    FRAMES_PREFIX,
    TIME_EXPONENTS,
    format_ns,
    parse_rows,
)
from ._textfile import first_data_line

__all__ = [
    "read_csv",
    "read_euroc",
    "read_tum",
    "write_csv",
    "write_euroc",
    "write_tum",
    "DEFAULT_SOURCE",
    "DEFAULT_TARGET",
]

DEFAULT_SOURCE = "world"
DEFAULT_TARGET = "body"


def _frames(meta: dict, source, target) -> tuple[str, str]:
    return (
        source or meta.get("source") or DEFAULT_SOURCE,
        target or meta.get("target") or DEFAULT_TARGET,
    )


def _frames_comment(stream: PoseStream) -> str:
    for name in (stream.source, stream.target):
        if any(c.isspace() for c in name) or "=" in name:
            raise InputError(f"frame name {name!r} cannot be stored in a text file comment")
    return f"{FRAMES_PREFIX} source={stream.source} target={stream.target}\n"


def _rows_text(columns: list[np.ndarray], sep: str) -> str:
    """Join columns (str arrays or float arrays written with repr) into lines."""
    as_text = []
    for c in columns:
        if c.dtype.kind in "USO":
            as_text.append(c.tolist())
        else:
            as_text.append([repr(v) for v in c.tolist()])
    return "".join(sep.join(row) + "\n" for row in zip(*as_text))


def _write_text(path, text: str, overwrite: bool) -> None:
    """Write ``text`` as UTF-8 under the output policy (atomic, no silent overwrite)."""
    with atomic_output(path, overwrite=overwrite) as tmp:
        tmp.write_text(text, encoding="utf-8")


def _times_text(t_ns: np.ndarray, exponent: int) -> np.ndarray:
    return np.array([format_ns(t, exponent) for t in t_ns.tolist()], dtype=object)


# -- TUM ------------------------------------------------------------------------------------
def read_tum(
    path, *, clean: bool = False, source: str | None = None, target: str | None = None
) -> tuple[PoseStream, ReadReport]:
    """Read a TUM trajectory: lines ``t tx ty tz qx qy qz qw`` (seconds, metres, xyzw).

    Extra columns (such as a 9th receive-time column) are ignored and noted in the report.
    Each line is ``T_source_target``; frames default to a ``# trackflow:`` comment, else
    ``"world"`` and ``"body"``.
    """
    path = Path(path)
    report = ReadReport(str(path), "tum")
    table, _ = parse_rows(
        path,
        report,
        delimiter=None,
        ncols=8,
        time_col=0,
        time_exponent=9,
        value_cols=range(1, 8),
        clean=clean,
        quat_cols=range(4, 8),
        split_at=(3,),
    )
    src, tgt = _frames(table.meta, source, target)
    position, quaternion = table.columns
    stream = finish_stream(
        report,
        where=table.where,
        t_ns=table.t_ns,
        position=position,
        quaternion=quaternion,
        owned=True,
        source=src,
        target=tgt,
        clean=clean,
        quat_tolerance=table.quat_tolerance,
        tail_unterminated=table.tail_unterminated,
    )
    return stream, report


def write_tum(path, stream: PoseStream, *, overwrite: bool = False) -> None:
    """Write ``t tx ty tz qx qy qz qw`` lines (exact decimal seconds, shortest exact floats).

    Only poses and times are stored (TUM has no covariance, confidence or flags). The file is
    written atomically and an existing one is replaced only with ``overwrite`` (see
    :func:`trackflow.io.atomic_output`).
    """
    head = _frames_comment(stream) + "# timestamp tx ty tz qx qy qz qw\n"
    cols = [_times_text(stream.t_ns, 9)]
    cols += [stream.position[:, i] for i in range(3)]
    cols += [stream.quaternion[:, i] for i in range(4)]
    _write_text(path, head + _rows_text(cols, " "), overwrite)


# -- EuRoC ----------------------------------------------------------------------------------
_EUROC_HEADER = (
    "#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], "
    "q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []\n"
)


def read_euroc(
    path, *, clean: bool = False, source: str | None = None, target: str | None = None
) -> tuple[PoseStream, ReadReport]:
    """Read EuRoC ground truth csv: ``#timestamp [ns], p_RS_R_{x,y,z}, q_RS_{w,x,y,z}, ...``.

    The pose is ``T_R_S`` (body S in reference R); EuRoC's quaternion comes scalar first and
    is reordered to ``(x, y, z, w)``. Velocity and bias columns are ignored. Frames default to
    ``"world"``/``"body"`` unless a ``# trackflow:`` comment or the arguments name them.
    """
    path = Path(path)
    report = ReadReport(str(path), "euroc")
    table, _ = parse_rows(
        path,
        report,
        delimiter=",",
        ncols=8,
        time_col=0,
        time_exponent=0,
        value_cols=(1, 2, 3, 5, 6, 7, 4),  # quaternion reordered to (x, y, z, w)
        clean=clean,
        quat_cols=range(4, 8),
        split_at=(3,),
    )
    src, tgt = _frames(table.meta, source, target)
    position, quaternion = table.columns
    stream = finish_stream(
        report,
        where=table.where,
        t_ns=table.t_ns,
        position=position,
        quaternion=quaternion,
        owned=True,
        source=src,
        target=tgt,
        clean=clean,
        quat_tolerance=table.quat_tolerance,
        tail_unterminated=table.tail_unterminated,
    )
    return stream, report


def write_euroc(path, stream: PoseStream, *, overwrite: bool = False) -> None:
    """Write the 8 pose columns of EuRoC ground truth (ns, metres, quaternion w first)."""
    q = stream.quaternion
    cols = [_times_text(stream.t_ns, 0)]
    cols += [stream.position[:, i] for i in range(3)]
    cols += [q[:, 3], q[:, 0], q[:, 1], q[:, 2]]
    _write_text(path, _frames_comment(stream) + _EUROC_HEADER + _rows_text(cols, ","), overwrite)


# -- generic CSV ----------------------------------------------------------------------------
_POSE_FIELDS = ("t", "x", "y", "z", "qx", "qy", "qz", "qw")
_SYNONYMS = {
    "t": ("t", "time", "timestamp", "stamp", "times", "t_s", "time_s"),
    "x": ("x", "tx", "px", "pos_x", "position_x", "p_x"),
    "y": ("y", "ty", "py", "pos_y", "position_y", "p_y"),
    "z": ("z", "tz", "pz", "pos_z", "position_z", "p_z"),
    "qx": ("qx", "q_x", "quat_x", "orientation_x", "rx"),
    "qy": ("qy", "q_y", "quat_y", "orientation_y", "ry"),
    "qz": ("qz", "q_z", "quat_z", "orientation_z", "rz"),
    "qw": ("qw", "q_w", "quat_w", "orientation_w", "rw"),
    "confidence": ("confidence", "conf"),
    "flags": ("flags",),
}
_COV_IJ = [(i, j) for i in range(6) for j in range(i, 6)]
_COV_NAMES = [f"cov_{i}_{j}" for i, j in _COV_IJ]


def _normalise_name(name: str) -> str:
    n = name.strip().lstrip("#").strip().lower()
    return n.split("[")[0].split("(")[0].strip().replace(" ", "_")


def _auto_mapping(header: list[str]) -> dict[str, int]:
    names = [_normalise_name(h) for h in header]
    out: dict[str, int] = {}
    for fld, syn in _SYNONYMS.items():
        for k, n in enumerate(names):
            if n in syn or n.split("_")[0] in syn[:1]:
                out.setdefault(fld, k)
    for k, n in enumerate(names):
        if n in _COV_NAMES:
            out[n] = k
    return out


def _is_header(toks: list[str]) -> bool:
    try:
        float(toks[0])
    except ValueError:
        return True
    return False


def read_csv(
    path,
    *,
    clean: bool = False,
    columns: dict[str, str | int] | None = None,
    delimiter: str = ",",
    time_unit: str = "s",
    source: str | None = None,
    target: str | None = None,
) -> tuple[PoseStream, ReadReport]:
    """Read a delimited file with a header (or explicit column indices).

    Parameters
    ----------
    columns : dict, optional
        Field -> column name (needs a header) or 0-based index. Fields: ``t, x, y, z, qx, qy,
        qz, qw`` (required), ``confidence``, ``flags`` and ``cov_i_j`` (0 <= i <= j < 6, the
        upper triangle of the 6x6 covariance in trackflow's convention; all 21 or none). By
        default names are matched from the header: ``t``/``time``/``timestamp``, ``x``/``tx``/
        ``pos_x``, ``qx``/``quat_x``, ..., also with a suffix (``x_opti``).
    delimiter : str
    time_unit : {"s", "ms", "us", "ns"}
    source, target : str, optional
        Frame names (default: ``# trackflow:`` comment, else ``"world"``/``"body"``).
    """
    path = Path(path)
    if time_unit not in TIME_EXPONENTS:
        raise InputError(f"time_unit must be one of {sorted(TIME_EXPONENTS)}, got {time_unit!r}")
    report = ReadReport(str(path), "csv")
    # first look: find the header, then map columns
    header = None
    first = first_data_line(path)
    if first is not None:
        toks = [x.strip() for x in first.split(delimiter)]
        header = toks if _is_header(toks) else None
    if columns is None:
        if header is None:
            mapping = {f: k for k, f in enumerate(_POSE_FIELDS)}
            report.notes.append("no header: assumed columns t, x, y, z, qx, qy, qz, qw")
        else:
            mapping = _auto_mapping(header)
    else:
        mapping = {}
        for fld, col in columns.items():
            if isinstance(col, (int, np.integer)):
                mapping[fld] = int(col)
            elif header is None:
                raise FormatError(f"{path}: column {col!r} named but the file has no header")
            elif col not in header:
                raise FormatError(f"{path}: no column named {col!r} (header: {header})")
            else:
                mapping[fld] = header.index(col)
    known = set(_POSE_FIELDS) | {"confidence", "flags"} | set(_COV_NAMES)
    unknown = set(mapping) - known
    if unknown:
        raise InputError(f"unknown column mapping field(s): {sorted(unknown)}")
    missing = [f for f in _POSE_FIELDS if f not in mapping]
    if missing:
        raise FormatError(f"{path}: cannot find column(s) for {missing} (header: {header})")
    n_cov = sum(c in mapping for c in _COV_NAMES)
    if n_cov not in (0, 21):
        raise FormatError(f"{path}: covariance needs all 21 cov_i_j columns, found {n_cov}")
    fields = list(_POSE_FIELDS[1:])
    fields += [f for f in ("confidence", "flags") if f in mapping]
    fields += _COV_NAMES if n_cov else []
    cols = [mapping[f] for f in fields]
    qcols = [mapping[c] for c in ("qx", "qy", "qz", "qw")]
    table, _ = parse_rows(
        path,
        report,
        delimiter=delimiter,
        ncols=max(cols + [mapping["t"]]) + 1,
        time_col=mapping["t"],
        time_exponent=TIME_EXPONENTS[time_unit],
        value_cols=cols,
        clean=clean,
        header=_is_header,
        quat_cols=qcols,
        split_at=(3, 7) if len(cols) > 7 else (3,),
    )
    position, quaternion, *rest = table.columns
    v = rest[0] if rest else np.zeros((len(position), 0))  # columns after the pose
    pos = {f: k - 7 for k, f in enumerate(fields)}
    cov = None
    if n_cov:
        cov = np.zeros((len(v), 6, 6))
        for (i, j), name in zip(_COV_IJ, _COV_NAMES):
            cov[:, i, j] = cov[:, j, i] = v[:, pos[name]]
    flags = None
    if "flags" in pos:
        f = v[:, pos["flags"]]
        if np.any((f != np.round(f)) | (f < 0) | (f > 0xFFFFFFFF)):
            k = int(np.argmax((f != np.round(f)) | (f < 0) | (f > 0xFFFFFFFF)))
            raise FormatError(f"{path}:{table.where[k]}: flags {f[k]} is not a uint32")
        flags = f.astype(np.uint32)
    src, tgt = _frames(table.meta, source, target)
    stream = finish_stream(
        report,
        where=table.where,
        t_ns=table.t_ns,
        position=position,
        quaternion=quaternion,
        owned=True,
        covariance=cov,
        confidence=v[:, pos["confidence"]] if "confidence" in pos else None,
        flags=flags,
        source=src,
        target=tgt,
        clean=clean,
        quat_tolerance=table.quat_tolerance,
        tail_unterminated=table.tail_unterminated,
    )
    return stream, report


def write_csv(
    path,
    stream: PoseStream,
    *,
    delimiter: str = ",",
    time_unit: str = "s",
    overwrite: bool = False,
) -> None:
    """Write every field with a header ``t,x,y,z,qx,qy,qz,qw,confidence,flags[,cov_i_j...]``.

    Covariance columns (upper triangle, trackflow convention) are written when the stream has
    one; :func:`read_csv` with default mapping reads the file back exactly.
    """
    if time_unit not in TIME_EXPONENTS:
        raise InputError(f"time_unit must be one of {sorted(TIME_EXPONENTS)}, got {time_unit!r}")
    names = list(_POSE_FIELDS) + ["confidence", "flags"]
    cols = [_times_text(stream.t_ns, TIME_EXPONENTS[time_unit])]
    cols += [stream.position[:, i] for i in range(3)]
    cols += [stream.quaternion[:, i] for i in range(4)]
    cols += [stream.confidence, stream.flags.astype(str)]
    if stream.covariance is not None:
        names += _COV_NAMES
        cols += [stream.covariance[:, i, j] for i, j in _COV_IJ]
    head = _frames_comment(stream) + delimiter.join(names) + "\n"
    _write_text(path, head + _rows_text(cols, delimiter), overwrite)
