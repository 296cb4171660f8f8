"""The one result type of the trajectory comparison: :class:`CompareResult`, its error series
and their statistics, as a table, as plain data (JSON) and back."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ._pairs import POSE_RELATIONS, metric_name

__all__ = ["CompareResult", "ErrorSeries", "Stats", "RESULT_FORMAT"]

#: ``"format"`` of a saved result (``as_dict``); version 1 files (no ``"format"``) load too.
RESULT_FORMAT = "trackflow.compare"
RESULT_VERSION = 2
STAT_KEYS = ("rmse", "mean", "median", "std", "min", "max")


@dataclass(frozen=True)
class Stats:
    """Summary statistics of a set of non-negative errors (or signed, for per-axis errors):
    RMSE, mean, median, standard deviation (population), min, max, sum of squares, count."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float
    n: int

    @classmethod
    def of(cls, e) -> Stats:
        e = np.asarray(e, dtype=float).reshape(-1)
        if not e.size:
            nan = float("nan")
            return cls(nan, nan, nan, nan, nan, nan, 0.0, 0)
        return cls(
            float(np.sqrt(np.mean(e * e))), float(np.mean(e)), float(np.median(e)),
            float(np.std(e)), float(np.min(e)), float(np.max(e)), float(np.dot(e, e)), e.size,
        )  # fmt: skip

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass(frozen=True)
class ErrorSeries:
    """One metric of a comparison: an error number per pair, with the pair's time.

    Attributes
    ----------
    name : str
        ``"<kind>_<what>_<unit>"``, e.g. ``"ape_trans_m"``, ``"rpe_rot_deg"``, ``"ape_x_m"``.
    kind : {"ape", "rpe", "axis"}
        Absolute error, relative error, or one world axis of the APE translation (signed).
    relation : str
        The pose relation (``trackflow.evaluation.POSE_RELATIONS``), or ``"x"``, ``"y"``,
        ``"z"`` for an axis.
    unit : str
        ``"m"``, ``"deg"``, ``"rad"``, ``"%"`` or ``""`` (no unit).
    t : ndarray, shape (K,)
        Reference time of each pair (RPE: of its first pose), seconds since the first
        reference sample.
    error : ndarray, shape (K,)
    """

    name: str
    kind: str
    relation: str
    unit: str
    t: np.ndarray
    error: np.ndarray

    def stats(self) -> Stats:
        return Stats.of(self.error)


def _name_info(name: str) -> tuple[str, str, str]:
    """``(kind, relation, unit)`` of a metric name (for results saved without them)."""
    for kind in ("ape", "rpe"):
        for rel in POSE_RELATIONS:
            full, unit = metric_name(kind, rel)
            if full == name and rel != "point_distance":
                return kind, rel, unit
    if name in ("ape_x_m", "ape_y_m", "ape_z_m"):
        return "axis", name[4], "m"
    raise InputError(f"unknown metric {name!r} in a saved result")


