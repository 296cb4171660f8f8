"""The one scheduler: every run of trackflow dispatches its events here, in time order.

A run is a set of :class:`EventSource` objects and one :class:`Scheduler`. Sources come in
two shapes, both behind the same protocol:

* **Timed** sources know their next event ahead (a recording's next arrival, a sampler's
  next tick, a jitter buffer's next release): :meth:`EventSource.next_ns` names its time and
  the scheduler calls :meth:`EventSource.fire` when it is due.
* **Live** sources receive events in their own threads (a tracker's socket, a Zenoh
  subscription). :meth:`EventSource.open` starts them; each event is dispatched through
  :meth:`Scheduler.arrival` in the receiving thread itself (no hand-off, so a packet's
  answers wait for no thread switch), or handed to the scheduling thread for later with
  :meth:`Scheduler.post`.

One rule orders everything: events are dispatched in time order (``clock.now_ns``), earlier
first; at equal times a sample goes before a tick (``SAMPLE < TICK``), then the order in
which they were scheduled. A receiving thread's event stamped at or before an already
dispatched one is dispatched just after it (``last + 1 ns``), counted in
:attr:`Scheduler.late`. Under the virtual clock a run goes as fast as possible; under a wall
clock (:class:`WallTime`) a timed event waits until its time, or ``delay_ns`` after it (a
jitter buffer, which lets events that travelled a network go in their time order; each is
still dispatched at its own time).
"""

from __future__ import annotations

import contextlib
import gc
import heapq
import itertools
import signal
import threading
import time
from collections.abc import Callable, Iterator
from typing import Protocol, runtime_checkable

from .errors import InputError

__all__ = [
    "SAMPLE",
    "TICK",
    "Arrival",
    "EventSource",
    "Scheduler",
    "Ticker",
    "TimedSource",
    "WallTime",
    "calm_gc",
    "collect_due",
    "stop_signals",
]

#: Event kinds; at equal times the smaller goes first (a sample before a tick).
SAMPLE, TICK = 0, 1


@runtime_checkable
class EventSource(Protocol):
    """Anything that produces events for a :class:`Scheduler`.

    Attributes
    ----------
    name : str
        For messages and statistics.
    kind : int
        :data:`SAMPLE` or :data:`TICK`: which of two events at one time goes first.
    """

    name: str
    kind: int

    def next_ns(self) -> int | None:
        """Time [ns] of the next timed event, or ``None`` (none known now; a live source
        may still post or dispatch events later)."""

    def fire(self, t_ns: int) -> None:
        """Dispatch the timed event announced by :meth:`next_ns` (``t_ns`` is its time)."""

    def open(self, scheduler: Scheduler) -> None:
        """Start receiving (live sources); nothing for timed ones."""

    def close(self) -> None:
        """Stop receiving; the scheduler dispatches nothing from this source afterwards."""


class TimedSource:
    """Base of timed sources: no thread, nothing to open or close.

    ``delay_ns``: on a wall clock, each event is released that long after its time (a jitter
    buffer: events that arrive late still go in time order); it is dispatched at its own
    time all the same.
    """

    kind = SAMPLE
    delay_ns = 0

    def early(self, t_ns: int, now_ns: int) -> bool:
        """Whether the event at ``t_ns`` may go before its time (e.g. a tick whose every
        input has already come); never, by default."""
        return False

    def open(self, scheduler: Scheduler) -> None:
        pass

    def close(self) -> None:
        pass


