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
