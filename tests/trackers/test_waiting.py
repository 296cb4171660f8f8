"""DueWait: the period of a stream from its arrivals, sleeping until the polling window opens,
polling until the datagram comes or the window closes; and a real socket read through it."""

from __future__ import annotations

import selectors
import socket
import threading
import time

import pytest

from trackflow.trackers.waiting import DueWait, select_nap

PERIOD = 1 / 240


class _Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


class _Selector:
    """A selector on a fake clock: a datagram becomes ready at ``ready_at``; a blocking
    select advances the clock to it (or by the timeout), a poll by ``step``."""

    def __init__(self, clock, ready_at, step=1e-5):
        self.clock, self.ready_at, self.step = clock, ready_at, step
        self.calls = []

    def nap(self, seconds):  # DueWait's nap: asleep until ready or the time is up
        self.calls.append(("nap", seconds))
        self.clock.t = min(max(self.ready_at, self.clock.t), self.clock.t + seconds)

    def select(self, timeout):
        self.calls.append(timeout)
        if self.clock.t >= self.ready_at:
            return ["datagram"]
        if timeout == 0:
            self.clock.t += self.step
            return []
        self.clock.t = min(self.ready_at, self.clock.t + timeout)
        return ["datagram"] if self.clock.t >= self.ready_at else []


def _nap(sel, seconds):
    sel.nap(seconds)


def _learned(spin_s, clock, n=6):
    w = DueWait(spin_s, clock=clock, nap=_nap)
    for k in range(n):
        w.arrived(clock.t + k * PERIOD)
    clock.t += (n - 1) * PERIOD
    return w


def test_the_period_is_the_median_interval_and_ignores_losses_and_pauses():
    clock = _Clock()
    w = DueWait(3e-4, clock=clock)
    times = [0.0, PERIOD, 2 * PERIOD]
    for t in times:
        w.arrived(t)
    assert w.period_s is None  # two intervals are not enough
    for t in (3 * PERIOD, 5 * PERIOD, 6 * PERIOD + 2e-4, 7 * PERIOD, 20.0, 20.0 + PERIOD):
        w.arrived(t)  # a lost frame, a late one, then a 13 s pause
    assert w.period_s == pytest.approx(PERIOD, abs=1e-12)
    assert w.due() == pytest.approx(20.0 + 2 * PERIOD)


def test_it_sleeps_until_the_window_then_polls_until_the_datagram():
    clock = _Clock()
    w = _learned(3e-4, clock)
    due = w.due()
    sel = _Selector(clock, ready_at=due + 1e-4)
    assert w.select(sel, 0.1) == ["datagram"]
    assert sel.calls[0] == ("nap", pytest.approx(PERIOD - 3e-4))  # asleep until due - spin
    assert set(sel.calls[1:]) == {0}  # then polled
    assert w.caught == 1
    assert w.polled_s == pytest.approx(4e-4, abs=2e-5)  # from due - spin to the datagram


def test_a_late_datagram_closes_the_window_and_the_wait_sleeps_again():
    clock = _Clock()
    w = _learned(3e-4, clock)
    due = w.due()
    sel = _Selector(clock, ready_at=due + 5e-3)
    assert w.select(sel, 0.1) == []  # the window closed without it
    assert clock.t == pytest.approx(due + 3e-4, abs=2e-5)
    assert w.caught == 0
    n = len(sel.calls)
    assert w.select(sel, 0.1) == ["datagram"]  # overdue: a plain blocking wait
    assert sel.calls[n:] == [0.1]


def test_off_or_unknown_period_is_the_plain_wait():
    clock = _Clock()
    for w in (DueWait(0.0, clock=clock), DueWait(3e-4, clock=clock)):
        if not w.spin_s:
            for k in range(6):
                w.arrived(k * PERIOD)
        sel = _Selector(clock, ready_at=clock.t + 1e-3)
        assert w.select(sel, 0.1) == ["datagram"]
        assert sel.calls == [0.1] and w.polled_s == 0.0
        assert w.period_s is None  # off: no period learned either
    with pytest.raises(ValueError, match="spin_s must be >= 0"):
        DueWait(-1.0)


