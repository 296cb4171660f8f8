"""Sinks that run for hours keep only their newest latencies (and results) with ``keep``;
without it they keep everything, and the counts stay whole either way."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.dataflow import CallbackSink, Component, Measurement, PullSink
from trackflow.math import Pose, UncertainPose

POSE = UncertainPose(Pose.identity(), np.eye(6) * 1e-6)


class _Source(Component):
    """Answers every pull with a pose made 1 ms before the time asked."""

    def pull(self, t_ns: int) -> Measurement | None:
        return Measurement(int(t_ns), POSE, int(t_ns) - 1_000_000)


@pytest.mark.parametrize("keep", [None, 5])
def test_a_pull_sink_keeps_its_newest_latencies(keep):
    sink = PullSink("q")
    sink.inputs.append(_Source("s"))
    sink.keep = keep
    sink.reset()
    for k in range(12):
        sink.clock.now_ns = k * 10_000_000 + 1_000_000 + k  # each latency its own value
        assert sink.get(k * 10_000_000) is not None
    lat = list(sink.stats.latencies_ns)
    want = [2_000_000 + k for k in range(12)]  # now - (t - 1 ms)
    assert sink.stats.events_in == sink.stats.events_out == 12
    assert lat == (want if keep is None else want[-keep:])


@pytest.mark.parametrize("keep", [None, 5])
def test_a_callback_sink_keeps_its_newest_latencies(keep):
    got = []
    sink = CallbackSink("q", got.append)
    sink.keep = keep
    sink.reset()
    for k in range(12):
        sink.clock.now_ns = k * 10_000_000 + 1_000_000 + k
        sink.push(Measurement(k * 10_000_000, POSE, k * 10_000_000))
    want = [1_000_000 + k for k in range(12)]
    assert len(got) == sink.stats.events_in == 12
    assert list(sink.stats.latencies_ns) == (want if keep is None else want[-keep:])
