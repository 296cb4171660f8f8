"""Line-oriented parsing of text recordings with file:line diagnostics (shared by text formats)."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from decimal import ROUND_HALF_EVEN, Decimal, InvalidOperation
from functools import partial
from pathlib import Path

import numpy as np

from ..errors import FormatError
from ..math import UNIT_TOLERANCE
from ._clean import TRUNCATED
from ._report import ReadReport
from ._textfile import plain_ascii, scan_text, text_blocks

__all__ = [
    "BLOCK_BYTES",
    "TEXT_UNIT_TOLERANCE",
    "Table",
    "FRAMES_PREFIX",
    "TIME_EXPONENTS",
    "format_ns",
    "parse_frames_comment",
    "parse_time_ns",
    "parse_rows",
]

#: Bytes of text parsed at once: enough for numpy's reader to run at full speed, little enough
#: that one block's line strings and temporaries stay a few tens of MB beside the arrays.
BLOCK_BYTES = 1 << 20
#: Bytes kept of a time token in the one-pass parse (longer ones are read again in full).
_TIME_WIDTH = 48
#: Smallest accepted ``| |q| - 1 |`` for quaternions printed as decimal text.
TEXT_UNIT_TOLERANCE = 1e-4
#: Comment that trackflow writers put into text files to keep the frame names.
FRAMES_PREFIX = "# trackflow:"
#: Power of ten from a time unit to nanoseconds.
TIME_EXPONENTS = {"s": 9, "ms": 6, "us": 3, "ns": 0}


def parse_time_ns(token: str, exponent: int) -> int:
    """Exact integer nanoseconds from a decimal token in units of ``10**-exponent`` ... seconds.

    ``exponent`` is 9 for seconds, 0 for nanoseconds (see ``TIME_EXPONENTS``). Raises
    ``ValueError`` for anything that is not a finite number.
    """
    try:
        d = Decimal(token)
        if not d.is_finite():
            raise FormatError(f"timestamp {token!r} is not finite")
        return int(d.scaleb(exponent).to_integral_value(ROUND_HALF_EVEN))
    except InvalidOperation as exc:
        raise FormatError(f"timestamp {token!r} is not a number") from exc


def format_ns(t_ns: int, exponent: int = 9) -> str:
    """Exact decimal text of integer nanoseconds in units of ``10**(exponent - 9)`` s."""
    t = int(t_ns)
    if exponent == 0:
        return str(t)
    sign = "-" if t < 0 else ""
    whole, frac = divmod(abs(t), 10**exponent)
    return f"{sign}{whole}.{frac:0{exponent}d}"


def parse_frames_comment(line: str) -> dict[str, str]:
    """``{"source": .., "target": ..}`` from a ``# trackflow: source=a target=b`` comment."""
    out = {}
    for item in line[len(FRAMES_PREFIX) :].split():
        key, sep, value = item.partition("=")
        if sep:
            out[key] = value
    return out


