"""Application sinks: push callback, pull ``get(t)`` and recorder."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from ._component import Component
from ._events import Measurement
from ._sources import NO_ORIGIN

__all__ = ["CallbackSink", "PullSink", "Recorder"]


class CallbackSink(Component):
    """Calls ``callback(measurement)`` for every pushed result.

    Statistics: delivery latency = network clock at delivery - origin sensor timestamp;
    ``wall_latencies_ns`` = wall time from the scheduler dispatching the causing event to
    delivery (processing cost).
    """

    push_in = 1
    kind = "callback"

    def __init__(self, name: str, callback: Callable[[Measurement], None] | None = None):
        super().__init__(name)
        self.callback = callback
        self.wall_latencies_ns: list[int] = []

    def reset(self) -> None:
        super().reset()
        self.wall_latencies_ns = []

    def push(self, m: Measurement, port: int = 0) -> None:
        self.stats.events_in += 1
        if m.origin_ns != NO_ORIGIN:
            self.stats.latencies_ns.append(self.clock.now_ns - m.origin_ns)
        if self.clock.dispatch_wall_ns:
            self.wall_latencies_ns.append(time.perf_counter_ns() - self.clock.dispatch_wall_ns)
        if self.callback is not None:
            self.callback(m)


class Recorder(CallbackSink):
    """Keeps every pushed result (and calls ``callback`` if given); :meth:`arrays` /
    :meth:`to_stream` give them back."""

    kind = "recorder"

    def __init__(self, name: str, callback: Callable[[Measurement], None] | None = None):
        super().__init__(name, callback)
        self.events: list[Measurement] = []

    def reset(self) -> None:
        super().reset()
        self.events = []

    def push(self, m: Measurement, port: int = 0) -> None:
        super().push(m, port)
        self.events.append(m)

    def arrays(self) -> dict[str, np.ndarray]:
        """``t_ns`` (N,), ``position`` (N, 3), ``quaternion`` (N, 4), ``covariance``
        (N, 6, 6) and ``origin_ns`` (N,) of the recorded events."""
        ev = self.events
        return {
            "t_ns": np.array([m.t_ns for m in ev], dtype=np.int64),
            "position": np.array([m.pose.position for m in ev]).reshape(-1, 3),
            "quaternion": np.array([m.pose.quaternion for m in ev]).reshape(-1, 4),
            "covariance": np.array([m.pose.covariance for m in ev]).reshape(-1, 6, 6),
            "origin_ns": np.array([m.origin_ns for m in ev], dtype=np.int64),
        }

    def to_stream(self, source: str, target: str):
        """The recorded events as a :class:`trackflow.io.PoseStream` ``T_source_target``."""
        from ..io import PoseStream

        a = self.arrays()
        return PoseStream(
            source, target, a["t_ns"], a["position"], a["quaternion"], covariance=a["covariance"]
        )


class PullSink(Component):
    """The application's pull interface: ``get(t_ns)`` evaluates the network at ``t_ns``."""

    pull_in = 1
    kind = "pull sink"

    def get(self, t_ns: int) -> Measurement | None:
        """The relationship at ``t_ns`` [ns] or ``None`` when it cannot be computed."""
        self.stats.events_in += 1
        m = self.inputs[0].pull(int(t_ns))
        if m is None:
            self.stats.reject("no result")
            return None
        self.stats.events_out += 1
        if m.origin_ns != NO_ORIGIN:
            self.stats.latencies_ns.append(self.clock.now_ns - m.origin_ns)
        return m
