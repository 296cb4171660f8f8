"""What an agent knows of the others: live edges, fragments, statics and clock offsets.

Discovery follows the liveliness tokens ``trackflow/<realm>/alive/<agent>/<edge>``: a new
token makes the agent fetch the owner's fragment (``fragment/<agent>``) and measure its clock
(``clock/<agent>``, round trips); a token that disappears takes its edge out of the live set.
Each change of the live set is handed to ``on_change(reason, t_event_ns, departed)`` (the
agent re-plans), from the discovery thread; the changes that arrive together (the tokens of
an agent that left or joined) are handed over once, when the burst has been taken in, with
every reason and the time of the first. ``departed`` is the set of sensors that left when
the burst held only departures (a plan that uses none of them cannot change), else ``None``.

After the first measurement (five round trips when its fragment comes), an agent's clock is
checked again only while this agent needs it (``clocks_needed``: the agents whose sensors it
receives), every :data:`CLOCK_PERIOD_S`, and less often while the offset holds still: the
period doubles, up to :data:`CLOCK_PERIOD_MAX_S`, after each check that moved the estimate by
no more than three sigma (or 0.1 ms), and is back at :data:`CLOCK_PERIOD_S` after one that
did. A realm of N agents no longer makes N x (N - 1) clock checks every 2 s.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from ..graph import Edge, SpatialRelationshipGraph
from ..timesync import RoundTripOffset
from .fragment import first_fragment, fragment_stale

__all__ = ["Discovery", "RemoteAgent", "alive_token", "realm_key"]

_REASONS = 8  # the reasons of one burst of changes named in its re-plan's event
#: the period of an agent's clock checks [s] (the clock thread's round), and the longest it
#: backs off to while the offset holds still (the estimate is the best round trip of the
#: last 32: at 8 s they span four minutes, over which synchronised hosts drift well under a
#: tenth of a millisecond)
CLOCK_PERIOD_S = 2.0
CLOCK_PERIOD_MAX_S = 8.0
_STILL_NS = 100_000  # a change of the estimate below this [ns] (or three sigma) is "still"


def realm_key(realm: str, *parts: str) -> str:
    """``trackflow/<realm>/<parts...>``: a key of the realm's key space."""
    return "/".join(("trackflow", realm, *parts))


def alive_token(sample) -> tuple[str, str, bool] | None:
    """``(agent, edge, gone)`` of a liveliness sample on ``trackflow/<realm>/alive/<agent>/<edge>``
    (``gone``: the token was undeclared, or its agent's session ended); ``None`` for another
    key."""
    import zenoh

    parts = str(sample.key_expr).split("/")
    if len(parts) != 5:
        return None
    return parts[3], parts[4], sample.kind == zenoh.SampleKind.DELETE


@dataclass
class RemoteAgent:
    """What the agent knows about another agent."""

    name: str
    edges: dict[str, Edge] = field(default_factory=dict)
    frames: list[str] = field(default_factory=list)
    clock: RoundTripOffset = field(default_factory=RoundTripOffset)
    #: its live sensors' liveness windows [s] (the ``stale_ms`` of their inputs)
    stale_s: dict[str, float] = field(default_factory=dict)
    #: the period of its clock checks [s] and when the next is due (``time.monotonic``)
    clock_period_s: float = CLOCK_PERIOD_S
    clock_due_s: float = 0.0

    def clock_checked(self, before_ns: int | None, now_s: float) -> None:
        """Set the next check's time after one that moved the offset from ``before_ns``:
        later (twice the period, at most :data:`CLOCK_PERIOD_MAX_S`) if it held still,
        at :data:`CLOCK_PERIOD_S` if it moved or was not known."""
        c = self.clock
        still = (
            before_ns is not None and c.known
            and abs(c.offset_ns - before_ns) <= max(_STILL_NS, 3e9 * c.sigma_s)
        )  # fmt: skip
        self.clock_period_s = (
            min(2.0 * self.clock_period_s, CLOCK_PERIOD_MAX_S) if still else CLOCK_PERIOD_S
        )
        self.clock_due_s = now_s + self.clock_period_s


