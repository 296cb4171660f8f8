"""The line-list text parser trackflow used before the block reader (frozen reference).

A verbatim copy of ``parse_rows`` and its helpers as of main d3dab05 (before issue 12's
``info`` memory fix), kept only so that tests can check that the block reader gives the same
arrays, reports and errors. It holds every line of the file in memory; do not use it elsewhere.
Its results are wrapped in the current ``Table`` (columns split as asked, and the quaternion
tolerance computed from the row tokens as it was then).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from trackflow.errors import FormatError
from trackflow.io._clean import TRUNCATED
from trackflow.io._report import ReadReport
from trackflow.io._table import (
    FRAMES_PREFIX,
    TEXT_UNIT_TOLERANCE,
    Table,
    parse_frames_comment,
    parse_time_ns,
)
from trackflow.io._textfile import read_lines  # unchanged since (KITTI times use it)


def _table(where, t_ns, values, tokens, tail, meta, quat_cols, split_at) -> Table:
    bounds = list(zip([0, *split_at], [*split_at, values.shape[1]]))
    table = Table(
        where=where,
        t_ns=t_ns,
        columns=tuple(values[:, a:b].copy() for a, b in bounds),
        tail_unterminated=tail,
        meta=meta,
    )
    table.quat_tolerance = quat_tolerance_from_tokens(tokens, list(quat_cols))
    return table


def parse_rows(
    path: Path,
    report: ReadReport,
    *,
    delimiter: str | None,
    ncols: int,
    time_col: int,
    time_exponent: int,
    value_cols: Sequence[int],
    clean: bool,
    header: Callable[[list[str]], bool] | None = None,
    time_offset_ns: int = 0,
    quat_cols: Sequence[int] = (),
    split_at: Sequence[int] = (),
    block_bytes: int | None = None,
) -> tuple[Table, list[str] | None]:
    """Parse a delimited text file into timestamps and float columns.

    Blank lines and lines starting with ``#`` are skipped (a ``# trackflow:`` comment supplies
    frame names). If ``header`` is given, it is called with the tokens of the first
    non-comment line and returns whether that line is a header. Rows with fewer than ``ncols``
    columns or unparsable numbers raise ``ValueError`` with ``file:line`` (or are dropped with
    ``clean``), except an unterminated last line, which is dropped as a truncated tail.
    ``report.rows_read`` is set. ``time_offset_ns`` is subtracted from every timestamp (exact
    integers, before conversion to int64).
    """
    lines, unterminated, tail_bytes = read_lines(path)
    meta: dict[str, str] = {}
    head: list[str] | None = None
    last_index = len(lines) - 1

    def split(line: str) -> list[str]:
        if delimiter is None:
            return line.split()
        return [x.strip() for x in line.split(delimiter)]

    data_idx: list[int] = []  # 0-based line index of each data row
    data: list[str] = []
    first = True
    for i, raw in enumerate(lines):
        line = raw.strip()
        if not line:
            continue
        if line[0] == "#":
            if line.startswith(FRAMES_PREFIX):
                meta.update(parse_frames_comment(line))
            continue
        if first:
            first = False
            if header is not None and header(split(line)):
                head = split(line)
                continue
        data_idx.append(i)
        data.append(line)
    report.rows_read = len(data)
    tail_in_data = bool(unterminated and data_idx and data_idx[-1] == last_index)
    args = (delimiter, ncols, time_col, time_exponent, list(value_cols), time_offset_ns)
    fast = None if tail_in_data else _parse_fast(data, *args)
    if fast is not None:
        t_ns, values = fast
        extra = len(split(data[0])) - ncols if data else 0
        if extra > 0:
            report.notes.append(f"ignored extra column(s) beyond the first {ncols}")
        table = _table(
            np.array(data_idx, dtype=np.int64) + 1, t_ns, values, _RowTokens(data, split),
            False, meta, quat_cols, split_at,
        )  # fmt: skip
        return table, head

    # slow path, row by row: exact diagnostics for malformed rows
    where: list[int] = []
    times: list[int] = []
    vals: list[list[float]] = []
    kept: list[str] = []
    extra = 0
    for i, line in zip(data_idx, data):
        toks = split(line)
        lineno = i + 1
        problem = None
        reason = None
        if len(toks) < ncols:
            problem = f"short row: {len(toks)} columns, expected {ncols}"
            reason = "short row"
        else:
            try:
                t = parse_time_ns(toks[time_col], time_exponent) - time_offset_ns
                if not -(2**63) <= t < 2**63:
                    raise ValueError(f"timestamp {toks[time_col]!r} out of the int64 ns range")
                v = [float(toks[j]) for j in value_cols]
            except ValueError as exc:
                problem = f"unparsable value ({exc})"
                reason = "unparsable value"
        if problem is not None:
            if unterminated and i == last_index:
                report.drop(TRUNCATED, lineno)
                report.truncated_bytes = tail_bytes
                report.notes.append(f"last line ({path}:{lineno}) is incomplete: {problem}")
                continue
            if not clean:
                raise FormatError(f"{path}:{lineno}: {problem}")
            report.drop(reason, lineno)
            continue
        extra = max(extra, len(toks) - ncols)
        where.append(lineno)
        times.append(t)
        vals.append(v)
        kept.append(line)
    if extra:
        report.notes.append(f"ignored extra column(s) beyond the first {ncols}")
    tail = bool(unterminated and where and where[-1] == last_index + 1)
    table = _table(
        np.array(where, dtype=np.int64), np.array(times, dtype=np.int64),
        np.array(vals, dtype=float).reshape(len(vals), len(value_cols)),
        _RowTokens(kept, split), tail, meta, quat_cols, split_at,
    )  # fmt: skip
    return table, head


class _RowTokens:
    """Tokens of row ``r`` on demand (only rows that need a closer look are split again)."""

    def __init__(self, lines: list[str], split: Callable[[str], list[str]]):
        self._lines = lines
        self._split = split

    def __len__(self) -> int:
        return len(self._lines)

    def __getitem__(self, r: int) -> list[str]:
        return self._split(self._lines[r])


def _time_fast(token: str, exponent: int) -> int:
    """``parse_time_ns`` for plain decimals without rounding (the common case), else exact."""
    body = token[1:] if token[:1] in "+-" else token
    whole, _, frac = body.partition(".")
    if whole.isdigit() and (not frac or frac.isdigit()) and len(frac) <= exponent:
        v = int(whole) * 10**exponent + (int(frac) * 10 ** (exponent - len(frac)) if frac else 0)
        return -v if token[0] == "-" else v
    return parse_time_ns(token, exponent)


def _times_vectorised(toks: np.ndarray, exponent: int, offset_ns: int) -> np.ndarray | None:
    """Exact ns from plain decimal strings (``-?digits[.digits]``, at most ``exponent``
    decimals) with numpy string functions; ``None`` when any token needs the general parser."""
    scale = 10**exponent
    if offset_ns % scale:
        return None
    try:  # one byte per character: a quarter of the memory of unicode arrays
        toks = np.strings.strip(np.asarray(toks).astype("S"))
    except UnicodeEncodeError:
        return None
    neg = np.strings.startswith(toks, b"-")
    if np.any(np.strings.startswith(toks, b"--")):
        return None
    body = np.where(neg, np.strings.lstrip(toks, b"-"), toks)
    parts = np.char.partition(body, b".")  # np.strings.partition needs numpy >= 2.1
    whole, frac = parts[:, 0], parts[:, 2]
    flen = np.strings.str_len(frac)
    ok = np.strings.isdigit(whole) & ((flen == 0) | np.strings.isdigit(frac))
    if not ok.all() or flen.max() > exponent or np.strings.str_len(whole).max() > 18:
        return None
    w = whole.astype(np.int64) - offset_ns // scale * np.where(neg, -1, 1)
    if exponent:
        f = np.strings.ljust(frac, exponent, b"0").astype(np.int64)
    else:
        f = np.zeros(len(toks), dtype=np.int64)
    if np.any(np.abs(w) > (2**63 - 1) // scale - 1):
        return None
    v = w * scale + f
    return np.where(neg, -v, v)


def _parse_fast(data, delimiter, ncols, time_col, time_exponent, value_cols, time_offset_ns):
    """Whole-file parse with numpy's C reader when every row is well formed, else ``None``."""
    if not data or max(value_cols) != ncols - 1:
        return None
    try:
        # the list of lines itself: joining it into one string (and a StringIO of it) would
        # hold several copies of the file in memory at once
        values = np.loadtxt(
            data,
            delimiter=delimiter,
            usecols=value_cols,
            ndmin=2,
            comments=None,
            dtype=float,
        )
        if values.shape != (len(data), len(value_cols)):
            return None
        toks = np.loadtxt(
            data,
            delimiter=delimiter,
            usecols=[time_col],
            ndmin=1,
            comments=None,
            dtype=str,
        )
        t_ns = _times_vectorised(toks, time_exponent, time_offset_ns)
        if t_ns is None:
            t = [_time_fast(str(x).strip(), time_exponent) - time_offset_ns for x in toks]
            t_ns = np.array(t, dtype=np.int64)
    except (ValueError, IndexError, OverflowError):
        return None  # the row-by-row parser names the offending line
    return t_ns, values


