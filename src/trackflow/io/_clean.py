"""Validation shared by every reader: reject malformed rows with file and line, or clean them.

Checks, in order, on the parsed rows of a recording:

1. non-finite values (NaN, inf) in any field, and position coordinates beyond
   ``MAX_POSITION_M`` (1e9 m: corrupt digits or a wrong unit, never a pose);
2. zero quaternions;
3. quaternions off unit length by more than the file's printed precision allows
   (``1e-6`` for binary data; for decimal text up to ``1e-3`` depending on the printed digits,
   see ``quat_tolerance_from_tokens``);
4. covariances that are not symmetric or not positive semi-definite;
5. timestamps that do not strictly increase (duplicates or steps back in time);
6. quaternion sign flips between consecutive samples (never an error: ``q`` and ``-q`` are the
   same rotation, see ``docs/conventions.md``; counted always, removed with ``clean=True``).

Without ``clean`` the first problem of kinds 1-5 raises ``ValueError`` naming the file and row.
With ``clean`` offending rows are dropped (1, 2, 4, 5) or repaired (3: normalised; 6: signs made
continuous), and every change is listed in the ``ReadReport``. For 5 the fewest rows are dropped
that leave a strictly increasing sequence (a longest increasing subsequence), so one wild stamp
costs one row, not all rows after it.
"""

from __future__ import annotations

from bisect import bisect_left
from collections.abc import Callable

import numpy as np

from ..errors import FormatError
from ..math import UNIT_TOLERANCE
from ._report import ReadReport
from ._stream import PoseStream, present_fields

__all__ = ["finish_stream", "locate", "fmt_ns"]

TRUNCATED = "truncated tail"
#: Largest accepted position coordinate [m]: beyond it a value is corrupt or in a wrong unit
#: (the Earth-Moon distance is 3.8e8 m), and squares of it would overflow in the filters.
MAX_POSITION_M = 1e9


def locate(report: ReadReport, where: int) -> str:
    """``file:line`` (or ``file: record i`` ...) for messages."""
    if report.unit == "line":
        return f"{report.path}:{where}"
    return f"{report.path}: {report.unit} {where}"


def fmt_ns(t: int) -> str:
    """Integer nanoseconds as exact decimal seconds."""
    t = int(t)
    sign = "-" if t < 0 else ""
    s, ns = divmod(abs(t), 1_000_000_000)
    return f"{sign}{s}.{ns:09d} s"


def _longest_increasing(t: np.ndarray) -> np.ndarray:
    """Indices of a longest strictly increasing subsequence of ``t``.

    Among equally long ones, earlier rows are preferred (a late row that jumps back is the one
    dropped): the classic patience algorithm runs backwards on ``-t``, where replacing a tail
    keeps the element seen last, i.e. the earliest row.
    """
    u = (-np.asarray(t)[::-1]).tolist()
    n = len(u)
    tails: list[int] = []  # tails[k]: smallest value ending an increasing run of length k + 1
    tail_idx: list[int] = []
    prev = [-1] * n
    for i, v in enumerate(u):
        k = bisect_left(tails, v)
        if k == len(tails):
            tails.append(v)
            tail_idx.append(i)
        else:
            tails[k] = v
            tail_idx[k] = i
        prev[i] = tail_idx[k - 1] if k else -1
    out = []
    i = tail_idx[-1] if tail_idx else -1
    while i >= 0:
        out.append(n - 1 - i)  # back to forward indices; the chain already runs forward
        i = prev[i]
    return np.array(out, dtype=np.int64)


def _finite_rows(a: np.ndarray) -> np.ndarray:
    """Per row (axis 0): all entries finite. Row sums decide the common case in one pass."""
    flat = a.reshape(len(a), int(np.prod(a.shape[1:])))
    with np.errstate(over="ignore", invalid="ignore"):
        ok = np.isfinite(np.einsum("ij->i", flat))
    if not ok.all():  # a huge-but-finite row can overflow its sum: look closer at those rows
        ok[~ok] = np.isfinite(flat[~ok]).all(axis=1)
    return ok


