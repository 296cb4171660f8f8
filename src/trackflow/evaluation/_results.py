"""Several saved comparisons side by side (what evo_res does): one table per metric, one row
per result, and the settings in which they differ."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError
from ._compare_result import STAT_KEYS, CompareResult

__all__ = ["ResultsComparison", "compare_results", "load_result"]

#: Settings that change what a metric measures: results that differ in them are flagged.
_SETTINGS = ("t_max_diff_s", "t_offset_s", "align", "n_to_align", "delta", "delta_unit",
             "delta_tol", "all_pairs", "pairs_from_reference")  # fmt: skip


def load_result(path) -> CompareResult:
    """A result written by ``trackflow compare --save-results FILE``
    (:meth:`CompareResult.from_dict`); ``InputError`` naming the file otherwise."""
    try:
        d = json.loads(Path(path).read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not JSON ({exc.msg}, line {exc.lineno})") from None
    return CompareResult.from_dict(d, what=str(path))


@dataclass(frozen=True)
class ResultsComparison:
    """Comparisons side by side (:func:`compare_results`).

    Attributes
    ----------
    names : tuple of str
        One per result (unique).
    results : tuple of CompareResult
    metrics : tuple of str
        The metrics every result has, in the first result's order.
    missing : dict of str to list of str
        Metrics some results lack -> the names of the results that have them.
    differences : dict of str to list
        Settings (and the alignment) in which the results differ -> the value of each.
    """

    names: tuple
    results: tuple
    metrics: tuple
    missing: dict
    differences: dict

    def stats(self) -> dict:
        """``{metric: {name: Stats.as_dict()}}``."""
        return {
            m: {n: r.series[m].stats().as_dict() for n, r in zip(self.names, self.results)}
            for m in self.metrics
        }

    def as_dict(self) -> dict:
        """Plain data (JSON serialisable)."""
        return {
            "results": [
                {
                    "name": n,
                    "labels": {"reference": r.labels[0], "estimate": r.labels[1]},
                    "pairs": int(len(r.t)),
                    "alignment": r.alignment["method"],
                    "settings": dict(r.settings),
                }
                for n, r in zip(self.names, self.results)
            ],  # fmt: skip
            "metrics": self.stats(),
            "missing": {k: list(v) for k, v in self.missing.items()},
            "differences": {k: list(v) for k, v in self.differences.items()},
        }

    def table(self) -> str:
        """One block per metric: a row per result with its statistics and pair count."""
        width = max(18, *(len(n) + 2 for n in self.names))
        rows = [f"{len(self.results)} results: " + ", ".join(self.names)]
        for key, values in self.differences.items():
            rows.append(
                f"note: they differ in {key}: "
                + ", ".join(f"{n} {v}" for n, v in zip(self.names, values))
            )
        for m, have in self.missing.items():
            rows.append(f"note: only {', '.join(have)} have {m}")
        for m, by_name in self.stats().items():
            unit = self.results[0].series[m].unit
            rows += ["", f"{m}" + (f" [{unit}]" if unit else "")]
            rows.append(f"{'result':<{width}}" + "".join(f"{k:>11}" for k in STAT_KEYS)
                        + f"{'n':>9}")  # fmt: skip
            for n, st in by_name.items():
                rows.append(f"{n:<{width}}" + "".join(f" {st[k]:10.6f}" for k in STAT_KEYS)
                            + f"{st['n']:>9}")  # fmt: skip
        return "\n".join(rows)


def compare_results(results, names=None) -> ResultsComparison:
    """Put comparisons side by side.

    Parameters
    ----------
    results : sequence of CompareResult
        At least one (two to compare).
    names : sequence of str, optional
        Their names (default: each result's estimate label); made unique by a suffix.

    Raises
    ------
    InputError
        No results, or no metric that they all have.
    """
    results = tuple(results)
    if not results:
        raise InputError("no results to compare")
    names = [r.labels[1] for r in results] if names is None else [str(n) for n in names]
    if len(names) != len(results):
        raise InputError(f"{len(names)} names for {len(results)} results")
    seen: dict = {}
    unique = []
    for n in names:
        seen[n] = seen.get(n, 0) + 1
        unique.append(n if seen[n] == 1 else f"{n} ({seen[n]})")
    common = [m for m in results[0].series if all(m in r.series for r in results)]
    if not common:
        raise InputError("the results have no metric in common (see their pose relations)")
    missing = {}
    for r in results:
        for m in r.series:
            if m not in common and m not in missing:
                missing[m] = [n for n, x in zip(unique, results) if m in x.series]
    differences = {}
    for key in _SETTINGS:
        values = [r.settings.get(key) for r in results]
        if any(v != values[0] for v in values):
            differences[key] = values
    return ResultsComparison(tuple(unique), results, tuple(common), missing, differences)
