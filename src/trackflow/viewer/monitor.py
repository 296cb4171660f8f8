"""Taps: the viewer's only contact with a running network.

A :class:`Tap` is a push consumer wired behind a component. In the dataflow thread it does
O(1) work per event - keep a reference to the newest event, count it, append one tuple to a
bounded ring - and, once per view frame when the viewer thread asks for it, one filter
prediction for the filtered pose. Everything heavier (ellipsoids, scene messages, the graph
panel) happens in the viewer's own thread at the view rate, reading what the taps hold.
"""

from __future__ import annotations

import math
from collections import deque

from ..dataflow import Component, Measurement

__all__ = ["Tap"]


class Tap(Component):
    """Keeps the newest pushed event of the component it is connected behind.

    Parameters
    ----------
    name : str
    kalman : KalmanFilter component, optional
        The filter this tap sits behind: its ``filter.nis`` is recorded with every event, and
        on request (:meth:`request_filtered`) its posterior at the newest event's time.
    history : int
        Length of the ring of ``(t_ns, latency_ns, nis)`` kept for time plots.

    Attributes
    ----------
    latest : Measurement or None
    arrival_ns : int
        Network clock when the newest event arrived.
    count : int
        Events seen since the network's last reset.
    recent : deque of (int, int, float)
        Event time [ns] (behind a filter: corrected for the known stamp offset), delivery
        latency (network clock at arrival minus that time) [ns], NIS.
    filtered : UncertainPose or None
        The filter's posterior at the newest event, refreshed when requested.
    """

    push_in = 1
    kind = "view tap"

    def __init__(self, name: str, kalman=None, history: int = 600):
        super().__init__(name)
        self.kalman = kalman
        self._filter = getattr(kalman, "filter", None) if kalman is not None else None
        self._history = int(history)
        self.reset()

    def reset(self) -> None:
        super().reset()
        self.latest: Measurement | None = None
        self.arrival_ns = 0
        self.count = 0
        self.recent: deque = deque(maxlen=self._history)
        self.filtered = None
        self._want = False
        if self.kalman is not None:
            self._filter = getattr(self.kalman, "filter", None)  # a reset makes a new filter

    def request_filtered(self) -> None:
        """Ask for the filter's posterior with the next event (called by the viewer thread)."""
        self._want = True

    def push(self, m: Measurement, port: int = 0) -> None:
        self.latest = m
        now = self.clock.now_ns
        self.arrival_ns = now
        self.count += 1
        f = self._filter
        nis = getattr(f, "nis", math.nan) if f is not None else math.nan
        self.recent.append((m.t_ns, now - m.t_ns, nis))
        if self._want and f is not None:
            self._want = False
            try:
                self.filtered = f.predict(m.t_ns * 1e-9)
            except ValueError:
                self.filtered = None
