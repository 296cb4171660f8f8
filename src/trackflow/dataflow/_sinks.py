"""Application sinks: push callback, pull ``get(t)`` and recorder."""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..errors import InputError
from ._component import Component
from ._events import Measurement
from ._sources import NO_ORIGIN

__all__ = ["LONG_RUN_KEEP", "CallbackSink", "PullSink", "Recorder", "keep_newest"]

#: results and latencies an answer sink of a long run keeps in memory (the newest minute at
#: 100 Hz): the answers themselves leave on the network, to a recording or to callbacks, so a
#: live run or an agent running for hours stays flat
LONG_RUN_KEEP = 6_000


class _Kept:
    """A sink that may keep only its newest latencies (and results) in memory: ``keep`` set
    (a live run or an agent running for hours) before :meth:`Component.reset`; the counts
    stay whole."""

    #: how many of the newest results and latencies stay in memory (None: all); set before
    #: ``reset``
    keep: int | None = None

    def reset(self) -> None:
        super().reset()
        if self.keep is not None:
            self.stats.latencies_ns = self._kept()

    def _kept(self):
        """A new store of results or latencies: a list, or the newest ``keep`` only."""
        return [] if self.keep is None else deque(maxlen=self.keep)


def keep_newest(components, keep: int = LONG_RUN_KEEP) -> None:
    """Bound the stores of every answer sink among ``components`` to the newest ``keep``
    results and latencies (a long run); takes effect at the sinks' next ``reset``."""
    for c in components:
        if isinstance(c, _Kept):
            c.keep = keep


class CallbackSink(_Kept, Component):
    """Calls ``callback(measurement)`` for every pushed result.

    Statistics: delivery latency = network clock at delivery - origin sensor timestamp;
    ``wall_latencies_ns`` = wall time from the scheduler dispatching the causing event to
    delivery (processing cost). With ``keep`` set (a live run for hours), only the newest
    ``keep`` latencies (and, for a :class:`Recorder`, results) stay in memory; the counts
    stay whole.
    """

    push_in = 1
    kind = "callback"

    def __init__(self, name: str, callback: Callable[[Measurement], None] | None = None):
        super().__init__(name)
        self.callback = callback
        self.wall_latencies_ns: list[int] = []

    def reset(self) -> None:
        super().reset()
        self.wall_latencies_ns = self._kept()

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
    :meth:`to_stream` give them back.

    With ``path`` it also writes every result, as it arrives, to a crash-safe native
    recording (:class:`trackflow.io.RecordingWriter`, ``.tfrec``) of ``T_source_target`` with
    its 6x6 covariance over ``(dt, dtheta)`` (``t_true = t + dt``, ``R_true = R Exp(dtheta)``).
    The file is created (replaced) when a run starts and closed when it ends; results pushed
    outside a run are appended to it. A killed process leaves every record written before the
    kill readable. A :class:`RecordingPlayer` made from
    the file (``RecordingPlayer.from_stream``) replays the recorded events bit for bit. A
    result whose timestamp is not after the previous recorded one (a naive chain can repeat a
    time) stays in memory but is not written, counted as the rejection "not recorded: time not
    increasing".

    Parameters
    ----------
    path : str or Path, optional
        The ``.tfrec`` file to write.
    source, target : str
        Frames of the recorded relationship (required with ``path``).
    """

    kind = "recorder"

    def __init__(
        self,
        name: str,
        callback: Callable[[Measurement], None] | None = None,
        *,
        path=None,
        source: str | None = None,
        target: str | None = None,
    ):
        if path is not None and not (source and target):
            raise InputError(f"recorder {name!r}: a recording path needs source and target frames")
        self.path = None if path is None else Path(path)
        self.source, self.target = source, target
        self._writer = None
        super().__init__(name, callback)
        self.events: list[Measurement] = []

    def reset(self) -> None:
        super().reset()
        self.events = self._kept()
        self.finish()
        self._last_written: int | None = None
        if self.path is not None:
            self._writer = self._open("w")

    def finish(self) -> None:
        """Close the recording file (if any); the network calls it after a run."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def push(self, m: Measurement, port: int = 0) -> None:
        super().push(m, port)
        self.events.append(m)
        if self.path is None:
            return
        if self._last_written is not None and m.t_ns <= self._last_written:
            self.stats.reject("not recorded: time not increasing")
            return
        if self._writer is None:  # a push outside a run: append (the file is created if new)
            self._writer = self._open("a")
        pose = m.pose
        self._writer.append_sample(m.t_ns, pose.position, pose.quaternion, pose.covariance)
        self._last_written = m.t_ns

    def _open(self, mode: str):
        from ..io import RecordingWriter

        return RecordingWriter(self.path, self.source, self.target, covariance=True, mode=mode)

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


class PullSink(_Kept, Component):
    """The application's pull interface: ``get(t_ns)`` evaluates the network at ``t_ns``.
    With ``keep`` set, only the newest ``keep`` latencies stay in memory."""

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