def finish_stream(
    report: ReadReport,
    *,
    where: np.ndarray,
    t_ns: np.ndarray,
    position: np.ndarray,
    quaternion: np.ndarray,
    source: str,
    target: str,
    clean: bool,
    covariance: np.ndarray | None = None,
    confidence: np.ndarray | None = None,
    flags: np.ndarray | None = None,
    quat_tolerance: Callable[[np.ndarray], np.ndarray] | None = None,
    tail_unterminated: bool = False,
    check_covariance_psd: bool = True,
    owned: bool = False,
) -> PoseStream:
    """Validate parsed rows, clean them if asked, and build the stream (see module docstring).

    Parameters
    ----------
    report : ReadReport
        Updated in place (``rows_kept``, ``dropped``, ``normalized``, ``sign_flips``); its
        ``rows_read`` must already count every data row, including ones dropped before this.
    where : ndarray of int, shape (N,)
        Location of each row for messages and the report (line number, record index, ...).
    t_ns, position, quaternion, covariance, confidence, flags
        Parsed fields, shapes (N,), (N, 3), (N, 4), (N, 6, 6) or None, (N,) or None, (N,) or None.
    quat_tolerance : callable, optional
        Given row indices, the accepted ``| |q| - 1 |`` of each (from the printed precision);
        default ``UNIT_TOLERANCE``.
    tail_unterminated : bool
        The last row is an unterminated last line: if it fails a value check it is dropped as a
        truncated tail (a writer cut off mid-line) instead of raising.
    check_covariance_psd : bool
        Check symmetry and positive semi-definiteness (readers of trusted binary data skip it).
    owned : bool
        The arrays are the reader's own (nobody else holds them): quaternions are rescaled in
        place instead of in a copy (large files: one copy less of the biggest field).
    """
    rows = _Rows(report, where, len(t_ns), clean, tail_unterminated)
    _reject_non_finite(rows, position, quaternion, covariance, confidence)
    quaternion = _unit_quaternions(rows, quaternion, quat_tolerance, owned)
    if covariance is not None and check_covariance_psd and rows.n:
        covariance = _valid_covariances(rows, covariance)
    kidx = _increasing_times(rows, t_ns)
    q = _continuous_signs(rows, quaternion, kidx)
    if report.normalized:  # list only repaired rows that made it into the stream
        kept_where = set(rows.where[kidx].tolist())
        report.normalized[:] = [w for w in report.normalized if w in kept_where]
    m = len(kidx)
    if m == rows.n:  # nothing dropped: keep the arrays, avoid gathering copies of large batches
        kidx = slice(None)
    if flags is None:
        f = present_fields(covariance is not None, confidence is not None)
        fl = np.full(m, f, dtype=np.uint32)
    else:
        fl = np.asarray(flags, dtype=np.uint32)[kidx]
    conf = np.ones(m) if confidence is None else np.asarray(confidence, dtype=float)[kidx]
    report.rows_kept = m
    return PoseStream._trusted(
        source,
        target,
        np.asarray(t_ns[kidx], dtype=np.int64),
        position[kidx],
        q,
        None if covariance is None else covariance[kidx],
        conf,
        fl,
    )


