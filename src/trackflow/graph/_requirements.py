"""What a query needs of its answers (thesis 2.2.2: needs and predicates of a query): the
planner keeps to paths that meet them, and a running query checks its answers against them.

A path's figures, from the edges' declared attributes:

* latency: the sum of its measured edges' ``latency_s``;
* rate: the lowest ``rate_hz`` of its measured edges (static edges never limit it);
* position and orientation sigma: ``sqrt(trace(C_p))`` [m] and ``sqrt(trace(C_r))`` [rad] of the
  covariance propagated along the path (eq. 6.26; ``C_p``, ``C_r``: its translation and
  rotation blocks), the radial RMS error.

An answer's figures: the same sigmas of its own covariance, and its latency ``now - origin``
(the age of the newest measurement behind it when it is delivered).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ._paths import Path

__all__ = ["Requirements"]


def _sigmas(cov) -> tuple[float, float]:
    c = np.asarray(cov, dtype=float)
    return math.sqrt(max(float(np.trace(c[:3, :3])), 0.0)), math.sqrt(
        max(float(np.trace(c[3:, 3:])), 0.0)
    )


@dataclass(frozen=True)
class Requirements:
    """A query's ``require:`` (each ``None`` when not asked).

    Parameters
    ----------
    max_latency_s : float, optional
        Path latency (planning) or answer age (running) at most this [s].
    max_sigma_pos_m : float, optional
        Radial RMS position error at most this [m].
    max_sigma_ori_rad : float, optional
        Radial RMS orientation error at most this [rad].
    min_rate_hz : float, optional
        Every sensor of the path at least this rate [1/s] (planning only).
    """

    max_latency_s: float | None = None
    max_sigma_pos_m: float | None = None
    max_sigma_ori_rad: float | None = None
    min_rate_hz: float | None = None

    def __post_init__(self):
        for name in ("max_latency_s", "max_sigma_pos_m", "max_sigma_ori_rad", "min_rate_hz"):
            v = getattr(self, name)
            if v is not None and not (0 < v < math.inf):
                raise InputError(f"require: {name} must be finite and > 0, got {v}")

    @classmethod
    def from_units(cls, doc: dict) -> Requirements:
        """From a setup's ``require:`` mapping (ms, mm, deg, Hz keys)."""
        allowed = {"max_latency_ms", "max_sigma_pos_mm", "max_sigma_ori_deg", "min_rate_hz"}
        unknown = set(doc) - allowed
        if unknown:
            raise InputError(f"require: unknown keys {sorted(unknown, key=str)} "
                             f"(allowed: {sorted(allowed)})")  # fmt: skip

        def get(key, scale):
            v = doc.get(key)
            if v is None:
                return None
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise InputError(f"require.{key}: expected a number, got {v!r}")
            return float(v) * scale

        return cls(
            get("max_latency_ms", 1e-3),
            get("max_sigma_pos_mm", 1e-3),
            get("max_sigma_ori_deg", math.pi / 180),
            get("min_rate_hz", 1.0),
        )

    def path_broken(self, path: Path) -> str | None:
        """The first requirement ``path`` does not meet, with its figure, or ``None``."""
        measured = [s.edge for s in path.steps if s.edge.kind == "measured"]
        if self.max_latency_s is not None:
            lat = sum(e.latency_s for e in measured)
            if lat > self.max_latency_s:
                return (f"require.max_latency_ms {self.max_latency_s * 1e3:g} "
                        f"(path {path}: {lat * 1e3:.3g} ms)")  # fmt: skip
        if self.min_rate_hz is not None and measured:
            rate = min(e.rate_hz for e in measured)
            if rate < self.min_rate_hz:
                return f"require.min_rate_hz {self.min_rate_hz:g} (path {path}: {rate:.3g} Hz)"
        if self.max_sigma_pos_m is not None or self.max_sigma_ori_rad is not None:
            return self._sigma_broken(path.value().covariance, f"path {path}")
        return None

    def answer_broken(self, covariance, age_ns: int | None = None) -> str | None:
        """The first requirement an answer of ``covariance`` (6x6) delivered ``age_ns``
        after its newest measurement does not meet, or ``None``."""
        if self.max_latency_s is not None and age_ns is not None:
            if age_ns * 1e-9 > self.max_latency_s:
                return (f"require.max_latency_ms {self.max_latency_s * 1e3:g} "
                        f"(answer {age_ns * 1e-6:.3g} ms)")  # fmt: skip
        if self.max_sigma_pos_m is not None or self.max_sigma_ori_rad is not None:
            return self._sigma_broken(covariance, "answer")
        return None

    def _sigma_broken(self, covariance, what: str) -> str | None:
        sp, so = _sigmas(covariance)
        if self.max_sigma_pos_m is not None and sp > self.max_sigma_pos_m:
            return (f"require.max_sigma_pos_mm {self.max_sigma_pos_m * 1e3:g} "
                    f"({what}: {sp * 1e3:.3g} mm)")  # fmt: skip
        if self.max_sigma_ori_rad is not None and so > self.max_sigma_ori_rad:
            return (f"require.max_sigma_ori_deg {math.degrees(self.max_sigma_ori_rad):g} "
                    f"({what}: {math.degrees(so):.3g} deg)")  # fmt: skip
        return None
