"""The relative delay of two trackers, estimated while they run (thesis 10.3.6-10.3.7).

Two sensors whose moving bodies are rigidly joined (the same frame, or frames linked by
static edges: a headset on a robot's tool) turn at the same angular speed. While the system
runs, an :class:`OnlineClockOffset` keeps the last ``window_s`` of each sensor's delivered
poses (a listener on its filter's :class:`~trackflow.dataflow.MeasuredAttributes`: one list
append per measurement) and, when asked (the run's status, about every few seconds, off the
dispatch path), estimates the delay of ``b`` relative to ``a`` with the offline estimator,
:func:`~trackflow.calibration.estimate_clock_offset`, on that window: the angular speeds
cross-correlated, then refined jointly with the rotation between the bodies, with a standard
error. Convention as offline: ``t_a = t_b + offset_s`` (both on the host clock here, so the
offset is the difference of the two trackers' remaining delays, latency and clock mapping).

:func:`rigid_pairs` finds the sensor pairs of a graph that can be compared this way;
:func:`replay_online_offset` plays two recordings through a network as the running system
would and gives the estimate it makes.
"""

from __future__ import annotations

import threading
from collections import deque

import numpy as np

from ..dataflow import RecordingPlayer, plan_query
from ..errors import InputError
from ..graph import MotionSpec, Query, SpatialRelationshipGraph
from ..io import PoseStream
from ..math import Pose
from .clock_offset import estimate_clock_offset

__all__ = ["OnlineClockOffset", "replay_online_offset", "rigid_pairs"]

#: the most samples kept per sensor (a bound for fast trackers: 1 kHz over 60 s)
MAX_SAMPLES = 60_000


class OnlineClockOffset:
    """The delay of sensor ``b`` relative to sensor ``a`` over the last ``window_s``.

    Parameters
    ----------
    a, b : str
        Sensor names (for messages).
    window_s : float
        How much of each stream the estimate uses [s].
    max_offset_s : float
        The largest delay searched [s].

    Examples
    --------
    ``kf_a.measured.listeners.append(est.add_a)`` (likewise ``b``), then ``est.estimate()``.
    """

    def __init__(self, a: str, b: str, *, window_s: float = 30.0, max_offset_s: float = 1.0):
        if not (window_s > 0 and max_offset_s > 0):
            raise InputError("online clock offset: window_s and max_offset_s must be > 0")
        self.a, self.b = a, b
        self.window_ns = int(window_s * 1e9)
        self.max_offset_s = float(max_offset_s)
        self._lock = threading.Lock()
        self._rows: tuple[deque, deque] = (deque(maxlen=MAX_SAMPLES), deque(maxlen=MAX_SAMPLES))
        self.last: dict | None = None

    def add_a(self, t_ns: int, position, quaternion) -> None:
        """A pose sensor ``a`` delivered (its measurement time [ns], position, quaternion)."""
        self._rows[0].append((t_ns, tuple(position), tuple(quaternion)))

    def add_b(self, t_ns: int, position, quaternion) -> None:
        """A pose sensor ``b`` delivered."""
        self._rows[1].append((t_ns, tuple(position), tuple(quaternion)))

    def forget(self) -> None:
        """Drop what both streams hold (their times changed: a correction was applied)."""
        with self._lock:
            for rows in self._rows:
                rows.clear()

    def _stream(self, k: int, name: str) -> PoseStream | None:
        with self._lock:
            rows = list(self._rows[k])
        if len(rows) < 10:
            return None
        t = np.array([r[0] for r in rows], dtype=np.int64)
        keep = t >= t.max() - self.window_ns
        t, order = np.unique(t[keep], return_index=True)  # increasing, one per time
        pos = np.array([r[1] for r in rows])[keep][order]
        quat = np.array([r[2] for r in rows])[keep][order]
        quat /= np.linalg.norm(quat, axis=1, keepdims=True)
        return PoseStream("world", name, t, pos, quat)

    def estimate(self) -> dict:
        """The delay over the window: ``{"a", "b", "offset_ms", "sigma_ms", "span_s",
        "peak"}`` (``offset_ms`` = ``t_a - t_b`` of one moment), or ``{"a", "b", "why"}``
        when there is none yet (too little data or motion). Kept as :attr:`last`."""
        out: dict = {"a": self.a, "b": self.b}
        sa, sb = self._stream(0, self.a), self._stream(1, self.b)
        if sa is None or sb is None:
            out["why"] = "too few measurements yet"
        else:
            try:
                r = estimate_clock_offset(sa, sb, max_offset_s=self.max_offset_s)
            except InputError as exc:
                out["why"] = str(exc)
            else:
                span = float(min(sa.t_ns[-1] - sa.t_ns[0], sb.t_ns[-1] - sb.t_ns[0])) * 1e-9
                out.update(offset_ms=round(r.offset_s * 1e3, 3),
                           sigma_ms=round(r.sigma_s * 1e3, 3), span_s=round(span, 2),
                           peak=round(r.peak_correlation, 3))  # fmt: skip
        self.last = out
        return out


