"""Rate-limited delivery of a sensor filter's states, decided by the consumer (``thin: true``).

A push query at ``rate_hz`` answers at ticks ``k * period`` of its agent's clock, and each
answer uses, of each remote sensor, only the newest state sent before the tick (the replica
predicts it to the tick). A consumer in thinned mode therefore tells the sensor's agent its
tick grid, and the sensor's agent sends it only those states.

Demand (Zenoh liveliness token, declared by the consumer, gone when it leaves or dies)::

    trackflow/<realm>/demand/<edge>/<consumer>/<period_ns>/<phase_ns>

``period_ns`` (1 ms .. 60 s) and ``phase_ns`` (``0 <= phase < period``) place the ticks at
``phase + k * period`` on the *sensor agent's* clock (the consumer maps its own grid with its
clock-offset estimate). One consumer may declare several grids for one edge (queries at
different rates); the sensor's agent serves the union of them on one stream per consumer::

    trackflow/<realm>/thin/<edge>/<consumer>

Every message there carries, as its Zenoh attachment, the tick it completes (int64 ns,
little-endian, sensor clock): "every state sent before this tick is accounted for". Its
payload is either a filter state (``docs/wire.md``, version 2), the newest one sent at or
before that tick, or empty (a heartbeat: nothing new since the previous tick; none are sent
before the sensor's first state). So a consumer
knows when it has everything a tick needs and answers at once instead of waiting for a jitter
buffer.

:class:`Thinner` is the rule, free of clocks and threads: offer it each state with its send
stamp ``h`` (the sensor agent's clock when the state was made; the consumer orders states and
ticks by it); ask it what is due when the clock passes a tick plus ``grace_ns``. A state is
the newest before tick ``T`` once a later state (``h > T``) comes or the clock passes
``T + grace``; states offered after their tick was completed (the sensor's own thread was
late) are sent at once, counted as late. :class:`ThinStreams` moves the clock it hands
:meth:`Thinner.due` no further than the sensor's progress (a recording's player that runs
late holds its ticks back), so an agent's own streams have no late states.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

from ..errors import InputError

__all__ = [
    "DEMAND_LIMITS_NS",
    "MAX_STREAMS_PER_EDGE",
    "Grid",
    "ThinStreams",
    "Thinner",
    "demand_key",
    "next_tick",
    "parse_demand",
    "prev_tick",
    "thin_key",
]

DEMAND_LIMITS_NS = (1_000_000, 60_000_000_000)  # accepted tick periods: 1 ms .. 60 s
MAX_STREAMS_PER_EDGE = 64  # consumers with a thinned stream of one sensor (more: rejected)
_IDLE_NS = 50_000_000  # without streams, look again after 50 ms
_HELD_NS = 1_000_000  # ticks held back by a late sensor: look again after 1 ms


class Grid(NamedTuple):
    """Ticks at ``phase_ns + k * period_ns`` (one clock, integer ns)."""

    period_ns: int
    phase_ns: int


def next_tick(h_ns: int, grids) -> int:
    """The first tick at or after ``h_ns`` of the union of ``grids`` [ns]."""
    return min(g.phase_ns + -((g.phase_ns - h_ns) // g.period_ns) * g.period_ns for g in grids)


def prev_tick(h_ns: int, grids) -> int:
    """The last tick strictly before ``h_ns`` of the union of ``grids`` [ns]."""
    return max(g.phase_ns + (h_ns - 1 - g.phase_ns) // g.period_ns * g.period_ns for g in grids)


def demand_key(realm: str, edge: str, consumer: str, grid: Grid) -> str:
    return f"trackflow/{realm}/demand/{edge}/{consumer}/{grid.period_ns}/{grid.phase_ns}"


def thin_key(realm: str, edge: str, consumer: str) -> str:
    return f"trackflow/{realm}/thin/{edge}/{consumer}"


def parse_demand(key: str, realm: str) -> tuple[str, str, Grid]:
    """``(edge, consumer, grid)`` of a demand token's key.

    Raises
    ------
    ValueError
        With a short reason (a rejection counter key) if the key is not a valid demand.
    """
    parts = key.split("/")
    if len(parts) != 7 or parts[:3] != ["trackflow", realm, "demand"]:
        raise InputError("malformed demand")
    edge, consumer, period, phase = parts[3:]
    if not (period.isdigit() and phase.isdigit()):
        raise InputError("malformed demand")
    p, ph = int(period), int(phase)
    if not DEMAND_LIMITS_NS[0] <= p <= DEMAND_LIMITS_NS[1]:
        raise InputError("demand period out of range")
    if ph >= p:
        raise InputError("demand phase out of range")
    return edge, consumer, Grid(p, ph)


@dataclass
class Thinner:
    """The thinned stream of one sensor filter to one consumer (see the module docstring).

    Parameters
    ----------
    grids : dict[Grid, int]
        The consumer's tick grids (sensor clock) with the number of tokens declaring each.
    now_ns : int
        The sensor agent's clock when the stream starts: the first tick it completes is the
        first one after it.

    Methods return the messages to send, in order, as ``(tick_ns, payload)`` pairs; a
    ``None`` payload is a heartbeat.
    """

    grids: dict
    now_ns: int
    sent: int = 0
    heartbeats: int = 0
    late: int = 0
    _last_h: int | None = None
    _pending: object = None
    _pending_tick: int = 0
    _done: int = field(init=False)

    def __post_init__(self):
        self._done = prev_tick(self.now_ns, self.grids)

    def offer(self, h_ns: int, payload) -> list:
        """A new state of the filter, made at ``h_ns`` (sensor clock)."""
        first = self._last_h is None
        h = h_ns if first else max(h_ns, self._last_h)
        self._last_h = h
        if h <= self._done:  # its tick was completed already: send at once
            self.late += 1
            self.sent += 1
            return [(self._done, payload)]
        out = []
        if h > self._upcoming():
            # the pending state (or nothing new) is the answer to every tick in [that, h)
            self._done = prev_tick(h, self.grids)
            if not first:
                out.append((self._done, self._take()))
        self._pending, self._pending_tick = payload, next_tick(h, self.grids)
        return out

    def _upcoming(self) -> int:
        """The next tick to complete."""
        if self._pending is not None:
            return self._pending_tick
        return next_tick(self._done + 1, self.grids)

    def _take(self):
        payload, self._pending = self._pending, None
        if payload is None:
            self.heartbeats += 1
        else:
            self.sent += 1
        return payload

    def deadline(self, grace_ns: int) -> int:
        """When :meth:`due` next has something to send (sensor clock) [ns]."""
        return self._upcoming() + grace_ns

    def due(self, now_ns: int, grace_ns: int) -> list:
        """What to send now that the clock reads ``now_ns``: the pending state, or a
        heartbeat, completing the last tick at or before ``now_ns - grace_ns``."""
        if now_ns < self.deadline(grace_ns):
            return []
        self._done = prev_tick(now_ns - grace_ns + 1, self.grids)
        if self._last_h is None:
            return []  # no state yet: nothing to answer with, so no heartbeat either
        return [(self._done, self._take())]

    def set_grids(self, grids: dict) -> None:
        """The consumer declared or withdrew a grid (the pending state stays pending)."""
        self.grids = grids
        if self._pending is not None:
            self._pending_tick = next_tick(self._last_h, grids)


@dataclass
class _Stream:
    thinner: Thinner
    publisher: object
    tokens: set = field(default_factory=set)


class ThinStreams:
    """(Sensor side) The thinned streams of an agent's own sensors: one per (sensor,
    consumer), opened by the consumer's first demand token and closed with its last.

    Not thread-safe: the agent calls it holding its lock.

    Parameters
    ----------
    realm : str
    open_publisher : callable
        ``open_publisher(key)``: a publisher (``put(payload, attachment=...)``,
        ``undeclare()``) on a stream's key.
    grace_of : callable
        ``grace_of(edge)``: how long after a tick a state made before it may still be offered
        for that sensor [ns].
    progress_of : callable, optional
        ``progress_of(edge)``: the sensor clock time [ns] up to which every state of that
        sensor has been offered, or ``None`` (the clock itself: states are stamped when
        they are made). A tick after it is not completed, whatever the clock reads (a
        recording's player that runs late: its states come, stamped before the tick,
        after ``grace``).
    """

    def __init__(self, realm: str, open_publisher, grace_of, progress_of=None):
        self.realm = realm
        self._open = open_publisher
        self._grace_of = grace_of
        self._progress_of = progress_of or (lambda edge: None)
        self.streams: dict[str, dict[str, _Stream]] = {}
        self.next_due = 0  # no stream has a tick due before this [ns]

    def declare(self, key: str, edge: str, consumer: str, grid: Grid, now_ns: int) -> str:
        """A demand token appeared; returns ``""`` or the reason it was refused. A new
        stream's first tick is the first after the sensor's progress (the states a late
        player has still to offer answer the ticks they were made before)."""
        streams = self.streams.setdefault(edge, {})
        st = streams.get(consumer)
        if st is None:
            if len(streams) >= MAX_STREAMS_PER_EDGE:
                return "too many thinned streams"
            publisher = self._open(thin_key(self.realm, edge, consumer))
            done = self._progress_of(edge)
            start = now_ns if done is None else min(now_ns, done)
            st = streams[consumer] = _Stream(Thinner({grid: 0}, start), publisher)
        if key not in st.tokens:
            st.tokens.add(key)
            grids = dict(st.thinner.grids)
            grids[grid] = grids.get(grid, 0) + 1
            st.thinner.set_grids(grids)
            self.next_due = 0
        return ""

    def withdraw(self, key: str) -> None:
        """A demand token went away; a stream without tokens ends (a consumer that left or
        died costs nothing)."""
        for streams in self.streams.values():
            for consumer, st in list(streams.items()):
                if key not in st.tokens:
                    continue
                st.tokens.discard(key)
                grid = parse_demand(key, self.realm)[2]
                grids = dict(st.thinner.grids)
                grids[grid] -= 1
                if grids[grid] <= 0:
                    del grids[grid]
                if grids:
                    st.thinner.set_grids(grids)
                else:
                    del streams[consumer]
                    st.publisher.undeclare()
                return

    def offer(self, edge: str, h_ns: int, payload: bytes, now_ns: int) -> None:
        """A new state of an own sensor's filter (made at ``h_ns``), for each of its streams;
        then whatever ticks are due on any stream go too (the caller, holding the lock
        anyway, does the timer's work on the spot)."""
        streams = self.streams.get(edge)
        if not streams:
            return
        for st in streams.values():
            _send(st, st.thinner.offer(h_ns, payload))
        if now_ns >= self.next_due:
            self.flush(now_ns)

    def flush(self, now_ns: int, wall_ns: int | None = None) -> None:
        """Complete every stream's ticks that are due by ``now_ns`` (the scheduler's time of
        this event), but none after its sensor's progress; remember the soonest next
        deadline (offers only move deadlines later, so it stays a lower bound). ``wall_ns``
        (default ``now_ns``): the clock's reading, from which an idle stream's next look and
        a tick held back by a late sensor (looked at again in 1 ms, unless the sensor's next
        state completes it first) are counted; a deadline between ``now_ns`` and it is due
        at once, so a timer that runs late walks its ticks in order."""
        wall = now_ns if wall_ns is None else max(wall_ns, now_ns)
        soonest = wall + _IDLE_NS
        for edge, streams in self.streams.items():
            grace = self._grace_of(edge)
            clock = now_ns
            done = self._progress_of(edge)
            if done is not None:
                clock = min(now_ns, done + grace)
            for st in streams.values():
                _send(st, st.thinner.due(clock, grace))
                deadline = st.thinner.deadline(grace)
                soonest = min(soonest, deadline if deadline > now_ns else wall + _HELD_NS)
        self.next_due = soonest

    def status(self) -> dict:
        return {
            e: {
                c: {
                    "grids": sorted([g.period_ns, g.phase_ns] for g in st.thinner.grids),
                    "sent": st.thinner.sent,
                    "heartbeats": st.thinner.heartbeats,
                    "late": st.thinner.late,
                }
                for c, st in sorted(ss.items())
            }
            for e, ss in sorted(self.streams.items())
            if ss
        }


def _send(st: _Stream, messages: list) -> None:
    for tick, payload in messages:
        st.publisher.put(
            b"" if payload is None else payload,
            attachment=tick.to_bytes(8, "little", signed=True),
        )