class Discovery:
    """The live set of other agents' edges, kept by one thread (module docstring).

    Parameters
    ----------
    name, realm : str
        This agent's name and realm.
    lock : threading.RLock
        The agent's lock: the live set changes under it.
    rejections : wire.Rejections
        Where malformed keys and fragments are counted.
    on_change : callable
        ``on_change(reason, t_event_ns, departed)``: the live set changed (or a re-plan was
        asked); ``departed``: the sensors that left, if nothing else changed, else ``None``.
    on_clock : callable
        Called after every round of clock measurements (every :data:`CLOCK_PERIOD_S`).
    clocks_needed : callable, optional
        ``clocks_needed() -> set`` of the agents whose clocks this agent uses (whose sensors
        it receives); only theirs are checked after the first measurement. Default: every
        agent with a live sensor.
    """

    def __init__(self, name, realm, lock, rejections, on_change, on_clock, clocks_needed=None):
        self.name, self.realm = name, realm
        self.lock = lock
        self.rejections = rejections
        self.on_change: Callable[[str, int], None] = on_change
        self.on_clock: Callable[[], None] = on_clock
        self.clocks_needed: Callable[[], set[str]] | None = clocks_needed
        self.remotes: dict[str, RemoteAgent] = {}
        self.live: dict[str, str] = {}  # live remote measured edge -> agent
        self.statics: dict[str, Edge] = {}  # remote static edges (kept after their agent left)
        self._seen: dict[str, set[str]] = {}  # agent -> edges whose tokens are alive
        self._work: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.session = None  # (set by start: the Zenoh session and this agent's clock)
        self.now_ns: Callable[[], int] = time.time_ns

    # -- life cycle -----------------------------------------------------------------------------
    def start(self, session, now_ns: Callable[[], int]) -> None:
        """Start the discovery and clock threads and follow the realm's tokens."""
        self.session, self.now_ns = session, now_ns
        for target in (self._worker, self._clock_loop):
            th = threading.Thread(target=target, name=f"{self.name}-{target.__name__}", daemon=True)
            th.start()
            self._threads.append(th)
        self._work.put(("replan", "start", time.perf_counter_ns()))
        self._sub = session.liveliness().declare_subscriber(
            realm_key(self.realm, "alive", "**"), self._on_liveliness, history=True
        )

    def stop(self) -> None:
        self._stop.set()
        self._work.put(("stop",))
        for th in self._threads:
            th.join(timeout=2.0)

    # -- queries --------------------------------------------------------------------------------
    def agent_of(self, edge: str) -> RemoteAgent | None:
        """The agent currently providing the live remote sensor ``edge`` (or ``None``)."""
        agent = self.live.get(edge)
        return self.remotes.get(agent) if agent is not None else None

    def stale_s(self, edge: str) -> float | None:
        """The liveness window [s] the agent providing the live sensor ``edge`` advertises
        (``None``: not advertised, or not a live remote sensor)."""
        rem = self.agent_of(edge)
        return None if rem is None else rem.stale_s.get(edge)

    def union_graph(self, own: SpatialRelationshipGraph) -> SpatialRelationshipGraph:
        """Own edges, live remote sensors and every static edge learned so far."""
        g = SpatialRelationshipGraph()
        for f in own.frames:
            g.add_frame(f)
        names = set()
        for e in own.edges:
            g.add_edge(e)
            names.add(e.name)
        for e in self.statics.values():
            if e.name not in names:
                g.add_edge(e)
                names.add(e.name)
        for edge, agent in sorted(self.live.items()):
            e = self.remotes[agent].edges[edge]
            if e.name not in names:
                g.add_edge(e)
                names.add(e.name)
        for rem in self.remotes.values():
            for f in rem.frames:
                g.add_frame(f)
        return g

    def clocks(self) -> dict:
        """Measured clock offsets of the other agents, ``host - remote``
        (:mod:`trackflow.timesync`), JSON-able."""
        return {
            n: {
                "offset_ms": r.clock.offset_ns * 1e-6,
                "sigma_ms": r.clock.sigma_s * 1e3,
                "period_s": r.clock_period_s,
            }
            for n, r in self.remotes.items()
            if r.clock.known
        }

    # -- events ---------------------------------------------------------------------------------
    def _on_liveliness(self, sample) -> None:
        token = alive_token(sample)
        if token is None:
            self.rejections.add("malformed liveliness key")
            return
        agent, edge, gone = token
        if agent == self.name:
            return
        self._work.put(("delete" if gone else "put", agent, edge, time.perf_counter_ns()))

    def _fetch_fragment(self, agent: str) -> RemoteAgent | None:
        replies = self.session.get(realm_key(self.realm, "fragment", agent), timeout=2.0)
        got = first_fragment(replies, self.rejections)
        if got is None:
            return None
        frames, edges, data = got
        rem = self.remotes.get(agent) or RemoteAgent(agent)
        rem.edges = {e.name: e for e in edges}
        rem.stale_s = fragment_stale(data)
        rem.frames = frames
        with self.lock:
            self.remotes[agent] = rem
        self._ping(rem, 5)
        return rem

    def _ping(self, rem: RemoteAgent, n: int) -> None:
        for _ in range(n):
            t0 = self.now_ns()
            replies = list(self.session.get(realm_key(self.realm, "clock", rem.name), timeout=1.0))
            t1 = self.now_ns()
            for reply in replies:
                if reply.ok is not None and len(reply.ok.payload.to_bytes()) == 8:
                    remote = int.from_bytes(reply.ok.payload.to_bytes(), "little", signed=True)
                    rem.clock.add_round_trip(t0, remote, t1)

    def _worker(self) -> None:
        """Discovery events, one at a time: fetch fragments, update the live set, re-plan.

        A token whose fragment cannot be fetched yet (the agent is still starting, or busy)
        is tried again every 0.5 s for 30 s, then counted as a rejection."""
        pending: list[tuple] = []  # (reason, t_event_ns, departed sensor) not handed over yet
        while True:
            item = self._work.get()
            if item[0] == "stop" or self._stop.is_set():
                return
            if item[0] == "replan":
                change = item[1], item[2], None
            elif item[0] == "delete":
                change = self._gone(*item[1:])
            else:
                change = self._appeared(*item[1:])
            if change is not None:
                pending.append(change)
            if pending and self._work.empty():  # once after a burst
                reasons = list(dict.fromkeys(r for r, _, _ in pending))
                more = f"; and {len(reasons) - _REASONS} more" if len(reasons) > _REASONS else ""
                gone = [e for _, _, e in pending]
                departed = None if None in gone else frozenset(gone)
                self.on_change("; ".join(reasons[:_REASONS]) + more,
                               min(t for _, t, _ in pending), departed)  # fmt: skip
                pending = []

    def _gone(self, agent: str, edge: str, t_event: int) -> tuple[str, int, str] | None:
        """The change a deleted token makes (``None``: none): its reason, time and sensor."""
        self._seen.get(agent, set()).discard(edge)
        with self.lock:  # status() reads these from other threads
            gone = self.live.get(edge) == agent
            if gone:
                del self.live[edge]
        return (f"sensor {edge} of agent {agent} left", t_event, edge) if gone else None

    def _appeared(self, agent: str, edge: str, t_event: int, *attempt) -> tuple | None:
        """The change a new token makes (``None``: none yet: its fragment is fetched again
        in 0.5 s while its agent starts)."""
        import zenoh

        if attempt and edge not in self._seen.get(agent, set()):
            return None  # the token went away while we waited
        self._seen.setdefault(agent, set()).add(edge)
        rem = self.remotes.get(agent)
        if rem is None or edge not in rem.edges:
            try:
                rem = self._fetch_fragment(agent)
            except zenoh.ZError:  # the other agent went away meanwhile
                rem = None
            if rem is None or edge not in rem.edges:
                n = attempt[0] if attempt else 0
                if n >= 60:
                    self.rejections.add("token without fragment edge")
                else:
                    retry = ("put", agent, edge, t_event, n + 1)
                    threading.Timer(0.5, self._work.put, args=(retry,)).start()
                return None
        with self.lock:
            for name in sorted(self._seen[agent] & set(rem.edges)):
                e = rem.edges[name]
                if e.kind == "static":
                    self.statics[name] = e
                else:
                    self.live[name] = agent
        return f"edge {edge} of agent {agent} appeared", t_event, None

    def _clock_loop(self) -> None:
        while not self._stop.wait(CLOCK_PERIOD_S):
            self.check_clocks(time.monotonic())
            self.on_clock()

    def check_clocks(self, now_s: float) -> int:
        """One round of the clock thread: check the clocks that are due of the agents this
        agent needs (module docstring); returns how many were checked."""
        import zenoh

        needed = None if self.clocks_needed is None else self.clocks_needed()
        with self.lock:
            due = [
                r for r in self.remotes.values()
                if r.name in self.live.values() and (needed is None or r.name in needed)
                and now_s >= r.clock_due_s - 0.05 * CLOCK_PERIOD_S  # (the thread's jitter)
            ]  # fmt: skip
        for rem in due:
            before = rem.clock.offset_ns if rem.clock.known else None
            try:
                self._ping(rem, 1)
            except zenoh.ZError:  # the remote may be gone; next round
                continue
            rem.clock_checked(before, now_s)
        return len(due)