def rigid_pairs(graph) -> list[tuple[str, str]]:
    """Pairs ``(a, b)`` of measured edges of ``graph`` (a
    :class:`~trackflow.graph.SpatialRelationshipGraph`) whose target frames are one body:
    the same frame, or frames joined by static edges. Sorted, ``a < b``."""
    static: dict[str, set[str]] = {}
    for e in graph.edges:
        if e.kind == "static":
            static.setdefault(e.source, set()).add(e.target)
            static.setdefault(e.target, set()).add(e.source)

    def body(frame: str) -> frozenset[str]:
        seen, todo = {frame}, [frame]
        while todo:
            for nxt in static.get(todo.pop(), ()):
                if nxt not in seen:
                    seen.add(nxt)
                    todo.append(nxt)
        return frozenset(seen)

    measured = sorted((e for e in graph.edges if e.kind == "measured"), key=lambda e: e.name)
    out = []
    for i, a in enumerate(measured):
        for b in measured[i + 1 :]:
            if b.target in body(a.target) and b.source not in body(a.target):
                out.append((a.name, b.name))
    return out


def replay_online_offset(
    a: PoseStream,
    b: PoseStream,
    *,
    window_s: float = 30.0,
    max_offset_s: float = 1.0,
    realtime: bool = False,
    speed: float = 1.0,
    play_s: float | None = None,
) -> dict:
    """What a running system estimates of ``b``'s delay relative to ``a`` (two recordings of
    rigidly joined bodies, each on its own clock) after playing both through one network:
    a sensor filter per stream (a loose constant-velocity model), the streams' bodies
    joined by a static edge, the estimate on the last ``window_s``
    (:meth:`OnlineClockOffset.estimate`). ``realtime`` plays on the wall clock (``speed``
    times real time) as a live run dispatches; the virtual clock gives the same events.
    ``play_s``: play only the first ``play_s`` seconds from when both have begun."""
    if play_s is not None:
        start = max(a.t_ns[0], b.t_ns[0])
        end = start + int(play_s * 1e9)
        a, b = (s[(s.t_ns >= start) & (s.t_ns < end)] for s in (a, b))
    g = SpatialRelationshipGraph()
    cov = np.diag([1e-6] * 3 + [1e-5] * 3)
    motion = MotionSpec(n_dp=1, n_do=1, noise=(0.0, 5.0, 0.0, 20.0))
    for name, s in (("a", a), ("b", b)):
        rate = 1e9 / float(np.median(np.diff(s.t_ns)))
        g.add_measured(name, f"world_{name}", f"body_{name}", rate_hz=rate, motion=motion,
                       covariance=cov)  # fmt: skip
    g.add_static("joint", "body_a", "body_b", Pose.identity())
    players = {
        name: RecordingPlayer.from_stream(name, s, covariance=cov)
        for name, s in (("a", a), ("b", b))
    }
    net = None
    for name in ("a", "b"):
        query = Query(f"world_{name}", f"body_{name}", name=name)
        net, _ = plan_query(g, query).build(players, network=net, prefix=f"{name}_")
    est = OnlineClockOffset("a", "b", window_s=window_s, max_offset_s=max_offset_s)
    filters = {n.rsplit("kf_", 1)[1]: c for n, c in net.components.items() if "kf_" in n}
    filters["a"].measured.listeners.append(est.add_a)
    filters["b"].measured.listeners.append(est.add_b)
    net.run(realtime=realtime, speed=speed)
    return est.estimate()