def _place(token: str) -> float:
    """Value of one unit in the last printed digit of a decimal token (``"0.25"`` -> 0.01,
    ``"1.5e-3"`` -> 1e-4; an unreadable exponent counts as 0)."""
    token = token.strip()
    if "e" not in token and "E" not in token:  # the usual case, cheaply (EuRoC: 115k tokens)
        dot = token.find(".")
        return 10.0 ** (dot + 1 - len(token)) if dot >= 0 else 1.0
    mant, _, exp = token.lower().partition("e")
    decimals = len(mant.partition(".")[2])
    try:
        e = int(exp) if exp else 0
    except ValueError:
        e = 0
    return 10.0 ** (e - decimals)


def quat_tolerance_from_tokens(
    tokens: list[list[str]], cols: Sequence[int]
) -> Callable[[np.ndarray], np.ndarray]:
    """Allowed ``| |q| - 1 |`` per row given the printed digits of its quaternion columns.

    Rounding each component to half a unit of its last digit changes the norm by at most one
    such unit, and real files are often normalised before an offline fusion or smoothing step
    (EuRoC ground truth is off by up to 2e-5, TUM RGB-D by 8e-5). The tolerance is
    ``max(TEXT_UNIT_TOLERANCE = 1e-4, min(2 units of the coarsest printed digit, 1e-3))``: a
    wrong component order, corrupted digits or a cut-off number are off by far more.
    """

    def tol(rows: np.ndarray) -> np.ndarray:
        place = np.array([max([_place(tokens[r][c]) for c in cols]) for r in rows])
        return np.maximum(TEXT_UNIT_TOLERANCE, np.minimum(2.0 * place, 1e-3))

    return tol