class Ticker(TimedSource):
    """The ticks of a sampler: ``first_ns + k * period_ns`` up to ``end_ns``.

    ``tick(t_ns)`` is called at each. A ticker whose tick is dispatched more than
    ``max_lag_ns`` after its time (a stalled process) skips to the present instead of
    firing the backlog; the skipped ticks are counted in :attr:`missed`.
    """

    kind = TICK

    def __init__(
        self,
        name: str,
        tick: Callable[[int], None],
        period_ns: int,
        first_ns: int,
        end_ns: int | None = None,
        max_lag_ns: int | None = None,
        delay_ns: int = 0,
    ):
        if period_ns <= 0:
            raise InputError(f"ticker {name!r}: period must be > 0 ns")
        self.name = name
        self.tick = tick
        self.period_ns = int(period_ns)
        self._next = int(first_ns)
        self.end_ns = end_ns
        self.max_lag_ns = max_lag_ns
        self.delay_ns = int(delay_ns)
        self.fired = 0
        self.missed = 0

    @staticmethod
    def first_at_or_after(origin_ns: int, period_ns: int, t_ns: int) -> int:
        """The first tick ``origin_ns + k * period_ns`` (integer ``k``) at or after ``t_ns``."""
        return origin_ns + -((origin_ns - t_ns) // period_ns) * period_ns

    def next_ns(self) -> int | None:
        if self.end_ns is not None and self._next > self.end_ns:
            return None
        return self._next

    def fire(self, t_ns: int) -> None:
        self._next = t_ns + self.period_ns
        self.fired += 1
        self.tick(t_ns)

    def lag_exceeded(self, t_ns: int, now_ns: int) -> bool:
        """Whether the tick at ``t_ns``, dispatched at ``now_ns``, is later than its release
        by more than ``max_lag_ns``."""
        return self.max_lag_ns is not None and now_ns - t_ns - self.delay_ns > self.max_lag_ns

    def skip_to(self, now_ns: int) -> None:
        """Skip the ticks whose release is already past (counted in :attr:`missed`)."""
        nxt = self.first_at_or_after(self._next, self.period_ns, now_ns - self.delay_ns + 1)
        self.missed += (nxt - self._next) // self.period_ns
        self._next = nxt


class WallTime:
    """A scheduler's time on a wall clock: ``(now() - wall0) * speed + t0``.

    Parameters
    ----------
    now : callable, optional
        The wall clock [ns] (default :func:`time.time_ns`, the host clock live inputs stamp
        their packets with).
    t0_ns : int, optional
        Scheduler time at the start; default: the wall clock's own time (no shift).
    speed : float
        > 1 plays faster than real time.
    """

    def __init__(self, now=time.time_ns, t0_ns: int | None = None, speed=1.0):
        if not speed > 0:
            raise InputError("speed must be > 0")
        self._now = now
        self.speed = float(speed)
        self._wall0 = now()
        self._t0 = self._wall0 if t0_ns is None else int(t0_ns)

    def now_ns(self) -> int:
        if self.speed == 1.0:
            return self._now() - self._wall0 + self._t0
        return int((self._now() - self._wall0) * self.speed) + self._t0

    def seconds_until(self, t_ns: int) -> float:
        return (t_ns - self.now_ns()) / self.speed * 1e-9


class Arrival:
    """One event dispatched by a receiving thread (:meth:`Scheduler.arrival`).

    :attr:`at_ns` is its dispatch time; :meth:`deliver` hands over its ``n`` samples, sample
    ``k`` at ``at_ns + k``, split at the timed events that fall among them.
    """

    __slots__ = ("_s", "at_ns", "used")

    def __init__(self, scheduler: Scheduler, at_ns: int):
        self._s = scheduler
        self.at_ns = at_ns
        self.used = 0

    def deliver(self, n: int, run: Callable[[int, int, int], None]) -> None:
        """``run(lo, hi, t_ns)`` for each stretch of samples ``lo..hi-1`` with no timed
        event between them (sample ``lo`` at ``t_ns``)."""
        s, a, i = self._s, self.at_ns, 0
        while i < n:
            due = s._head_time()
            if due is not None and due < a + i:  # a timed event before sample i goes first
                s._fire_head()
                continue
            j = n if due is None else max(i + 1, min(n, due - a + 1))
            s._set_now(a + i)
            run(i, j, a + i)
            s._last = max(s._last, a + j - 1)
            i = j
        self.used = max(n, 1)
        s._last = max(s._last, a + self.used - 1)


class Scheduler:
    """Time-ordered dispatch of every event of a run (module docstring).

    Parameters
    ----------
    clock : object with ``now_ns`` and ``dispatch_wall_ns``
        The network clock components read (:class:`trackflow.dataflow.Network`'s).
    time : WallTime, optional
        ``None``: virtual time (as fast as possible); else the wall clock timed events wait
        for.
    """

    def __init__(self, clock, time: WallTime | None = None):
        self.clock = clock
        self.time = time
        self.sources: list[EventSource] = []
        self.lock = threading.RLock()
        self._wake = threading.Condition(self.lock)
        self._heap: list = []
        self._seq = itertools.count()
        self._last = -(2**62)  # the latest dispatch time handed out
        self._armed: dict[int, int] = {}  # id(source) -> seq of its one live heap entry
        self.late = 0  # events stamped at or before an already dispatched one
        self.error: BaseException | None = None
        self.stopped = threading.Event()
        #: called (holding the lock) each time the events due so far have been dispatched:
        #: before the scheduling thread waits, after each :meth:`arrival` block, whenever the
        #: dispatch moves on to a later time (a virtual run, or a backlog on the wall clock)
        #: and at the run's end; a component that gathers what a round made (an agent's batch
        #: of filter states) sends it from here
        self.drained: list[Callable[[], None]] = []

    # -- sources ---------------------------------------------------------------------------------
    def add(self, source: EventSource) -> EventSource:
        """Add a source; its next timed event (if any) is scheduled. Returns it."""
        with self.lock:
            self.sources.append(source)
            self._schedule(source)
            self._wake.notify()
        return source

    def _schedule(self, source) -> None:
        t = source.next_ns()
        if t is None:
            self._armed.pop(id(source), None)  # an entry announced before is stale
        else:
            delay = getattr(source, "delay_ns", 0)
            seq = self._armed[id(source)] = next(self._seq)
            heapq.heappush(self._heap, (t, source.kind, seq, source, None, delay))

    def reschedule(self, source: EventSource) -> None:
        """From any thread: the source's next event changed (it is asked again; the event
        it announced before is dropped)."""
        with self.lock:
            self._schedule(source)
            self._wake.notify()

    def _drop_stale(self) -> None:
        """Pop heap entries of sources that were rescheduled since."""
        heap = self._heap
        while heap and heap[0][3] is not None and self._armed.get(id(heap[0][3])) != heap[0][2]:
            heapq.heappop(heap)

    def post(
        self, t_ns: int, fn: Callable[[int], None], kind: int = SAMPLE, delay_ns: int = 0
    ) -> None:
        """From any thread: ``fn(t_ns)`` dispatched by the scheduling thread at ``t_ns``,
        released ``delay_ns`` after it on a wall clock (a jitter buffer). An event posted
        at or before an already dispatched one is dispatched as soon as it is released,
        counted in :attr:`late`."""
        with self.lock:
            heapq.heappush(self._heap, (int(t_ns), kind, next(self._seq), None, fn, delay_ns))
            self._wake.notify()

    @contextlib.contextmanager
    def arrival(self, stamp_ns: int) -> Iterator[Arrival | None]:
        """Dispatch an event in the calling (receiving) thread: within the block the
        scheduler is held, the timed events before ``stamp_ns`` have been dispatched, and the
        :class:`Arrival` gives the dispatch time (``None`` once the run is over: dispatch
        nothing). An error raised in the block stops the run and is raised by :meth:`run`."""
        with self.lock:
            if self.stopped.is_set():
                yield None
                return
            try:
                a = max(int(stamp_ns), self._last + 1)
                if a > stamp_ns:
                    self.late += 1
                while (due := self._head_time()) is not None and due < a and self._released():
                    self._fire_head()
                arr = Arrival(self, a)
                yield arr
                if not arr.used:
                    self._last = max(self._last, a)
                self._drained()
            except BaseException as exc:  # raised by the scheduling thread, which stops
                self.error = exc
                self.stopped.set()
                self._wake.notify()

    def wake(self) -> None:
        """Make the scheduling thread look at its sources again (a live source's state
        changed)."""
        with self.lock:
            self._wake.notify()

    # -- dispatch -------------------------------------------------------------------------------
    def _head_time(self) -> int | None:
        self._drop_stale()
        return self._heap[0][0] if self._heap else None

    def _released(self) -> bool:
        """Whether the head event's release time has come (always, on a virtual clock)."""
        if self.time is None:
            return True
        self._drop_stale()
        if not self._heap:
            return False
        t, _, _, source, _, delay = self._heap[0]
        now = self.time.now_ns()
        return t + delay <= now or (isinstance(source, TimedSource) and source.early(t, now))

    def _drained(self) -> None:
        for fn in self.drained:
            fn()

    def _set_now(self, t: int) -> None:
        self.clock.now_ns = t
        self.clock.dispatch_wall_ns = time.perf_counter_ns()

    def _fire_head(self) -> None:
        self._drop_stale()
        t, _, _, source, fn, _ = heapq.heappop(self._heap)
        if source is not None:
            del self._armed[id(source)]
        if t < self._last and source is None:  # a posted event behind the dispatched ones
            self.late += 1
        if isinstance(source, Ticker) and self.time is not None:
            now = self.time.now_ns()
            if source.lag_exceeded(t, now):  # a stalled process: no backlog of ticks
                source.skip_to(now)
                self._schedule(source)
                return
        self._set_now(t)
        self._last = max(self._last, t)
        if source is None:
            fn(t)
        else:
            source.fire(t)
            self._schedule(source)

    def run(
        self,
        until_ns: int | None = None,
        *,
        stop: threading.Event | None = None,
        on_idle: Callable[[int], None] | None = None,
        idle_s: float = 0.1,
        calm: bool = False,
    ) -> None:
        """Open the sources, dispatch until ``until_ns`` (scheduler time), ``stop`` is set
        or a receiving thread fails (its error is raised here), then close the sources.
        Without ``until_ns`` a virtual run ends when no timed event is left; a wall-clock
        run goes on until stopped (live sources may post or dispatch events at any time).

        ``on_idle(now)`` is called between events at least every ``idle_s`` (wall clock).
        ``calm``: run inside :func:`calm_gc` (garbage collection off the events' path).
        """
        stop = stop or threading.Event()
        self.stopped.clear()
        opened = []
        try:
            for src in list(self.sources):
                src.open(self)
                opened.append(src)
            with calm_gc() if calm else contextlib.nullcontext():
                if self.time is None:
                    self._run_virtual(until_ns, stop)
                else:
                    self._run_wall(until_ns, stop, on_idle, idle_s, calm)
        finally:
            with self.lock:
                self.stopped.set()
            for src in opened:
                src.close()
        if self.error is not None:
            err, self.error = self.error, None
            raise err

    def _run_virtual(self, until_ns, stop) -> None:
        try:
            while not stop.is_set():
                t = self._head_time()
                if t is None or (until_ns is not None and t > until_ns):
                    break
                if t > self.clock.now_ns:
                    self._drained()  # the previous time's events are all dispatched
                self._fire_head()
        finally:
            self._drained()

    def _run_wall(self, until_ns, stop, on_idle, idle_s, calm) -> None:
        try:
            self._wall_loop(until_ns, stop, on_idle, idle_s, calm)
        finally:
            with self.lock:
                self._drained()

    def _wall_loop(self, until_ns, stop, on_idle, idle_s, calm) -> None:
        wall, heap = self.time, self._heap
        next_idle = 0.0
        while not (stop.is_set() or self.stopped.is_set()):
            if on_idle is not None and time.monotonic() >= next_idle:
                on_idle(wall.now_ns())
                next_idle = time.monotonic() + idle_s
            if calm:
                collect_due()
            with self.lock:
                now = wall.now_ns()
                self._drop_stale()
                if heap and (until_ns is None or heap[0][0] <= until_ns) and self._released():
                    if heap[0][0] > self.clock.now_ns:  # (a backlog: as a virtual run does)
                        self._drained()  # the previous time's events are all dispatched
                    self._fire_head()
                    continue
                if until_ns is not None and now >= until_ns:
                    break
                self._drained()
                wait = idle_s
                if heap and (until_ns is None or heap[0][0] <= until_ns):
                    wait = min(wait, wall.seconds_until(heap[0][0] + heap[0][5]))
                elif until_ns is not None:
                    wait = min(wait, wall.seconds_until(until_ns))
                if wait > 0:
                    self._wake.wait(wait)


# -- process-wide policies, each once -------------------------------------------------------------
@contextlib.contextmanager
def calm_gc():
    """Within the block, garbage collection stays off the events' path.

    It collects, then freezes every object alive (:func:`gc.freeze`), so that later
    collections look only at the objects made since (a full collection over the imported
    modules and compiled kernels would stall one event by milliseconds), and turns the
    automatic collector off: the scheduler calls :func:`collect_due` between events to make
    the collections the collector would have made. On exit the collector is on and the
    objects unfrozen again.
    """
    gc.collect()
    gc.freeze()
    was_on = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_on:
            gc.enable()
        gc.unfreeze()


def collect_due() -> None:
    """The collection the automatic collector would make now (by its thresholds: the oldest
    generation whose count is due), or none; for use inside :func:`calm_gc`."""
    t0, t1, t2 = gc.get_threshold()
    c0, c1, c2 = gc.get_count()
    if c0 > t0:
        gc.collect(2 if c2 > t2 else 1 if c1 > t1 else 0)


@contextlib.contextmanager
def stop_signals(handler):
    """``handler(signum, frame)`` for SIGTERM and SIGHUP (a service manager's stop, a closed
    terminal) within the block, the previous handlers restored after it. Outside the main
    thread (embedded use) signals are left alone."""
    old = {}
    for sig in (signal.SIGTERM, signal.SIGHUP):
        try:
            old[sig] = signal.signal(sig, handler)
        except ValueError:  # not the main thread
            pass
    try:
        yield
    finally:
        for sig, previous in old.items():
            signal.signal(sig, previous)