class _Rows:
    """The rows under validation: which are still kept, and what a rejection does (raise
    naming the first bad row, or drop and count them with ``clean``)."""

    def __init__(self, report: ReadReport, where, n: int, clean: bool, tail_unterminated: bool):
        self.report, self.n, self.clean = report, n, clean
        self.where = np.asarray(where, dtype=np.int64)
        self.tail_unterminated = tail_unterminated
        self.keep = np.ones(n, dtype=bool)

    def drop_tail(self) -> None:
        """Drop the unterminated last row as a truncated tail."""
        last = int(self.where[self.n - 1])
        self.keep[self.n - 1] = False
        self.report.drop(TRUNCATED, last)
        self.report.notes.append(f"last line ({locate(self.report, last)}) is incomplete")

    def reject(self, reason: str, bad: np.ndarray, detail: Callable[[int], str]) -> None:
        """Rows ``bad`` (bool, (N,)) fail a check: raise ``ValueError`` at the first one
        (``detail(i)`` says why), or drop them with ``clean``; a bad unterminated last row is
        always dropped as a truncated tail."""
        bad = bad & self.keep
        if not np.any(bad):
            return
        idx = np.flatnonzero(bad)
        if self.tail_unterminated and idx[-1] == self.n - 1:
            self.drop_tail()
            idx = idx[:-1]
            if not idx.size:
                return
        if not self.clean:
            i = int(idx[0])
            raise FormatError(
                f"{locate(self.report, int(self.where[i]))}: {detail(i)} "
                f"({len(idx)} such rows; read with clean=True to drop them)"
            )
        self.keep[idx] = False
        self.report.drop(reason, self.where[idx])


def _reject_non_finite(rows: _Rows, position, quaternion, covariance, confidence) -> None:
    """Check 1: NaN or inf in any field; implausible positions; confidences outside [0, 1]."""
    finite = _finite_rows(position) & _finite_rows(quaternion)
    if covariance is not None:
        finite &= _finite_rows(covariance)
    if confidence is not None:
        finite &= np.isfinite(confidence)
    rows.reject("NaN or inf value", ~finite, lambda i: "NaN or inf value")
    with np.errstate(invalid="ignore"):
        near = (position <= MAX_POSITION_M) & (position >= -MAX_POSITION_M)  # no |p| copy
        far = finite & ~near.all(axis=1)
    rows.reject(
        "implausible position",
        far,
        lambda i: (
            f"position {tuple(float(v) for v in position[i])} m is beyond "
            f"{MAX_POSITION_M:g} m (not a pose; wrong unit or corrupt digits?)"
        ),
    )
    if confidence is not None:
        conf_ok = (confidence >= 0.0) & (confidence <= 1.0)
        rows.reject("confidence outside [0, 1]", ~conf_ok, lambda i: f"confidence {confidence[i]}")


def _unit_quaternions(rows: _Rows, quaternion: np.ndarray, quat_tolerance, owned) -> np.ndarray:
    """Checks 2 and 3: zero quaternions, and lengths off 1 beyond the printed precision
    (repaired with ``clean``). Returns the quaternions with every row visibly off unit length
    rescaled (exact values survive write/read round trips)."""
    report, n, keep = rows.report, rows.n, rows.keep
    with np.errstate(invalid="ignore"):
        norm = np.sqrt(np.einsum("ij,ij->i", quaternion, quaternion))
    rows.reject("zero quaternion", ~(norm > 1e-12), lambda i: "quaternion is zero")
    off = norm - 1.0
    np.abs(off, out=off)  # in place: one array of N, not two
    cand = np.flatnonzero(keep & (off > UNIT_TOLERANCE))
    if cand.size:
        # tolerances of the candidates only (cand is sorted: row i is at searchsorted(cand, i))
        if quat_tolerance is None:
            tol = np.full(cand.size, UNIT_TOLERANCE)
        else:
            tol = np.asarray(quat_tolerance(cand), dtype=float)
        over = off[cand] > tol
        if np.any(~over):
            report.notes.append(
                f"{int(np.sum(~over))} quaternion(s) off unit length by up to "
                f"{float(np.max(off[cand[~over]])):.2g} (within the rounding tolerance of the "
                "printed digits) were normalised"
            )
        bad = np.zeros(n, dtype=bool)
        bad[cand[over]] = True
        if np.any(bad) and not rows.clean:
            rows.reject(
                "non-unit quaternion",
                bad,
                lambda i: (
                    f"quaternion {tuple(float(v) for v in quaternion[i])} has norm "
                    f"{norm[i]:.9g}, not unit (allowed deviation "
                    f"{tol[np.searchsorted(cand, i)]:.2g})"
                ),
            )
        elif np.any(bad):
            if rows.tail_unterminated and bad[n - 1]:
                rows.drop_tail()
            report.normalized.extend(int(w) for w in rows.where[bad & keep])
    rescale = off > 1e-12
    del off
    if np.any(rescale):
        quaternion = quaternion if owned else quaternion.copy()
        # rows divided by 1.0 stay exactly as they are: no gathering copy of the rescaled rows
        norm[~(rescale & (norm > 1e-12))] = 1.0
        quaternion /= norm[:, None]
    return quaternion


