"""What a sensor actually does, measured while it runs (thesis 6.4: attributes averaged in the
graph at a low rate), beside what the setup declares.

Each sensor filter (:class:`trackflow.dataflow.KalmanFilter`) keeps running averages over
about the last :data:`WINDOW` measurements it took:

* **rate**: one over the mean interval between measurement times;
* **latency**: the mean of (dispatch time - measurement time), the time from exposure (or
  the sensor's stamp, corrected by its known offset) to the measurement's arrival in the
  network;
* **consistency**: the mean normalised innovation squared (NIS) of the filter's updates. It
  is near ``d = 6`` (a pose: position and orientation) when the declared noise and motion
  model fit what the sensor delivers; well above, the sensor is noisier or moves harder than
  declared; well below, the declaration is conservative. (It does not give the noise sigma
  by itself: the innovation also holds the prediction's error, so the mean NIS of a sensor
  with the declared noise read 2.6 with a loose motion model in a check here; a sigma
  estimate needs the innovation covariance split into its two parts.)

A rate or latency far from the declaration (more than :data:`FAR` times off), or a mean NIS
more than ``FAR**2`` times off ``d``, is reported.
"""

from __future__ import annotations

import math

__all__ = ["FAR", "WINDOW", "MeasuredAttributes"]

#: measurements the running averages remember (about)
WINDOW = 200
#: a measured figure more than this many times off the declared one is reported
FAR = 1.5
_NIS_DOF = 6  # a pose measurement: position and orientation


class MeasuredAttributes:
    """Running averages of one sensor's rate, latency and NIS (module docstring)."""

    __slots__ = ("n", "interval_s", "latency_s", "nis", "_last_t")

    def __init__(self):
        self.n = 0
        self.interval_s = math.nan
        self.latency_s = math.nan
        self.nis = math.nan
        self._last_t: int | None = None

    @staticmethod
    def _average(old: float, new: float, n: int) -> float:
        """The mean of the first ``n`` values, then an exponential average over WINDOW."""
        if math.isnan(old):
            return new
        w = 1.0 / min(n, WINDOW)
        return old + w * (new - old)

    def update(self, t_ns: int, now_ns: int, nis: float) -> None:
        """A measurement taken at time ``t_ns`` [ns], dispatched at ``now_ns``, with the NIS
        of its update (NaN: none, such as a filter's first measurement)."""
        self.n += 1
        if self._last_t is not None and t_ns > self._last_t:
            self.interval_s = self._average(self.interval_s, (t_ns - self._last_t) * 1e-9, self.n)
        self._last_t = t_ns
        self.latency_s = self._average(self.latency_s, (now_ns - t_ns) * 1e-9, self.n)
        if nis == nis:  # not NaN
            self.nis = self._average(self.nis, nis, self.n)

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.interval_s if self.interval_s > 0 else math.nan

    def summary(self, edge) -> dict:
        """Measured and declared figures of ``edge`` (a :class:`~trackflow.graph.Edge`), and
        the ones far apart (``"far"``: name -> "measured vs declared")."""
        measured = {
            "measurements": self.n,
            "rate_hz": _r(self.rate_hz),
            "latency_ms": _r(self.latency_s * 1e3),
            "nis_mean": _r(self.nis),
        }
        declared = {"rate_hz": edge.rate_hz, "latency_ms": _r(edge.latency_s * 1e3)}
        far = {}
        for key in ("rate_hz", "latency_ms"):
            m, d = measured[key], declared[key]
            if m is not None and d and not (d / FAR <= m <= d * FAR):
                far[key] = f"{m:g} measured vs {d:g} declared"
        nis = measured["nis_mean"]
        if nis is not None and not (_NIS_DOF / FAR**2 <= nis <= _NIS_DOF * FAR**2):
            far["nis_mean"] = (
                f"{nis:g} (near {_NIS_DOF} when the declared noise and motion fit): "
                + ("noisier or moving harder than declared" if nis > _NIS_DOF else
                   "declared noise or motion larger than needed")
            )  # fmt: skip
        return {"measured": measured, "declared": declared, "far": far}


def _r(x: float) -> float | None:
    """``x`` to four significant digits (None for NaN or infinity: not measured yet)."""
    if not math.isfinite(x):
        return None
    return float(f"{x:.4g}")
