"""What a sensor actually does, measured while it runs (thesis 6.4: attributes averaged in the
graph at a low rate), beside what the setup declares.

Each sensor filter (:class:`trackflow.dataflow.KalmanFilter`) writes every measurement
delivered to it, taken or refused (a filter declared too precise gates the sensor's noisier
measurements: the figures are of the sensor, not of what the filter kept), into a ring of
the last :data:`WINDOW` (its time, the dispatch time, the NIS of the update if taken and the
measured pose): one list store per event. The figures are computed from
the ring when they are asked for (status, the run's summary, the path switch's re-scoring,
about once a second), not per event:

* **rate** [Hz]: one over the median interval between measurement times: the rate the
  sensor runs at (an outage or a dropped frame does not lower it; the dropout fraction says
  how many were missed, and liveness judges the outage);
* **dropout**: the fraction of frames missed, counted from the gaps between measurement times
  that are whole multiples of the median interval;
* **latency** [ms]: the median of (dispatch time - measurement time), the time from exposure
  (the tracker's stamp mapped onto the host clock) to the measurement's arrival in the
  network (the median: the late frames a stalled tracker flushes when it continues, up to
  :data:`~trackflow.dataflow.BACKLOG_NS` old, do not make its typical latency for the next
  few seconds). An input that maps its clock one way (DTrack, VRPN) cannot tell its latency from
  its clock offset and subtracts the declared ``latency_ms``: what it reports is the
  declaration plus the delivery delay. NatNet reports its latency in every frame;
* **noise** [mm, deg]: the measurement noise sigma by the variate difference method: for
  white noise of sigma ``s`` on a smooth motion sampled evenly, the third difference
  ``z[k+3] - 3 z[k+2] + 3 z[k+1] - z[k]`` of each axis has variance ``20 s**2`` and the
  motion's share is ``jerk * dt**3`` (5 um at 120 Hz for a hand-held 10 m/s^3). The median of
  the squared differences over the ring (over ``0.455``, the median of chi-square with one
  degree of freedom) keeps the fast moves out. Orientation: the same on the rotation vectors
  ``Log(q[k+1]^* q[j])``. It reads high for slow sensors on fast motion (the jerk term grows
  with ``dt**3``). Its standard error is by batch means (eight contiguous parts of the
  ring);
* **consistency**: the mean normalised innovation squared (NIS) of the measurements the
  filter took (a refused one's is above the gate and not averaged). Near
  ``d = 6`` (a pose) when the declared noise and motion model fit what the sensor delivers;
  the innovation holds the prediction's error too, so the NIS alone does not give the noise.

A rate, latency or noise more than :data:`FAR` times off the declared one, or a mean NIS more
than ``FAR**2`` times off ``d``, is reported (``"far"`` in :meth:`MeasuredAttributes.summary`).
:meth:`MeasuredAttributes.edge` gives the edge with its measured figures in place of the
declared ones, for the planner's evaluation functions (thesis eq. 2.5 and 6.26).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..math import quat_rminus

__all__ = ["FAR", "WINDOW", "MeasuredAttributes"]

#: measurements the ring remembers (the newest)
WINDOW = 512
#: a measured figure more than this many times off the declared one is reported
FAR = 1.5
_NIS_DOF = 6  # a pose measurement: position and orientation
_CHI2_1_MEDIAN = 0.45493642  # the median of chi-square with one degree of freedom
_THIRD_DIFF_VAR = 20.0  # variance of a third difference of unit white noise: 1 + 9 + 9 + 1
_EVEN = 0.1  # intervals within 10 % of the median count as evenly sampled
_MIN_QUADS = 16  # evenly sampled runs of four needed for a noise figure
_BATCHES = 8  # parts of the ring whose spread gives the noise figure's standard error
_NAN3, _NAN4 = np.full(3, np.nan), np.full(4, np.nan)
_FIGURES = ("rate_hz", "dropout", "latency_ms", "noise_mm", "noise_mm_sigma", "noise_deg",
            "noise_deg_sigma", "nis_mean")  # fmt: skip


class MeasuredAttributes:
    """The last :data:`WINDOW` measurements of one sensor and the figures computed from
    them (module docstring)."""

    __slots__ = ("n", "listeners", "_ring")

    def __init__(self, listeners: list | None = None):
        self.n = 0
        #: called with ``(t_ns, position, quaternion)`` of every measured pose delivered
        #: (such as :class:`trackflow.calibration.OnlineClockOffset`): keep them cheap. The
        #: list is the caller's when given (a filter keeps one across its resets)
        self.listeners: list = [] if listeners is None else listeners
        # one tuple per measurement (t_ns, now_ns, nis, position, quaternion): a list store
        # per event, the arrays made when the figures are asked for
        self._ring: list = [None] * WINDOW

    def update(self, t_ns: int, now_ns: int, nis: float, position=None, quaternion=None) -> None:
        """A measurement taken at time ``t_ns`` [ns], dispatched at ``now_ns``, with the NIS
        of its update (NaN: none, such as a filter's first measurement) and its pose
        (``position`` (3,) [m], ``quaternion`` (4,) x, y, z, w; ``None``: not known, such as
        another agent's filter state). The ring keeps the pose arrays themselves, not
        copies: pass arrays that do not change afterwards (a pose's are read-only; a
        tracker's block is made per packet)."""
        self._ring[self.n % WINDOW] = (t_ns, now_ns, nis, position, quaternion)
        self.n += 1
        if position is not None:
            for listener in self.listeners:
                listener(t_ns, position, quaternion)

    def _arrays(self):
        """The remembered measurements, oldest first: times, dispatch times [ns], NIS, and
        positions (m, 3) and quaternions (m, 4) (NaN where not known)."""
        m = min(self.n, WINDOW)
        k = self.n % WINDOW
        rows = self._ring[k:] + self._ring[:k] if m == WINDOW else self._ring[:m]
        if m == 0:
            return (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0),
                    np.zeros((0, 3)), np.zeros((0, 4)))  # fmt: skip
        t, now, nis, pos, quat = zip(*rows)
        nan3, nan4 = _NAN3, _NAN4
        pos = np.concatenate([nan3 if p is None else p for p in pos]).reshape(-1, 3)
        quat = np.concatenate([nan4 if q is None else q for q in quat]).reshape(-1, 4)
        return (np.array(t, dtype=np.int64), np.array(now, dtype=np.int64),
                np.array(nis, dtype=float), pos.astype(float, copy=False),
                quat.astype(float, copy=False))  # fmt: skip

    def figures(self) -> dict:
        """The measured figures: ``measurements`` (all delivered), ``rate_hz``,
        ``dropout``, ``latency_ms``, ``noise_mm``, ``noise_deg`` with their standard errors
        ``noise_mm_sigma``, ``noise_deg_sigma`` and ``nis_mean`` (NaN where not measured
        yet)."""
        t, now, nis, pos, quat = self._arrays()
        out = dict.fromkeys(_FIGURES, math.nan)
        out["measurements"] = self.n
        if len(t) == 0:
            return out
        out["latency_ms"] = float(np.median(now - t)) * 1e-6
        if np.any(nis == nis):
            out["nis_mean"] = float(np.nanmean(nis))
        order = np.argsort(t, kind="stable")
        t, pos, quat = t[order], pos[order], quat[order]
        dt = np.diff(t)
        dt = dt[dt > 0]
        if len(dt) == 0:
            return out
        step = float(np.median(dt))
        out["rate_hz"] = 1e9 / step
        missed = np.maximum(np.rint(dt / step) - 1, 0).sum()
        out["dropout"] = float(missed / (missed + len(dt)))
        noise = _noise(t, pos, quat, step)
        if noise is not None:
            out["noise_mm"], out["noise_deg"], out["noise_mm_sigma"], out["noise_deg_sigma"] = noise
        return out

    def edge(self, edge):
        """``edge`` (a :class:`~trackflow.graph.Edge`) with its measured rate, latency and
        noise in place of the declared ones where measured: the noise as a diagonal
        covariance (position sigma squared on the translation block, orientation on the
        rotation block)."""
        f = self.figures()
        changes = {}
        if math.isfinite(f["rate_hz"]) and f["rate_hz"] > 0:
            changes["rate_hz"] = f["rate_hz"]
        if math.isfinite(f["latency_ms"]) and f["latency_ms"] >= 0:
            changes["latency_s"] = f["latency_ms"] * 1e-3
        if math.isfinite(f["noise_mm"]):
            sp, so = f["noise_mm"] * 1e-3, math.radians(f["noise_deg"])
            changes["covariance"] = np.diag([sp * sp] * 3 + [so * so] * 3)
        return dataclasses.replace(edge, **changes) if changes else edge

    def summary(self, edge) -> dict:
        """Measured and declared figures of ``edge`` (a :class:`~trackflow.graph.Edge`), and
        the ones far apart (``"far"``: name -> "measured vs declared")."""
        f = self.figures()
        measured = {"measurements": f["measurements"]}
        measured.update((k, _r(f[k])) for k in _FIGURES)
        c = edge.covariance
        declared = {
            "rate_hz": edge.rate_hz,
            "latency_ms": _r(edge.latency_s * 1e3),
            "noise_mm": _r(math.sqrt(max(np.trace(c[:3, :3]), 0.0) / 3) * 1e3),
            "noise_deg": _r(math.degrees(math.sqrt(max(np.trace(c[3:, 3:]), 0.0) / 3))),
        }
        far = {}
        for key in ("rate_hz", "latency_ms", "noise_mm", "noise_deg"):
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


def _noise(t: np.ndarray, pos: np.ndarray, quat: np.ndarray, step: float) -> tuple | None:
    """Position [mm] and orientation [deg] noise sigma by third differences of the
    evenly sampled runs of four (module docstring) and their standard errors, or
    ``None`` (too few)."""
    if len(t) < 4:
        return None
    d = np.diff(t).astype(float)
    even = np.abs(d - step) <= _EVEN * step
    quad = even[:-2] & even[1:-1] & even[2:]  # runs t[k] .. t[k+3]
    k = np.flatnonzero(quad)
    k = k[np.isfinite(pos[k]).all(1) & np.isfinite(pos[k + 3]).all(1)]
    k = k[np.isfinite(pos[k + 1]).all(1) & np.isfinite(pos[k + 2]).all(1)]
    if len(k) < _MIN_QUADS:
        return None
    d3 = pos[k + 3] - 3 * pos[k + 2] + 3 * pos[k + 1] - pos[k]
    # the rotation vectors of the four orientations of each run against its second, at once
    r = quat_rminus(quat[k + np.arange(4)[:, None]], quat[k + 1])  # (4, n, 3)
    r3 = r[3] - 3 * r[2] + 3 * r[1] - r[0]
    sigma, error = _sigma_and_error(np.stack([d3, r3]))
    s_pos, s_ori, e_pos, e_ori = (float(x) for x in (*sigma, *error))
    return s_pos * 1e3, math.degrees(s_ori), e_pos * 1e3, math.degrees(e_ori)


def _sigma_and_error(d3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The noise sigma from third differences ``d3`` (s, n, 3) of ``s`` signals, and its
    standard error by batch means: the spread of the estimates of :data:`_BATCHES`
    contiguous parts (the first ``n // _BATCHES`` runs each, in order) over
    ``sqrt(_BATCHES)`` (neighbouring differences share samples, so they are not
    independent: the batches keep that in). Both (s,)."""
    scale = _THIRD_DIFF_VAR * _CHI2_1_MEDIAN
    sq = (d3 * d3).reshape(len(d3), -1)  # (s, 3 n), run by run
    sigma = np.sqrt(np.median(sq, axis=1) / scale)
    per = 3 * (d3.shape[1] // _BATCHES)
    parts = np.sqrt(np.median(sq[:, : per * _BATCHES].reshape(len(d3), _BATCHES, per), axis=2)
                    / scale)  # fmt: skip
    return sigma, np.std(parts, axis=1, ddof=1) / math.sqrt(_BATCHES)


def _r(x: float) -> float | None:
    """``x`` to four significant digits (None for NaN or infinity: not measured yet)."""
    if not math.isfinite(x):
        return None
    return float(f"{x:.4g}")