def test_a_real_stream_is_read_whole_through_the_polling_wait():
    """200 datagrams at 500 Hz over loopback, read through a DueWait on a real selector:
    every one arrives, in order, and once the period is known the wait polled."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.setblocking(False)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    stop = threading.Event()

    def send():
        for k in range(200):
            if stop.wait(0.002):
                return
            tx.sendto(k.to_bytes(4, "little"), rx.getsockname())

    sender = threading.Thread(target=send, daemon=True)
    sel = selectors.DefaultSelector()
    sel.register(rx, selectors.EVENT_READ)
    w = DueWait(5e-4)
    got = []
    sender.start()
    try:
        for _ in range(20_000):  # bounded: each select returns within 0.1 s
            if len(got) == 200:
                break
            for _key, _ in w.select(sel, 0.1):
                got.append(int.from_bytes(rx.recv(16), "little"))
                w.arrived(time.time())
            if not sender.is_alive() and not sel.select(0.2):
                break
    finally:
        stop.set()
        sender.join(5)
        sel.close()
        rx.close()
        tx.close()
    assert got == list(range(200))
    assert w.period_s is not None and w.polled_s > 0.0


def test_the_setup_option_is_checked():
    from trackflow.dataflow import parse_input

    assert parse_input({"natnet": {"body": 1, "spin_us": 300}}).options["spin_us"] == 300
    assert parse_input({"natnet": {"body": 1}}).options["spin_us"] == 0  # off by default
    with pytest.raises(ValueError, match=r"input.natnet.spin_us: -5 out of range"):
        parse_input({"natnet": {"body": 1, "spin_us": -5}})


class _HighFds:
    """A selector whose descriptor select(2) cannot take."""

    def __init__(self):
        self.calls = []

    def get_map(self):
        return {5000: None}

    def select(self, timeout):
        self.calls.append(timeout)
        return []


def test_a_descriptor_beyond_select_naps_in_the_selector_to_the_millisecond_below():
    sel = _HighFds()
    select_nap(sel, 3.7e-3)
    select_nap(sel, 0.4e-3)  # under a millisecond: no nap, the window opens now
    assert sel.calls == [pytest.approx(3e-3)]


def _rehearsing(clock, rehearse_s=4e-4, takes=0.0):
    w = DueWait(0.0, clock=clock, nap=_nap, rehearse_s=rehearse_s)
    for k in range(6):
        w.arrived(clock.t + k * PERIOD)
    clock.t += 5 * PERIOD
    calls = []

    def rehearse(waiting):  # takes ``takes`` seconds of the fake clock
        assert waiting() is False  # no datagram yet (the fake selector's poll)
        calls.append(clock.t)
        clock.t += takes

    w.rehearse = rehearse
    return w, calls


def test_it_rehearses_once_per_datagram_to_be_over_rehearse_s_before_it_is_due():
    clock = _Clock()
    w, calls = _rehearsing(clock, takes=3e-4)
    due = w.due()
    sel = _Selector(clock, ready_at=due + 1e-4)
    assert w.period_s == pytest.approx(PERIOD)  # learned without polling
    assert w.select(sel, 0.1) == ["datagram"]
    # before a rehearsal was measured, it is assumed to take FIRST_REHEARSAL_S
    assert calls == [pytest.approx(due - 4e-4 - DueWait.FIRST_REHEARSAL_S)]
    assert sel.calls[0] == ("nap", pytest.approx(PERIOD - 4e-4 - DueWait.FIRST_REHEARSAL_S))
    assert sel.calls[-1] == 0.1  # then the plain wait (no polling)
    assert w.rehearsed == 1  # measured with the fake poll's step (1e-5)
    assert w.rehearsal_s() == pytest.approx(3e-4, abs=2e-5)
    sel.ready_at = due + 2e-4  # the same datagram expected again: no second rehearsal
    assert w.select(sel, 0.1) == ["datagram"] and w.rehearsed == 1
    w.arrived(due + 2e-4)  # the next datagram: timed by the measured duration now
    due = w.due()
    assert w.select(_Selector(clock, ready_at=due), 0.1) == ["datagram"]
    assert calls[1] == pytest.approx(due - 4e-4 - 3e-4, abs=2e-5)
    assert clock.t == pytest.approx(due, abs=2e-5)


def test_a_slow_rehearsal_moves_the_next_one_earlier():
    clock = _Clock()
    w, calls = _rehearsing(clock, takes=2e-3)
    for _ in range(3):
        due = w.due()
        assert w.select(_Selector(clock, ready_at=due + 1e-5), 0.1) == ["datagram"]
        w.arrived(clock.t)
    assert calls[-1] == pytest.approx(due - 4e-4 - 2e-3, abs=2e-5)  # over 0.4 ms before due
    assert w.rehearsal_s() == pytest.approx(2e-3, abs=2e-5)


def test_a_datagram_before_the_rehearsal_or_a_late_wait_skips_it():
    clock = _Clock()
    w, calls = _rehearsing(clock)
    due = w.due()
    sel = _Selector(clock, ready_at=due - 3e-3)  # early: it wakes the nap
    assert w.select(sel, 0.1) == ["datagram"] and calls == []
    clock.t = due - 2e-4  # the loop comes back within rehearse_s of the due time
    assert w.select(_Selector(clock, ready_at=due + 2e-4), 0.1) == ["datagram"]
    clock.t = due + 1e-4  # or after it: no rehearsal either
    assert w.select(_Selector(clock, ready_at=due + 2e-4), 0.1) == ["datagram"]
    assert calls == [] and w.rehearsed == 0


def test_a_short_timeout_returns_before_the_rehearsal():
    clock = _Clock()
    w, calls = _rehearsing(clock)
    sel = _Selector(clock, ready_at=w.due() + 1e-4)
    assert w.select(sel, 1e-3) == []  # the caller's loop comes back (its stop flag)
    assert calls == []
    assert w.select(sel, 0.1) == ["datagram"] and len(calls) == 1


def test_rehearsing_needs_a_callable_and_a_time():
    clock = _Clock()
    for w in (DueWait(0.0, clock=clock, nap=_nap, rehearse_s=1e-3), DueWait(0.0, clock=clock)):
        for k in range(6):
            w.arrived(clock.t + k * PERIOD)
        clock.t += 5 * PERIOD
        sel = _Selector(clock, ready_at=w.due() if w.period_s else clock.t + 1e-3)
        assert w.select(sel, 0.1) == ["datagram"]
        assert sel.calls == [0.1] and w.rehearsed == 0  # no rehearse callable / no time
    with pytest.raises(ValueError, match="rehearse_s must be >= 0"):
        DueWait(0.0, rehearse_s=-1.0)


def test_the_rehearsal_option_is_checked():
    from trackflow.dataflow import parse_input

    assert parse_input({"dtrack": {"body": 1, "rehearse_us": 1500}}).options["rehearse_us"] == 1500
    assert parse_input({"natnet": {"body": 1}}).options["rehearse_us"] == 0  # off by default
    with pytest.raises(ValueError, match=r"input.natnet.rehearse_us: 1000000.0 out of range"):
        parse_input({"natnet": {"body": 1, "rehearse_us": 1e6}})


def test_a_datagram_during_the_rehearsal_is_seen_by_it():
    clock = _Clock()
    w = DueWait(0.0, clock=clock, nap=_nap, rehearse_s=4e-4)
    for k in range(6):
        w.arrived(clock.t + k * PERIOD)
    clock.t += 5 * PERIOD
    seen = []

    def rehearse(waiting):  # decoding takes 0.5 ms, then it asks before delivering
        clock.t += 5e-4
        seen.append(waiting())

    w.rehearse = rehearse
    due = w.due()
    sel = _Selector(clock, ready_at=due - 1e-3)  # early, while the rehearsal decodes
    assert w.select(sel, 0.1) == ["datagram"]
    assert seen == [True]  # the rehearsal is told, and cuts itself short
