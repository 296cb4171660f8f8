"""``ReadReport``: what a reader found and changed while loading a recording."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["ReadReport"]


@dataclass
class ReadReport:
    """Account of every row of a recording: kept, dropped (and why) or modified.

    Attributes
    ----------
    path : str
        The file (or bag) that was read.
    format : str
        The format name used (``"native"``, ``"tum"``, ...).
    unit : str
        What ``rows_read`` counts and the numbers in the lists refer to: ``"line"`` (1-based
        text line numbers), ``"record"`` (0-based native record index), ``"message"`` (0-based
        index among the topic's bag messages) or ``"row"`` (0-based row of a .mat array).
    rows_read : int
        Data rows seen, including dropped ones (comments and headers excluded).
    rows_kept : int
        Samples in the returned stream. Always ``rows_read == rows_kept + rows_dropped``.
    dropped : dict[str, list[int]]
        Reason -> locations of the rows that were dropped for it.
    normalized : list[int]
        Rows whose quaternion was rescaled to unit length beyond the rounding of the file's
        printed digits (only with ``clean=True``; otherwise that is an error).
    sign_flips : list[int]
        Rows whose quaternion has the opposite sign of the previous kept sample (``q`` and
        ``-q`` are the same rotation, so this is never an error). With ``clean=True`` the
        signs were made continuous (``signs_fixed``).
    signs_fixed : bool
        True when the signs in ``sign_flips`` were flipped back in the returned stream.
    truncated_bytes : int
        Size of an incomplete tail (a record or line cut off by a crashed writer); that row is
        also listed in ``dropped`` under ``"truncated tail"``.
    notes : list[str]
        Anything else worth knowing (conversions applied, ignored columns, topic used).
    """

    path: str
    format: str
    unit: str = "line"
    rows_read: int = 0
    rows_kept: int = 0
    dropped: dict[str, list[int]] = field(default_factory=dict)
    normalized: list[int] = field(default_factory=list)
    sign_flips: list[int] = field(default_factory=list)
    signs_fixed: bool = False
    truncated_bytes: int = 0
    notes: list[str] = field(default_factory=list)

    def drop(self, reason: str, where) -> None:
        """Record that the rows at ``where`` (an int or iterable of ints) were dropped."""
        rows = [int(where)] if isinstance(where, int) else [int(w) for w in where]
        if rows:
            self.dropped.setdefault(reason, []).extend(rows)

    @property
    def rows_dropped(self) -> int:
        """Total number of dropped rows over all reasons."""
        return sum(len(v) for v in self.dropped.values())

    @property
    def truncated(self) -> bool:
        """True when the recording ended in an incomplete row or record."""
        return self.truncated_bytes > 0 or "truncated tail" in self.dropped

    @property
    def changed(self) -> bool:
        """True when the stream differs from the file's rows in any way besides parsing."""
        return bool(self.dropped or self.normalized or (self.signs_fixed and self.sign_flips))

    def as_dict(self) -> dict:
        """Plain-data form (JSON serialisable)."""
        return {
            "path": self.path,
            "format": self.format,
            "unit": self.unit,
            "rows_read": self.rows_read,
            "rows_kept": self.rows_kept,
            "rows_dropped": self.rows_dropped,
            "dropped": {k: list(v) for k, v in self.dropped.items()},
            "normalized": list(self.normalized),
            "sign_flips": list(self.sign_flips),
            "signs_fixed": self.signs_fixed,
            "truncated_bytes": self.truncated_bytes,
            "notes": list(self.notes),
        }

    def summary(self, max_items: int = 5) -> str:
        """A few human-readable lines: counts per reason with the first locations."""

        def first(xs: list[int]) -> str:
            head = ", ".join(str(x) for x in xs[:max_items])
            return head + (", ..." if len(xs) > max_items else "")

        out = [
            f"{self.path} ({self.format}): {self.rows_kept} of {self.rows_read} rows kept, "
            f"{self.rows_dropped} dropped"
        ]
        for reason, rows in self.dropped.items():
            out.append(f"  dropped {len(rows)} ({reason}): {self.unit} {first(rows)}")
        if self.normalized:
            out.append(
                f"  normalised {len(self.normalized)} quaternions: {self.unit} "
                f"{first(self.normalized)}"
            )
        if self.sign_flips:
            what = "made continuous" if self.signs_fixed else "kept as recorded"
            out.append(
                f"  {len(self.sign_flips)} quaternion sign flips ({what}): {self.unit} "
                f"{first(self.sign_flips)}"
            )
        if self.truncated_bytes:
            out.append(f"  incomplete tail of {self.truncated_bytes} bytes ignored")
        out.extend(f"  note: {n}" for n in self.notes)
        return "\n".join(out)

    def __str__(self) -> str:
        return self.summary()