def _valid_covariances(rows: _Rows, c: np.ndarray) -> np.ndarray:
    """Check 4: symmetric and positive semi-definite; returns them exactly symmetric."""
    ct = np.swapaxes(c, 1, 2)
    scale = np.max(np.abs(c), axis=(1, 2))
    asym = np.max(np.abs(c - ct), axis=(1, 2))
    sym_ok = asym <= 1e-9 * np.maximum(scale, 1e-300)
    rows.reject(
        "asymmetric covariance", ~sym_ok, lambda i: f"covariance not symmetric ({asym[i]:.3g})"
    )
    c = 0.5 * (c + ct)
    eig = np.linalg.eigvalsh(np.where(np.isfinite(c), c, 0.0))
    psd = eig[:, 0] >= -1e-9 * np.maximum(eig[:, -1], 1e-300)
    rows.reject(
        "covariance not positive semi-definite",
        ~psd,
        lambda i: f"covariance not positive semi-definite (eigenvalue {eig[i, 0]:.3g})",
    )
    return c


def _increasing_times(rows: _Rows, t_ns: np.ndarray) -> np.ndarray:
    """Check 5: strictly increasing stamps. With ``clean`` the fewest rows are dropped (exact
    repeats of the previous stamp first, then outside a longest increasing subsequence).
    Returns the indices of the kept rows (M,)."""
    report, keep, where = rows.report, rows.keep, rows.where
    kidx = np.flatnonzero(keep)
    tk = t_ns if len(kidx) == rows.n else t_ns[kidx]  # no gathering copy of a whole batch
    if tk.size < 2 or not np.any(np.diff(tk) <= 0):
        return kidx
    d = np.diff(tk)
    if not rows.clean:
        j = int(np.argmax(d <= 0)) + 1
        i, p = int(kidx[j]), int(kidx[j - 1])
        what = "duplicated timestamp" if d[j - 1] == 0 else "timestamp goes back in time"
        raise FormatError(
            f"{locate(report, int(where[i]))}: {what}: {fmt_ns(t_ns[i])} after "
            f"{fmt_ns(t_ns[p])} ({locate(report, int(where[p]))}); "
            "read with clean=True to drop such rows"
        )
    # drop exact repeats of the previous row's stamp first (keeps the first of a run)
    dup = np.concatenate([[False], d == 0])
    rest = kidx[~dup]
    lis = rest[_longest_increasing(t_ns[rest])]
    dropped = np.setdiff1d(kidx, lis)
    kept_times = set(t_ns[lis].tolist())
    is_dup = np.array([t in kept_times for t in t_ns[dropped].tolist()], dtype=bool)
    report.drop("duplicated timestamp", where[dropped[is_dup]])
    report.drop("non-increasing timestamp", where[dropped[~is_dup]])
    keep[dropped] = False
    return lis


def _continuous_signs(rows: _Rows, quaternion: np.ndarray, kidx: np.ndarray) -> np.ndarray:
    """Check 6: sign flips between consecutive kept rows (never an error): counted always,
    made continuous with ``clean``. Returns the kept rows' quaternions (M, 4)."""
    q = quaternion if len(kidx) == rows.n else quaternion[kidx]
    if len(kidx) > 1:
        flip = np.einsum("ij,ij->i", q[1:], q[:-1]) < 0.0
        if np.any(flip):
            rows.report.sign_flips.extend(int(w) for w in rows.where[kidx[1:][flip]])
            if rows.clean:
                sign = np.where(np.cumsum(np.concatenate([[False], flip])) % 2 == 1, -1.0, 1.0)
                q = q * sign[:, None]
                rows.report.signs_fixed = True
    return q
