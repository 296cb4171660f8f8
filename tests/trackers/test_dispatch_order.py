"""The live scheduler dispatches a packet's samples at ``a, a + 1, ...`` and fires a sampler
tick that falls among them between them (a sample first at a tie), for a packet given as
samples or as a block."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.trackers.inputs import SampleBlock
from trackflow.trackers.runtime import _Scheduler


class _Clock:
    now_ns = 0
    dispatch_wall_ns = 0


class _Sampler:
    period_ns = 100

    def __init__(self, log):
        self.log = log

    def tick(self, t):
        self.log.append(("tick", t))


class _Delivery:
    def __init__(self, log):
        self.log = log

    def deliver(self, items, clock=None):
        self.log.extend(("sample", n, s.arrival_ns) for n, s in items)
        return [object()] * len(items)

    def deliver_block(self, names, block, arrival_ns, clock=None):
        assert isinstance(block, SampleBlock)
        self.log.extend(("sample", n, arrival_ns + k) for k, n in enumerate(names))
        return [True] * len(names)


def _scheduler(log, next_tick):
    s = _Scheduler.__new__(_Scheduler)
    s.clock, s.sampler, s.delivery, s.writers = _Clock(), _Sampler(log), _Delivery(log), {}
    s.next_tick, s.ticks = next_tick, 0
    return s


@pytest.mark.parametrize("as_block", [False, True])
@pytest.mark.parametrize("tick", [998, 1000, 1002, 1004, 1005])
def test_ticks_among_a_packets_samples(as_block, tick):
    m = 5
    pos, quat = np.zeros((m, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (m, 1))
    covs = (np.eye(6),) * m
    block = SampleBlock(tuple(range(m)), 500, 990, pos, quat, np.stack(covs), covs)
    samples = block if as_block else list(block)
    log: list = []
    s = _scheduler(log, tick)
    s._dispatch_packet([f"b{k}" for k in range(m)], samples, 1000)
    # in time order, a sample before a tick at the same nanosecond; the ticks from the last
    # sample on are left to the next packet or the scheduling thread
    last = 1000 + m - 1
    events = [(1000 + k, 0, ("sample", f"b{k}", 1000 + k)) for k in range(m)]
    events += [(t, 1, ("tick", t)) for t in range(tick, last, 100)]
    assert log == [e for *_, e in sorted(events)]
    assert s.next_tick == (tick if tick >= last else tick + 100)


def test_calm_gc_leaves_collections_to_collect_due():
    """Inside calm_gc the automatic collector is off (no collection in a packet's path);
    collect_due makes the one that is due; on exit the collector is as before."""
    import gc

    from trackflow.trackers.runtime import calm_gc, collect_due

    class Node:
        def __init__(self):
            self.other = self  # a cycle: only the collector frees it

    was_on = gc.isenabled()
    with calm_gc():
        assert not gc.isenabled()
        t0 = gc.get_threshold()[0]
        for _ in range(t0 + 10):  # more young objects than the threshold: a collection due
            Node()
        assert gc.get_count()[0] > t0  # nothing collected them
        collect_due()
        assert gc.get_count()[0] < t0
        collect_due()  # nothing due: nothing happens
    assert gc.isenabled() == was_on
