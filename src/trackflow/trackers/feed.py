"""A live input fed in-process by a :class:`trackflow.dataflow.PoseFeed` (the optical tracker
on rendered frames, ``input: {optical: ...}``), paced in real time.

Frame ``i`` is exposed at ``start + t_ns[i] - t_ns[0]`` on the host clock (``start`` = when
the input starts); the feeding thread waits for that instant, has the feed process the frame
and hands ``(frame, exposure, poses)`` to the runtime as one "packet", stamped when the
processing is done (so the status line's latency is the processing time). A frame whose
successor is already exposed when the previous one is done is skipped, as a tracker that
cannot keep up drops camera frames; skipped frames are the status line's dropouts. A body
the feed does not measure in a frame is a counted rejection (``not tracked``).
"""

from __future__ import annotations

import numpy as np

from ..dataflow import InputSpec, feed_factory
from ..errors import InputError
from ._packet import PacketError
from .live_input import Body, LiveInput, Sample, host_ns

__all__ = ["FeedInput"]


class FeedInput(LiveInput):
    """One :class:`~trackflow.dataflow.PoseFeed` (built once by its registered factory from
    the first sensor's options) feeding one or more sensors (bodies)."""

    def __init__(self, spec: InputSpec):
        super().__init__(spec)
        self.protocol = spec.protocol
        self.feed = feed_factory(spec.protocol)(spec.options)
        t = np.asarray(self.feed.t_ns, dtype=np.int64)
        if t.ndim != 1 or t.size == 0 or np.any(np.diff(t) <= 0):
            raise InputError(f"input.{spec.protocol}: frame times must be strictly increasing")
        self.offsets = t - t[0]  # exposure of frame i after the start [ns]
        self.feed.warm_up()

    def add_body(self, name: str, spec: InputSpec, covariance) -> Body:
        body = spec.options["body"]
        if not self.feed.has_body(body):
            raise InputError(
                f"sensor {name!r}: input.{spec.protocol}.body {body!r} is not measured by "
                f"{spec.options.get('config', spec.protocol)}"
            )
        return super().add_body(name, spec, covariance)

    def _handle(self, data, arrival_ns) -> list[tuple[int, Sample]]:
        index, exposure_ns, poses = data
        if not self._frame(index):
            return []

        def one(b: Body):
            p = poses.get(b.options["body"])
            if p is None:
                raise PacketError("not tracked", b.options["body"])
            return self._sample(
                b, exposure_ns, arrival_ns, p.pose.position, p.pose.quaternion, p.covariance
            )

        return self._per_body(one)

    def _run(self, sink) -> None:
        start = host_ns()
        self._connected(True)
        self.ready.set()
        n = len(self.offsets)
        i = 0
        while i < n and not self._stop.is_set():
            exposure = start + int(self.offsets[i])
            wait = exposure - host_ns()
            if wait > 0 and self._stop.wait(wait * 1e-9):
                break
            poses = self.feed.measure(i)
            sink(self, (i, exposure, poses), host_ns())
            late = host_ns() - start
            i += 1
            while i + 1 < n and self.offsets[i + 1] <= late:
                i += 1  # its successor is exposed already: drop frame i
        if i >= n:
            self._event_all("end of frames")
        self._connected(False)
