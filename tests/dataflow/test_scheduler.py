"""The one scheduler (trackflow/scheduler.py): time order, the tie rule, a packet's samples
split at the ticks among them, the jitter buffer's release, errors of receiving threads,
stalled tickers, and the garbage-collection policy."""

from __future__ import annotations

import gc
import threading

import numpy as np
import pytest

from trackflow import Pose, UncertainPose
from trackflow.dataflow import (
    SAMPLE,
    TICK,
    Network,
    PullSink,
    Recorder,
    RecordingPlayer,
    Sampler,
    Scheduler,
    Ticker,
    TimedSource,
    WallTime,
    calm_gc,
    collect_due,
)
from trackflow.graph import MotionSpec


class _Clock:
    now_ns = 0
    dispatch_wall_ns = 0


class _Times(TimedSource):
    """A timed source firing at given times, logging them."""

    def __init__(self, name, times, log, kind=SAMPLE):
        self.name, self.kind, self.times, self.log = name, kind, list(times), log

    def next_ns(self):
        return self.times[0] if self.times else None

    def fire(self, t_ns):
        assert t_ns == self.times.pop(0)
        self.log.append((self.name, t_ns))


def test_virtual_order_and_tie_rule():
    log: list = []
    clock = _Clock()
    s = Scheduler(clock)
    s.add(_Times("tick", [10, 20, 30], log, kind=TICK))
    s.add(_Times("a", [5, 20, 25], log))
    s.add(_Times("b", [20, 40], log))
    s.run()
    # time order; at 20 both samples before the tick, in the order they were scheduled
    # (b's at the start, a's after a's sample at 5)
    assert log == [("a", 5), ("tick", 10), ("b", 20), ("a", 20), ("tick", 20), ("a", 25),
                   ("tick", 30), ("b", 40)]  # fmt: skip
    assert clock.now_ns == 40


def test_until_stops_before_later_events():
    log: list = []
    s = Scheduler(_Clock())
    s.add(_Times("a", [1, 2, 3, 4], log))
    s.run(until_ns=2)
    assert log == [("a", 1), ("a", 2)]


@pytest.mark.parametrize("tick", [998, 1000, 1002, 1004, 1005])
def test_ticks_among_a_packets_samples(tick):
    """A packet's samples go at ``a, a + 1, ...``; a tick falling among them is fired
    between them (a sample first at a tie); later ticks wait."""
    m, log = 5, []
    s = Scheduler(_Clock())
    ticker = s.add(Ticker("q", lambda t: log.append(("tick", t)), 100, tick))

    def run(lo, hi, t):
        log.extend(("sample", f"b{k}", t + k - lo) for k in range(lo, hi))

    with s.arrival(1000) as arr:
        assert arr.at_ns == 1000
        arr.deliver(m, run)
    last = 1000 + m - 1
    events = [(1000 + k, 0, ("sample", f"b{k}", 1000 + k)) for k in range(m)]
    events += [(t, 1, ("tick", t)) for t in range(tick, last, 100)]
    assert log == [e for *_, e in sorted(events)]
    assert ticker.next_ns() == (tick if tick >= last else tick + 100)


def test_arrival_after_a_dispatched_event_goes_just_after_it():
    s = Scheduler(_Clock())
    with s.arrival(1000) as arr:
        arr.deliver(3, lambda lo, hi, t: None)
    with s.arrival(1001) as arr:  # stamped before the last dispatched sample (1002)
        assert arr.at_ns == 1003
    assert s.late == 1


def test_error_in_a_receiving_thread_stops_the_run_and_is_raised():
    class Boom(EventSourceThread):
        def work(self, sched):
            with sched.arrival(0) as arr:
                if arr is not None:
                    raise KeyError("decoder bug")

    s = Scheduler(_Clock(), WallTime())
    s.add(Boom())
    with pytest.raises(KeyError, match="decoder bug"):
        s.run(stop=threading.Event())


class EventSourceThread:
    """A live source whose thread does ``work(scheduler)`` once."""

    name, kind = "live", SAMPLE

    def next_ns(self):
        return None

    def fire(self, t_ns):  # pragma: no cover - no timed events
        raise AssertionError

    def open(self, scheduler):
        self.thread = threading.Thread(target=self.work, args=(scheduler,))
        self.thread.start()

    def close(self):
        self.thread.join(5.0)


def test_jitter_buffer_releases_in_time_order():
    """Posted events with a delay go in the order of their times, not of their posting,
    each dispatched at its own time."""
    log: list = []
    clock = _Clock()
    wall = WallTime()
    s = Scheduler(clock, wall)
    now = wall.now_ns()
    delay = 50_000_000
    for t in (now + 3, now + 1, now + 2):
        s.post(t, lambda t_ns: log.append((t_ns, clock.now_ns)), delay_ns=delay)
    s.run(until_ns=now + delay + 10_000_000)
    assert log == [(now + k, now + k) for k in (1, 2, 3)]


def test_stalled_ticker_skips_its_backlog():
    fired: list = []
    wall = WallTime()
    now = wall.now_ns()
    s = Scheduler(_Clock(), wall)
    period = 1_000_000
    ticker = s.add(Ticker("q", fired.append, period, now - 500 * period, max_lag_ns=5 * period))
    s.run(until_ns=now + 3 * period)
    assert ticker.missed >= 490  # the ticks of the stall were skipped, not fired
    assert len(fired) == ticker.fired
    assert all(t >= now - 6 * period for t in fired)


def _network():
    rng = np.random.default_rng(3)
    n = 200
    t = np.arange(n, dtype=np.int64) * 10_000_000 + 1_000_000_000
    pos = np.cumsum(rng.normal(0, 1e-3, (n, 3)), axis=0)
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    net = Network()
    src = net.add(RecordingPlayer("s", t, pos, quat, np.eye(6) * 1e-6, 2_000_000))
    from trackflow.dataflow import KalmanFilter

    kf = net.add(KalmanFilter("kf", MotionSpec(n_dp=1, n_do=1, noise=(0.0, 3.0, 0.0, 10.0))))
    smp = net.add(Sampler("smp", 200.0))
    rec = net.add(Recorder("rec"))
    net.connect(src, kf)
    net.connect(kf, smp, mode="pull")
    net.connect(smp, rec)
    return net, rec


def test_network_wall_clock_run_equals_virtual_run():
    """One scheduler: the wall-clock run dispatches the same events in the same order as the
    virtual one, so the answers are equal bit for bit (before, within a tolerance)."""
    net, rec = _network()
    net.run()
    virtual = [(m.t_ns, m.pose.position.copy(), m.pose.covariance.copy()) for m in rec.events]
    net, rec = _network()
    net.run(realtime=True, speed=20.0)
    wall = [(m.t_ns, m.pose.position, m.pose.covariance) for m in rec.events]
    assert len(virtual) == len(wall) > 300
    for (ta, pa, ca), (tb, pb, cb) in zip(virtual, wall):
        assert ta == tb
        assert np.array_equal(pa, pb) and np.array_equal(ca, cb)


def test_pull_sink_without_events():
    net = Network()
    from trackflow.dataflow import StaticPose

    s = net.add(StaticPose("calib", UncertainPose.exact(Pose.identity())))
    app = net.add(PullSink("app"))
    net.connect(s, app)
    with pytest.raises(ValueError, match="no sensor or recording"):
        net.run()


def test_calm_gc_leaves_collections_to_collect_due():
    """Inside calm_gc the automatic collector is off (no collection in an event's path);
    collect_due makes the one that is due; on exit the collector is as before."""

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