@dataclass
class CompareResult:
    """APE/RPE of an estimate against a reference (:func:`compare_trajectories`).

    Attributes
    ----------
    series : dict of str to ErrorSeries
        Every metric, in the order of the table: APE relations, RPE relations, then the
        per-axis APE translation errors (with ``trans_part``).
    t : ndarray (K,)
        Reference times of the associated pairs, seconds since the first reference sample.
    rpe_t : ndarray (J,)
        Reference times of the first pose of each RPE pair [s].
    ref_xyz, est_xyz : ndarray (K, 3)
        Associated reference and aligned estimated positions, world frame of the reference [m].
    alignment : dict
        ``{"method", "rotation" (3x3), "translation" (3,) [m], "scale", "n_aligned"}``: the
        estimate's positions became ``scale * rotation @ p + translation``.
    n_ref, n_est : int
        Samples of the two recordings (after any processing).
    settings : dict
        The comparison's settings (``CompareSettings.as_dict``).
    nees : ndarray (K,) or None
        Position NEES per pair when the estimate has covariances.
    labels : tuple of str
        Names of the reference and the estimate (file stems on the command line).
    notes : list of str
        What the numbers leave out (e.g. RPE pairs without reference motion).
    """

    series: dict
    t: np.ndarray
    rpe_t: np.ndarray
    ref_xyz: np.ndarray
    est_xyz: np.ndarray
    alignment: dict
    n_ref: int
    n_est: int
    settings: dict = field(default_factory=dict)
    nees: np.ndarray | None = None
    labels: tuple = ("reference", "estimate")
    notes: list = field(default_factory=list)

    # -- the metrics of the default relations, by their historical names --------------------
    def _error(self, name: str) -> np.ndarray:
        if name not in self.series:
            raise InputError(
                f"this comparison has no {name} (pose relations: "
                f"{self.settings.get('pose_relations')})"
            )
        return self.series[name].error

    @property
    def ape_trans(self) -> np.ndarray:
        """APE translation per pair [m] (K,)."""
        return self._error("ape_trans_m")

    @property
    def ape_rot_deg(self) -> np.ndarray:
        """APE rotation angle per pair [deg] (K,)."""
        return self._error("ape_rot_deg")

    @property
    def rpe_trans(self) -> np.ndarray:
        """RPE translation per pair [m] (J,)."""
        return self._error("rpe_trans_m")

    @property
    def rpe_rot_deg(self) -> np.ndarray:
        """RPE rotation angle per pair [deg] (J,)."""
        return self._error("rpe_rot_deg")

    @property
    def ape_axes(self) -> np.ndarray:
        """``t(P') - t(Q)`` per pair, world axes of the reference [m] (K, 3)."""
        return self.est_xyz - self.ref_xyz

    @property
    def delta(self):
        return self.settings.get("delta", 1)

    # -- summaries ----------------------------------------------------------------------------
    def stats(self) -> dict:
        """``{metric name: Stats.as_dict()}`` (plus ``"ape_position_nees"`` with covariances)."""
        out = {name: s.stats().as_dict() for name, s in self.series.items()}
        if self.nees is not None and len(self.nees):
            from scipy.stats import chi2

            out["ape_position_nees"] = {
                "mean": float(np.mean(self.nees)),
                "expected": 3.0,
                "inside_95_percent": float(np.mean(self.nees <= chi2.ppf(0.95, 3))),
            }
        return out

    def as_dict(self, arrays: bool = False) -> dict:
        """Plain data (JSON serialisable); with ``arrays`` every per-pair error too, so that
        :meth:`from_dict` gives the result back (``compare --save-results``)."""
        a = self.alignment
        out = {
            "format": RESULT_FORMAT,
            "version": RESULT_VERSION,
            "labels": {"reference": self.labels[0], "estimate": self.labels[1]},
            "pairs": int(len(self.t)),
            "reference_samples": self.n_ref,
            "estimate_samples": self.n_est,
            "settings": dict(self.settings),
            "alignment": {
                "method": a["method"],
                "rotation": np.asarray(a["rotation"]).tolist(),
                "translation": np.asarray(a["translation"]).tolist(),
                "scale": float(a["scale"]),
                "n_aligned": a.get("n_aligned"),
            },
            "metrics": {
                n: {"kind": s.kind, "relation": s.relation, "unit": s.unit}
                for n, s in self.series.items()
            },
            "notes": list(self.notes),
            "stats": self.stats(),
        }
        if arrays:
            arr = {"t_s": self.t.tolist(), "rpe_t_s": self.rpe_t.tolist()}
            for n, s in self.series.items():
                if s.kind == "axis":
                    continue
                arr[n] = s.error.tolist()
                if s.t is not (self.t if s.kind == "ape" else self.rpe_t):
                    arr[f"{n}_t_s"] = s.t.tolist()
            arr["ape_xyz_m"] = self.ape_axes.tolist()
            arr["ref_xyz_m"] = self.ref_xyz.tolist()
            arr["est_xyz_m"] = self.est_xyz.tolist()
            if self.nees is not None:
                arr["ape_position_nees"] = self.nees.tolist()
            out["arrays"] = arr
        return out

    @classmethod
    def from_dict(cls, d: dict, what: str = "the result") -> CompareResult:
        """The result saved by :meth:`as_dict` with ``arrays=True`` (version 1 or 2).

        Raises
        ------
        InputError
            Not a saved comparison, or saved without its arrays (``--json`` instead of
            ``--save-results``).
        """
        if not isinstance(d, dict) or "stats" not in d or "alignment" not in d:
            raise InputError(f"{what}: not a saved comparison (expected 'compare --save-results')")
        if d.get("format", RESULT_FORMAT) != RESULT_FORMAT or d.get("version", 1) > RESULT_VERSION:
            raise InputError(f"{what}: unknown result format {d.get('format')} {d.get('version')}")
        arr = d.get("arrays")
        if not isinstance(arr, dict):
            raise InputError(
                f"{what}: holds statistics only; 'compare --save-results FILE' writes the "
                "per-pair errors that are needed"
            )
        try:
            t = np.asarray(arr["t_s"], float)
            rpe_t = np.asarray(arr["rpe_t_s"], float)
            ref_xyz = np.asarray(arr["ref_xyz_m"], float).reshape(-1, 3)
            est_xyz = np.asarray(arr["est_xyz_m"], float).reshape(-1, 3)
        except (KeyError, ValueError, TypeError) as exc:
            raise InputError(f"{what}: malformed arrays ({exc})") from exc
        info = d.get("metrics") or {n: None for n in d["stats"]}
        series = {}
        for name, meta in info.items():
            if name == "ape_position_nees":
                continue
            kind, rel, unit = (
                (meta["kind"], meta["relation"], meta["unit"]) if meta else _name_info(name)
            )
            if kind == "axis":
                k = "xyz".index(rel)
                err, ts = est_xyz[:, k] - ref_xyz[:, k], t
            else:
                if name not in arr:
                    raise InputError(f"{what}: no per-pair errors of {name}")
                err = np.asarray(arr[name], float)
                ts = np.asarray(arr[f"{name}_t_s"], float) if f"{name}_t_s" in arr else (
                    t if kind == "ape" else rpe_t
                )  # fmt: skip
            if err.shape != ts.shape:
                raise InputError(f"{what}: {name} has {err.size} errors for {ts.size} times")
            series[name] = ErrorSeries(name, kind, rel, unit, ts, err)
        a = d["alignment"]
        labels = d.get("labels") or {}
        nees = arr.get("ape_position_nees")
        settings = dict(d.get("settings", {}))
        settings.setdefault("pose_relations", ["trans_part", "angle_deg"])
        return cls(
            series=series,
            t=t,
            rpe_t=rpe_t,
            ref_xyz=ref_xyz,
            est_xyz=est_xyz,
            alignment={
                "method": a["method"],
                "rotation": np.asarray(a["rotation"], float),
                "translation": np.asarray(a["translation"], float),
                "scale": float(a["scale"]),
                "n_aligned": a.get("n_aligned"),
            },
            n_ref=int(d.get("reference_samples", 0)),
            n_est=int(d.get("estimate_samples", 0)),
            settings=settings,
            nees=None if nees is None else np.asarray(nees, float),
            labels=(labels.get("reference", "reference"), labels.get("estimate", "estimate")),
            notes=list(d.get("notes", [])),
        )

    def table(self) -> str:
        """Human-readable summary: two lines of settings, then one row per metric."""
        a, s = self.alignment, self.settings
        head = (
            f"{len(self.t)} associated pairs ({self.n_ref} reference, {self.n_est} estimate "
            f"samples); alignment {a['method']}"
        )
        if a["method"] in ("sim3", "scale"):
            head += f", scale {a['scale']:.6g}"
        if s.get("n_to_align") is not None:
            head += f" (fitted on the first {a['n_aligned']} pairs)"
        unit = {"f": "frame(s)", "m": "m", "d": "deg", "r": "rad"}[s.get("delta_unit", "f")]
        rows = [
            head,
            f"RPE: {len(self.rpe_t)} pairs, delta {s.get('delta', 1):g} {unit}, "
            + ("all pairs" if s.get("all_pairs") else "consecutive pairs")
            + (" (chosen on the reference)" if s.get("pairs_from_reference") else ""),
        ]
        rows += [f"note: {n}" for n in self.notes]
        width = max([18] + [len(n) + 2 for n in self.series])
        rows.append(f"{'metric':<{width}}" + "".join(f"{k:>11}" for k in STAT_KEYS))
        for name, st in self.stats().items():
            if name == "ape_position_nees":
                rows.append(
                    f"position NEES: mean {st['mean']:.3g} (3 if consistent), "
                    f"{100 * st['inside_95_percent']:.1f} % inside the 95 % bound"
                )
                continue
            rows.append(f"{name:<{width}}" + "".join(f" {st[k]:10.6f}" for k in STAT_KEYS))
        return "\n".join(rows)
