"""Taps: the viewer's only contact with a running network.

A :class:`Tap` is a push consumer wired behind a component. In the dataflow thread it does
O(1) work per event - count it and append ``(time, latency, NIS)`` to its slot's ring on the
shared :class:`~trackflow.viewer.board.Board` (a few scalar stores) - and, at most at the view
rate, write the newest pose (behind a sensor's filter: the filter's posterior at the event)
into the slot. Everything heavier (ellipsoids, scene messages, the graph panel) happens in the
view process at the view rate, reading the board.
"""

from __future__ import annotations

import math

from ..dataflow import Component, Measurement
from .board import Board

__all__ = ["Tap"]


class Tap(Component):
    """Writes the events pushed into it to one slot of a view board.

    Parameters
    ----------
    name : str
    board : Board
    slot : int
    period_ns : int
        The view's frame period in network time: a pose is written when the event is at
        least this much newer than the last one written (decimation).
    kalman : KalmanFilter component, optional
        The filter this tap sits behind: its ``filter.nis`` goes into the ring with every
        event, and the pose written is the filter's posterior at the event's time.
    ahead : (component, int), optional
        A query's pull-able output and the slot of its prediction: while :attr:`ahead_ns` is
        set, each pose written is followed by the output pulled at the event's time plus
        :attr:`ahead_ns`, written to that slot (the prediction ghost; no extra sampler, so it
        works under any scheduler that drives the query).

    Attributes
    ----------
    latest : Measurement or None
        The newest event (a reference; kept for tests and Python users).
    ahead_ns : int
        Prediction offset [ns]; 0: no prediction is pulled.
    """

    push_in = 1
    kind = "view tap"

    def __init__(self, name: str, board: Board, slot: int, period_ns: int, kalman=None, ahead=None):
        super().__init__(name)
        self.board, self.slot, self.period_ns = board, int(slot), int(period_ns)
        self.kalman = kalman
        self.ahead = ahead
        self.ahead_ns = 0
        self.reset()

    def reset(self) -> None:
        super().reset()
        self.latest: Measurement | None = None
        self._due = -(2**62)
        self._filter = getattr(self.kalman, "filter", None)  # a reset makes a new filter
        self.board.clear(self.slot)

    @property
    def count(self) -> int:
        """Events seen since the network's last reset."""
        return self.board.count(self.slot)

    @property
    def arrival_ns(self) -> int:
        """Network clock when the newest event arrived [ns]."""
        return self.board.arrival_ns(self.slot)

    @property
    def recent(self) -> list[tuple[int, int, float]]:
        """The ring, oldest first: event time [ns] (behind a filter: corrected for the known
        stamp offset), delivery latency (network clock at arrival minus that time) [ns], NIS."""
        t, lat, nis = self.board.read_ring(self.slot)
        return list(zip(t.tolist(), lat.tolist(), nis.tolist()))

    def push(self, m: Measurement, port: int = 0) -> None:
        self.latest = m
        now = self.clock.now_ns
        f = self._filter
        t = m.t_ns
        self.board.write_event(self.slot, t, now - t, getattr(f, "nis", math.nan), now)
        if t >= self._due or t < self._due - 2 * self.period_ns:  # decimated; or a rewind
            self._due = t + self.period_ns
            pose = m.pose
            if f is not None:
                try:
                    pose = f.predict(t * 1e-9)
                except ValueError:
                    pass  # the measurement itself, then
            self.board.write_pose(self.slot, t, pose.position, pose.quaternion, pose.covariance)
            if self.ahead_ns and self.ahead is not None:
                src, slot = self.ahead
                a = src.pull(t + self.ahead_ns)
                if a is not None:
                    p = a.pose
                    self.board.write_pose(slot, a.t_ns, p.position, p.quaternion, p.covariance)