@dataclass
class Table:
    """Parsed numeric rows of a text recording."""

    where: np.ndarray  # (N,) 1-based line numbers
    t_ns: np.ndarray  # (N,) int64
    columns: tuple[np.ndarray, ...]  # the K value columns in groups: (N, K_1), (N, K_2), ...
    tail_unterminated: bool  # the last row is an unterminated last line
    meta: dict[str, str] = field(default_factory=dict)  # from a "# trackflow:" comment
    # printed precision of the quaternion columns, for the rows that may need it (sorted rows)
    quat_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    quat_places: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def values(self) -> np.ndarray:
        """All value columns, (N, K) (a copy when they were read in several groups)."""
        if len(self.columns) == 1:
            return self.columns[0]
        return np.concatenate(self.columns, axis=1)

    def quat_tolerance(self, rows: np.ndarray) -> np.ndarray:
        """Allowed ``| |q| - 1 |`` of rows ``rows`` given the printed digits of their quaternion.

        Rounding each component to half a unit of its last digit changes the norm by at most
        one such unit, and real files are often normalised before an offline fusion or
        smoothing step (EuRoC ground truth is off by up to 2e-5, TUM RGB-D by 8e-5). The
        tolerance is ``max(TEXT_UNIT_TOLERANCE = 1e-4, min(2 units of the coarsest printed
        digit, 1e-3))``: a wrong component order, corrupted digits or a cut-off number are off
        by far more. The digits were looked at while parsing, for every row off unit length by
        more than ``UNIT_TOLERANCE / 2``; any other row is within every tolerance, so it gets
        the floor ``TEXT_UNIT_TOLERANCE``.
        """
        rows = np.asarray(rows, dtype=np.int64)
        place = np.zeros(len(rows))
        if len(self.quat_rows):
            k = np.minimum(np.searchsorted(self.quat_rows, rows), len(self.quat_rows) - 1)
            hit = self.quat_rows[k] == rows
            place[hit] = self.quat_places[k[hit]]
        return np.maximum(TEXT_UNIT_TOLERANCE, np.minimum(2.0 * place, 1e-3))


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
    integers, before conversion to int64). ``quat_cols`` are the file columns of a quaternion
    whose printed digits set its unit-length tolerance (:meth:`Table.quat_tolerance`).
    ``split_at`` splits the value columns into groups, each read into its own C-contiguous
    array (``Table.columns``), so that a reader's position and quaternion need no copies.

    The file is read in blocks of about ``block_bytes`` (default ``BLOCK_BYTES``) of whole
    lines, each parsed with numpy into arrays sized after a first pass that counts the lines:
    memory is the final arrays plus one block, never the file's lines (``docs/formats.md``).
    """
    n_lines, unterminated, tail_bytes, size = scan_text(path)
    rows = _max_rows(n_lines, size, delimiter, ncols, len({time_col, *value_cols}))
    build = _Builder(
        path, report, n_lines, rows, unterminated, tail_bytes, delimiter, ncols, time_col,
        time_exponent, list(value_cols), clean, header, time_offset_ns, list(quat_cols),
        list(split_at),
    )  # fmt: skip
    for first_line, lines, plain in text_blocks(path, block_bytes or BLOCK_BYTES):
        build.add(first_line, lines, plain)
    return build.finish(), build.head


def _max_rows(n_lines: int, size: int, delimiter: str | None, ncols: int, used: int) -> int:
    """Most rows a text of ``n_lines`` lines and ``size`` bytes can hold: a row has at most one
    line and at least its ``used`` columns (a character each) and ``ncols - 1`` separators."""
    return min(n_lines, size // (used + (ncols - 1) * len(delimiter or " ")) + 1)


class _Builder:
    """Rows of a text file parsed block by block into preallocated arrays (see ``parse_rows``)."""

    def __init__(
        self, path, report, n_lines, rows, unterminated, tail_bytes, delimiter, ncols,
        time_col, time_exponent, value_cols, clean, header, time_offset_ns, quat_cols, split_at,
    ):  # fmt: skip
        self.path, self.report, self.clean = path, report, clean
        self.last_index = n_lines - 1
        self.unterminated, self.tail_bytes = unterminated, tail_bytes
        self.delimiter, self.ncols, self.header = delimiter, ncols, header
        self.args = (delimiter, ncols, time_col, time_exponent, value_cols, time_offset_ns)
        self.quat_cols = quat_cols
        self.quat_idx = [value_cols.index(c) for c in quat_cols]
        self.bounds = list(zip([0, *split_at], [*split_at, len(value_cols)]))
        # room for every row the file can hold: untouched pages are never resident
        self.where = np.empty(rows, dtype=np.int64)
        self.t_ns = np.empty(rows, dtype=np.int64)
        self.columns = [np.empty((rows, b - a)) for a, b in self.bounds]
        self.n = 0
        self.rows_read = 0
        self.extra = 0
        self.meta: dict[str, str] = {}
        self.head: list[str] | None = None
        self.first = True
        self.quat_rows: list[np.ndarray] = []
        self.quat_places: list[np.ndarray] = []

    def split(self, line: str) -> list[str]:
        if self.delimiter is None:
            return line.split()
        return [x.strip() for x in line.split(self.delimiter)]

    def add(self, first_line: int, lines: list[str], plain: bool) -> None:
        """Parse one block of lines; ``first_line`` is the 0-based index of ``lines[0]``;
        ``plain``: ASCII without comments, carriage returns or other unusual whitespace.

        A plain block is first tried as it stands, every line a data row (no loop over its
        lines); numpy rejects it if a line is blank, and then it is looked at line by line.
        """
        last = first_line + len(lines) - 1
        if plain and not self.first and not (self.unterminated and last == self.last_index):
            fast = _parse_fast(lines, *self.args)
            if fast is not None:
                self.rows_read += len(lines)
                self.extra = max(self.extra, _extra_columns(lines, self.delimiter, self.ncols))
                self._append(np.arange(first_line, last + 1), fast[0], fast[1], lines)
                return
        idx, data = self._data_rows(first_line, lines)
        del lines
        self.rows_read += len(data)
        if self.unterminated and len(idx) and idx[-1] == self.last_index:
            # an unterminated last line may be cut off: only the row-by-row parser drops it
            self._rows(idx[:-1], data[:-1])
            self._slow(idx[-1:], data[-1:])
        else:
            self._rows(idx, data)

    def _data_rows(self, first_line: int, lines: list[str]) -> tuple[np.ndarray, list[str]]:
        """Line indices and stripped text of the data rows among ``lines`` (comments, blank
        lines and a header set aside)."""
        idx: list[int] = []  # 0-based line index of each data row
        data: list[str] = []
        for k, raw in enumerate(lines):
            line = raw.strip()
            if not line:
                continue
            if line[0] == "#":
                if line.startswith(FRAMES_PREFIX):
                    self.meta.update(parse_frames_comment(line))
                continue
            if self.first:
                self.first = False
                if self.header is not None and self.header(self.split(line)):
                    self.head = self.split(line)
                    continue
            idx.append(first_line + k)
            data.append(line)
        return np.array(idx, dtype=np.int64), data

    def _rows(self, idx: np.ndarray, data: list[str]) -> None:
        """Rows parsed by numpy when all are well formed, else row by row."""
        fast = _parse_fast(data, *self.args)
        if fast is None:
            self._slow(idx, data)
            return
        self.extra = max(self.extra, _extra_columns(data, self.delimiter, self.ncols))
        self._append(idx, fast[0], fast[1], data)

    def _slow(self, idx: np.ndarray, data: list[str]) -> None:
        """Row by row: exact diagnostics for malformed rows."""
        ncols, path, report = self.ncols, self.path, self.report
        _, _, time_col, time_exponent, value_cols, time_offset_ns = self.args
        where: list[int] = []
        times: list[int] = []
        vals: list[list[float]] = []
        kept: list[str] = []
        for i, line in zip(idx.tolist(), data):
            toks = self.split(line)
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
                        raise FormatError(f"timestamp {toks[time_col]!r} out of the int64 ns range")
                    v = [float(toks[j]) for j in value_cols]
                except ValueError as exc:
                    problem = f"unparsable value ({exc})"
                    reason = "unparsable value"
            if problem is not None:
                if self.unterminated and i == self.last_index:
                    report.drop(TRUNCATED, lineno)
                    report.truncated_bytes = self.tail_bytes
                    report.notes.append(f"last line ({path}:{lineno}) is incomplete: {problem}")
                    continue
                if not self.clean:
                    raise FormatError(f"{path}:{lineno}: {problem}")
                report.drop(reason, lineno)
                continue
            self.extra = max(self.extra, len(toks) - ncols)
            where.append(i)
            times.append(t)
            vals.append(v)
            kept.append(line)
        values = np.array(vals, dtype=float).reshape(len(vals), len(value_cols))
        self._append(np.array(where, dtype=np.int64), np.array(times, dtype=np.int64), values, kept)

    def _append(self, idx: np.ndarray, t_ns: np.ndarray, values: np.ndarray, data) -> None:
        """Store parsed rows, and the printed precision of quaternions off unit length."""
        n, m = self.n, len(idx)
        if not m:
            return
        if n + m > len(self.where):  # more rows than the size bound allowed: grow
            grow = max(n + m, 2 * len(self.where)) - n
            self.where = np.concatenate([self.where[:n], np.empty(grow, np.int64)])
            self.t_ns = np.concatenate([self.t_ns[:n], np.empty(grow, np.int64)])
            self.columns = [
                np.concatenate([c[:n], np.empty((grow, c.shape[1]))]) for c in self.columns
            ]
        self.where[n : n + m] = idx + 1
        self.t_ns[n : n + m] = t_ns
        for col, (a, b) in zip(self.columns, self.bounds):
            col[n : n + m] = values[:, a:b]
        self.n += m
        if self.quat_idx:
            q = values[:, self.quat_idx]
            with np.errstate(invalid="ignore"):
                off = np.abs(np.sqrt(np.einsum("ij,ij->i", q, q)) - 1.0)
            # a superset of the rows finish_stream asks about (off > UNIT_TOLERANCE)
            rows = np.flatnonzero(off > 0.5 * UNIT_TOLERANCE)
            if rows.size:
                self.quat_rows.append(rows + n)
                self.quat_places.append(self._places([data[r] for r in rows.tolist()]))

    def _places(self, lines: list[str]) -> np.ndarray:
        """Coarsest printed digit (``_place``) of the quaternion columns of each line (M,)."""
        try:
            toks = np.loadtxt(
                lines, delimiter=self.delimiter, usecols=self.quat_cols, ndmin=2,
                comments=None, dtype="S",
            )  # fmt: skip
            places = _places_vectorised(np.strings.strip(toks))
        except (ValueError, IndexError):
            places = None
        if places is None:  # non-ASCII or exponent notation: token by token
            cols = self.quat_cols
            places = np.array([max(_place(self.split(x)[c]) for c in cols) for x in lines])
        return places

    def finish(self) -> Table:
        n = self.n
        self.report.rows_read = self.rows_read
        if self.extra > 0:
            self.report.notes.append(f"ignored extra column(s) beyond the first {self.ncols}")

        def trim(a: np.ndarray) -> np.ndarray:
            return a[:n] if 2 * n >= len(a) else a[:n].copy()  # a file of mostly comments

        where = trim(self.where)
        tail = bool(self.unterminated and n and where[-1] == self.last_index + 1)
        return Table(
            where=where,
            t_ns=trim(self.t_ns),
            columns=tuple(trim(c) for c in self.columns),
            tail_unterminated=tail,
            meta=self.meta,
            quat_rows=_concat(self.quat_rows, np.int64),
            quat_places=_concat(self.quat_places, float),
        )


def _places_vectorised(toks: np.ndarray) -> np.ndarray | None:
    """``max(_place(t) for t in row)`` for each row of plain decimal byte strings (M, C);
    ``None`` when a token has an exponent (the general ``_place`` reads those)."""
    if np.any(np.strings.find(toks, b"e") >= 0) or np.any(np.strings.find(toks, b"E") >= 0):
        return None
    dot = np.strings.find(toks, b".")
    exp = np.where(dot >= 0, dot + 1 - np.strings.str_len(toks), 0)
    coarsest = exp.max(axis=1)  # powers of ten as Python computes them (exact same doubles)
    powers = {int(e): 10.0 ** int(e) for e in np.unique(coarsest)}
    return np.array([powers[e] for e in coarsest.tolist()], dtype=float)


def _concat(parts: list[np.ndarray], dtype) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(0, dtype=dtype)


def _extra_columns(data: list[str], delimiter: str | None, ncols: int) -> int:
    """Most columns beyond ``ncols`` in rows that all have at least ``ncols``.

    Counting separators in the joined rows answers the common case (no extra column) without
    splitting every row: ``ncols - 1`` separators per row means exactly ``ncols`` columns.
    """
    if not data:
        return 0
    joined = "\n".join(data)
    if delimiter is not None:
        if joined.count(delimiter) == len(data) * (ncols - 1):
            return 0
        return max(line.count(delimiter) for line in data) + 1 - ncols
    if plain_ascii(joined) and joined.count(" ") + joined.count("\t") == len(data) * (ncols - 1):
        return 0
    return max(map(len, map(str.split, data))) - ncols


def _time_fast(token: str, exponent: int) -> int:
    """``parse_time_ns`` for plain decimals without rounding (the common case), else exact."""
    body = token[1:] if token[:1] in "+-" else token
    whole, _, frac = body.partition(".")
    if whole.isdigit() and (not frac or frac.isdigit()) and len(frac) <= exponent:
        v = int(whole) * 10**exponent + (int(frac) * 10 ** (exponent - len(frac)) if frac else 0)
        return -v if token[0] == "-" else v
    return parse_time_ns(token, exponent)


def _times_vectorised(toks: np.ndarray, exponent: int, offset_ns: int) -> np.ndarray | None:
    """Exact ns from plain decimal byte strings (``-?digits[.digits]``, at most ``exponent``
    decimals) with numpy string functions; ``None`` when any token needs the general parser."""
    scale = 10**exponent
    if offset_ns % scale:
        return None
    toks = np.strings.strip(toks)  # bytes: only ASCII counts as digits, Latin-1 falls back
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
    """Parse of a block of rows with numpy's C reader when every row is well formed, else
    ``None``: the time column as text and the value columns as floats, in one pass when the
    time column is not also a value column."""
    if not data or max(value_cols) != ncols - 1:
        return None
    load = partial(np.loadtxt, data, delimiter=delimiter, comments=None)
    try:
        with warnings.catch_warnings():  # "input contained no data": blank lines
            warnings.simplefilter("ignore", UserWarning)
            if time_col in value_cols:
                values = load(usecols=value_cols, ndmin=2, dtype=float)
                toks = None
            else:
                # numpy stores non-ASCII text in "S" fields as Latin-1 (or raises ValueError)
                dtype = np.dtype([("t", f"S{_TIME_WIDTH}"), ("v", float, (len(value_cols),))])
                rows = load(usecols=[time_col, *value_cols], ndmin=1, dtype=dtype)
                if rows.shape != (len(data),):
                    return None
                values, toks = rows["v"], rows["t"]
        if values.shape != (len(data), len(value_cols)):
            return None
        if toks is None or np.any(np.strings.str_len(toks) >= _TIME_WIDTH):  # maybe cut off
            toks = load(usecols=[time_col], ndmin=1, dtype="S")
        t_ns = _times_vectorised(toks, time_exponent, time_offset_ns)
        if t_ns is None:
            t = [
                _time_fast(x.decode("latin-1").strip(), time_exponent) - time_offset_ns
                for x in toks.tolist()
            ]
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
