"""A trackflow agent: one process's part of a distributed tracking setup on Eclipse Zenoh.

Key space (``<realm>`` and names: letters, digits, ``_``, ``-``)::

    trackflow/<realm>/alive/<agent>/<edge>   liveliness token per edge the agent provides
    trackflow/<realm>/fragment/<agent>       queryable: the agent's SRG fragment (JSON)
    trackflow/<realm>/clock/<agent>          queryable: the agent's clock reading (int64 ns)
    trackflow/<realm>/edge/<edge>            pub/sub: a sensor filter's states (docs/wire.md, v2)
    trackflow/<realm>/demand/<edge>/<consumer>/<period_ns>/<phase_ns>
                                             liveliness token: a consumer's tick grid (thin)
    trackflow/<realm>/thin/<edge>/<consumer> pub/sub: the states that grid needs (thinning.py)
    trackflow/<realm>/get/<edge>?t=<ns>      queryable: the sensor filter's get(t) (wire)
    trackflow/<realm>/query/<query>?t=<ns>   queryable: a pull query's get(t) (wire)
    trackflow/<realm>/result/<query>         pub/sub: a push query's results (wire)
    trackflow/<realm>/status/<agent>         queryable: plans, re-plans and counters (JSON)

Every agent assembles the union graph of the live fragments (discovered through the tokens,
fetched from the fragment queryables) and plans its own queries with
:func:`trackflow.dataflow.plan_query`. Each sensor's Kalman filter runs where the sensor is
(answering ``get/<edge>``) and publishes its state after every measurement; a consumer's plan
uses another agent's sensor through a replica of that filter fed with those states
(:mod:`trackflow.distributed.replica`), and does the inversion, chaining, time alignment and
fusion itself. When a token disappears the affected queries re-plan at once (or report "no
path" with the reason).
"""

from __future__ import annotations

import collections
import gc
import heapq
import itertools
import json
import queue
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from ..dataflow import (
    Component,
    KalmanFilter,
    Measurement,
    Network,
    PullSink,
    Recorder,
    RecordingPlayer,
    plan_query,
)
from ..errors import ServiceError
from ..graph import Edge, SpatialRelationshipGraph
from ..math import UncertainPose
from ..optional import require
from . import wire
from .clock import ClockOffset, time_error_covariance, twist_between
from .config import AgentConfig, zenoh_config
from .fragment import fragment_json, parse_fragment
from .replica import RemoteFilter, RemoteGet, StatePublisher, warm_up
from .thinning import Grid, ThinStreams, demand_key, parse_demand, thin_key

__all__ = ["Agent", "QueryState", "RemoteSource", "set_agent_gc", "remote_get", "run_agent"]

_SENSOR, _TICK = 0, 1
_GC_THRESHOLDS = (1000, 20, 100)  # set_agent_gc: young collections stay short, full ones rare
_REDECLARE_NS = 50_000  # a thinned input's demand follows the clock offset to within 50 us
_FOREVER_NS = 2**62  # (progress of a recording played to its end)


def _key(realm: str, *parts: str) -> str:
    return "/".join(("trackflow", realm, *parts))


class RemoteSource(Component):
    """The source node of a measured edge fed from outside the network: a live sensor of this
    agent (:meth:`Agent.feed`), or another agent's sensor (whose states go straight to its
    :class:`~trackflow.distributed.replica.RemoteFilter`; this node then only stands for the
    sensor in the plan)."""

    push_out = True
    kind = "remote source"

    def deliver(self, m: Measurement) -> None:
        self.stats.events_in += 1
        self.emit(m)


@dataclass
class QueryState:
    """The current plan of one of the agent's queries and its history of re-plans."""

    name: str
    state: str = "waiting"  # "running", "no path"
    reason: str = ""
    paths: list[str] = field(default_factory=list)
    sink: object = None
    sampler: object = None
    generation: int = 0
    events: list[dict] = field(default_factory=list)
    published: int = 0
    last: Measurement | None = None
    inputs: frozenset = frozenset()  # remote sensors of the plan (thin: ticks wait for them)


@dataclass
class _ThinInput:
    """(Consumer side) a remote sensor received thinned: its demand tokens and coverage."""

    periods: frozenset
    offset_ns: int
    tokens: list
    subscriber: object
    covered_ns: int | None = None


@dataclass
class _Remote:
    """What the agent knows about another agent."""

    name: str
    edges: dict[str, Edge] = field(default_factory=dict)
    frames: list[str] = field(default_factory=list)
    clock: ClockOffset = field(default_factory=ClockOffset)


class Agent:
    """One agent (see the module docstring). Use as a context manager or call :meth:`start`
    and :meth:`close`.

    Parameters
    ----------
    config : AgentConfig
        Name, realm, Zenoh configuration and the setup fragment (own sensors, statics, queries).
    """

    def __init__(self, config: AgentConfig):
        self.cfg = config
        self.name = config.name
        self.realm = config.realm
        self.setup = config.setup
        self.rejections = wire.Rejections()
        self.lost_messages = 0
        self.received = [0, 0, 0]  # messages, bytes, heartbeats of remote sensors' streams
        self._tick_waits: collections.deque = collections.deque(maxlen=4096)  # tick -> run [ns]
        self._thin_arrivals: collections.deque = collections.deque(maxlen=4096)  # tick -> here
        self.late_events = 0
        self.missed_ticks = 0
        self.skipped_samples = 0
        self._publishers: dict[str, StatePublisher] = {}
        self._own: set[str] = set()
        self.queries = {n: QueryState(n) for n in self.setup.queries}
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._work: queue.Queue = queue.Queue()
        self._clock_offset_ns = int(round(config.clock_offset_ms * 1e6))
        self._reorder_ns = int(round(config.reorder_ms * 1e6))
        self._heap: list = []
        self._heap_cv = threading.Condition(self._lock)
        self._seq = itertools.count()
        self._remotes: dict[str, _Remote] = {}
        self._live: dict[str, str] = {}  # live remote measured edge -> agent
        self._seen: dict[str, set[str]] = {}  # agent -> edges whose tokens are alive
        self._statics: dict[str, Edge] = {}  # remote static edges (kept after their agent left)
        self._sources: dict[str, Component] = {}
        self._filters: dict[str, KalmanFilter] = {}
        self._last_seq: dict[str, int] = {}
        self._subs: dict[str, object] = {}
        self._thin_in: dict[str, _ThinInput] = {}  # remote edge -> its thinned subscription
        self._covered: dict[str, int] = {}  # thin mode: raw remote edge -> covered up to [ns]
        self._thin_cv = threading.Condition(self._lock)
        self._played: dict[str, int] = {}  # own recording -> every sample arriving by it played
        self._grace_ns = int(round(config.thin_grace_ms * 1e6))
        self._thin = ThinStreams(  # (sensor side) consumers' thinned streams of own sensors
            config.realm,
            lambda key: self.session.declare_publisher(key, express=False),  # batched
            self._grace,
            self._played.get,
        )
        self._players: list[tuple[RecordingPlayer, threading.Thread]] = []
        self._threads: list[threading.Thread] = []
        self.net = Network()
        self.session = None

    # -- clock ----------------------------------------------------------------------------------
    def now_ns(self) -> int:
        """This agent's clock [ns]: Unix time (plus the configured test offset)."""
        return time.time_ns() + self._clock_offset_ns

    # -- life cycle -----------------------------------------------------------------------------
    def start(self) -> Agent:
        zenoh = require("zenoh", extra="distributed", feature="trackflow agent")

        conf = zenoh_config(self.cfg)
        try:
            self.session = zenoh.open(conf)
        except zenoh.ZError as exc:
            listen = conf.get_json("listen/endpoints")
            raise ServiceError(
                f"agent {self.name!r}: cannot open the Zenoh session (listen {listen}): {exc}"
            ) from None
        s, r = self.session, self.realm
        warm_up()  # compiled kernels are typed, not sized: one model warms them for all
        self._own_sensors()
        self._decl = [
            s.declare_queryable(_key(r, "fragment", self.name), self._on_fragment_query),
            s.declare_queryable(_key(r, "clock", self.name), self._on_clock_query),
            s.declare_queryable(_key(r, "status", self.name), self._on_status_query),
        ]
        self._decl += [  # only what this agent can answer
            s.declare_queryable(_key(r, "query", n), self._on_pull_query)
            for n, q in self.setup.queries.items()
            if q.mode == "pull"
        ]
        self._decl += [s.declare_queryable(_key(r, "get", n), self._on_edge_get) for n in self._own]
        self._tokens = [
            s.liveliness().declare_token(_key(r, "alive", self.name, e.name))
            for e in self.setup.graph.edges
        ]
        self._tokens.append(s.liveliness().declare_token(_key(r, "agent", self.name)))
        self._results = {
            n: s.declare_publisher(_key(r, "result", n))
            for n, q in self.setup.queries.items()
            if q.mode == "push"
        }
        targets = [self._worker, self._pump, self._clock_loop]
        if self._own:
            targets.append(self._thin_loop)
        for target in targets:
            th = threading.Thread(target=target, name=f"{self.name}-{target.__name__}", daemon=True)
            th.start()
            self._threads.append(th)
        self._work.put(("replan", "start", time.perf_counter_ns()))
        self._discovery = s.liveliness().declare_subscriber(
            _key(r, "alive", "**"), self._on_liveliness, history=True
        )
        if self._own:  # consumers' tick grids for thinned streams of the own sensors
            self._demands = s.liveliness().declare_subscriber(
                _key(r, "demand", "**"), self._on_demand, history=True
            )
        for _, th in self._players:
            th.start()
        return self

    def close(self) -> None:
        """Stop every thread and close the Zenoh session (tokens disappear for the others)."""
        self._stop.set()
        with self._heap_cv:
            self._heap_cv.notify_all()
            self._thin_cv.notify_all()
        self._work.put(("stop",))
        for _, th in self._players:
            if th.is_alive():
                th.join(timeout=2.0)
        for th in self._threads:
            th.join(timeout=2.0)
        if self.session is not None:
            self.session.close()
            self.session = None

    def __enter__(self) -> Agent:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def wait(self, timeout_s: float | None = None) -> None:
        """Block until the recordings have played (or ``timeout_s``; forever without
        recordings and timeout)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        for _, th in self._players:
            th.join(None if deadline is None else max(0.0, deadline - time.monotonic()))
        if not self._players:
            self._stop.wait(timeout_s)

    # -- own sensors ----------------------------------------------------------------------------
    def _own_sensors(self) -> None:
        """A source, its Kalman filter (answering get/<edge>) and the publisher of its states
        per own sensor; recordings are played in real time from ``start_ns``."""
        from ..io import read_stream

        for edge in self.setup.graph.edges:
            if edge.kind != "measured":
                continue
            path = self.setup.recordings.get(edge.name)
            if path is not None:
                stream, _ = read_stream(path)
                src = RecordingPlayer.from_stream(
                    edge.name, stream, int(round(edge.latency_s * 1e9)), covariance=edge.covariance
                )
                src = RecordingPlayer(
                    edge.name,
                    src.t_ns + self.cfg.start_ns,
                    src.position,
                    src.quaternion,
                    src.covariance,
                    src.latency_ns,
                )
                th = threading.Thread(target=self._play, args=(src,), daemon=True)
                self._players.append((src, th))
                self._played[edge.name] = _played_before(src.arrivals(), 0)
            else:
                src = RemoteSource(edge.name)
                src.kind = "live source"
            self._sources[edge.name] = src
            kf = self._filters[edge.name] = self._make_filter(edge)
            self._own.add(edge.name)
            pub = self._publishers[edge.name] = StatePublisher(
                f"publish_{edge.name}",
                kf,
                # express: each state leaves at once, not batched with later ones
                self.session.declare_publisher(_key(self.realm, "edge", edge.name), express=True),
            )
            pub.tap = lambda h_ns, buf, name=edge.name: self._offer_thin(name, h_ns, buf)
        with self._lock:
            self._rebuild_base()

    @staticmethod
    def _make_filter(edge: Edge) -> KalmanFilter:
        return KalmanFilter(
            f"kf_{edge.name}",
            edge.motion,
            role="predictor",
            stamp_offset_ns=int(round(edge.stamp_offset_s * 1e9)),
        )

    def _rebuild_base(self) -> Network:
        """A fresh network holding every source with its filter (kept across re-plans, so
        their state survives): own sensors' filters push into their state publishers, other
        agents' sensors are replicas fed by the subscriptions."""
        net = Network()
        for name, src in self._sources.items():
            src.consumers = []
            kf = self._filters[name]
            kf.consumers = []
            net.add(src)
            net.add(kf)
            if isinstance(kf, RemoteFilter):
                continue
            net.connect(src, kf, mode="push")
            pub = self._publishers.get(name)
            if pub is not None:  # states leave before local inference (see StatePublisher)
                pub.consumers = []
                net.add(pub)
                net.connect(kf, pub, mode="push", port=0)
                net.connect(src, pub, mode="push", port=1)
        self.net = net
        return net

    def feed(self, edge: str, t_ns: int, pose: UncertainPose) -> None:
        """Push a live measurement of an own sensor (stamped ``t_ns`` on this agent's clock)."""
        src = self._sources.get(edge)
        if not isinstance(src, RemoteSource):
            raise ValueError(f"agent {self.name!r} has no live sensor {edge!r}")
        with self._lock:
            self.net.clock.now_ns = self.now_ns()
            src.deliver(Measurement(int(t_ns), pose, int(t_ns)))

    def get(self, query: str, t_ns: int) -> Measurement | None:
        """``get(t)`` of one of this agent's pull queries (``None``: no path or no result;
        the status says why)."""
        st = self.queries.get(query)
        if st is None:
            raise ValueError(f"agent {self.name!r} has no query {query!r}")
        with self._lock:
            if not isinstance(st.sink, PullSink):
                return None
            self.net.clock.now_ns = self.now_ns()
            return st.sink.get(int(t_ns))

    def _play(self, player: RecordingPlayer) -> None:
        """Deliver each sample at its arrival time on this agent's clock; samples more than
        0.1 s in the past when the agent starts (a restarted agent) are skipped, counted.
        ``_played`` follows (under the lock, with each sample) how far the recording has
        been played: the thinned streams complete no tick after it (a player that runs
        late holds its ticks back instead of sending states late)."""
        first = self.now_ns() - 100_000_000
        arrivals = player.arrivals()
        with self._lock:
            self._played[player.name] = _played_before(
                arrivals, int(np.searchsorted(arrivals, first))
            )
        for arrival, idx in player.events():
            if arrival < first:
                self.skipped_samples += 1
                continue
            while not self._stop.is_set():
                delay = (arrival - self.now_ns()) * 1e-9
                if delay <= 0:
                    break
                self._stop.wait(min(delay, 0.5))
            if self._stop.is_set():
                return
            with self._lock:
                self.net.clock.now_ns = arrival
                player.deliver(idx)
                self._played[player.name] = _played_before(arrivals, idx + 1)

    # -- thinned streams of own sensors (sensor side) ------------------------------------------
    def _on_demand(self, sample) -> None:
        """A consumer's tick grid for one of this agent's sensors appeared (PUT) or went away
        (DELETE: withdrawn, or the consumer died). Garbage is a counted rejection."""
        import zenoh

        key = str(sample.key_expr)
        if sample.kind == zenoh.SampleKind.DELETE:
            with self._lock:
                self._thin.withdraw(key)
            return
        try:
            edge, consumer, grid = parse_demand(key, self.realm)
        except ValueError as exc:
            self.rejections.add(str(exc))
            return
        if edge not in self._own:
            if edge in self._statics or edge in {e.name for e in self.setup.graph.edges}:
                self.rejections.add("demand for a static edge")
            elif edge not in self._live:  # (also while this agent has not met the owner yet)
                self.rejections.add("demand for unknown edge")
            return  # another agent's sensor: its agent serves it
        with self._lock:
            refused = self._thin.declare(key, edge, consumer, grid, self.now_ns())
            if refused:
                self.rejections.add(refused)
            self._thin_cv.notify()

    def _offer_thin(self, edge: str, h_ns: int, buf: bytes) -> None:
        """(Under the agent's lock, from the state publisher.) A new state of an own sensor."""
        self._thin.offer(edge, h_ns, buf, self.now_ns())

    def _grace(self, edge: str) -> int:
        """How long after a tick a state made before it may still come [ns]: a live sensor's
        states are stamped when the agent takes them (under its lock), so never; a
        recording's player stamps its scheduled arrival, and its thread may run late."""
        return self._grace_ns if isinstance(self._sources.get(edge), RecordingPlayer) else 0

    def _thin_loop(self) -> None:
        """Completes the ticks of the thinned streams when no state did it before: sends
        each stream's pending state (or a heartbeat) once the tick (plus the grace of
        recordings) has passed."""
        with self._thin_cv:
            while not self._stop.is_set():
                now = self.now_ns()
                if now < self._thin.next_due:
                    self._thin_cv.wait(min((self._thin.next_due - now) * 1e-9, 0.05))
                    continue
                self._thin.flush(now)

    # -- discovery ------------------------------------------------------------------------------
    def _on_liveliness(self, sample) -> None:
        import zenoh

        parts = str(sample.key_expr).split("/")
        if len(parts) != 5:
            self.rejections.add("malformed liveliness key")
            return
        agent, edge = parts[3], parts[4]
        if agent == self.name:
            return
        if sample.kind == zenoh.SampleKind.DELETE:
            self._work.put(("delete", agent, edge, time.perf_counter_ns()))
        else:
            self._work.put(("put", agent, edge, time.perf_counter_ns()))

    def _fetch_fragment(self, agent: str) -> _Remote | None:
        replies = self.session.get(_key(self.realm, "fragment", agent), timeout=2.0)
        for reply in replies:
            if reply.ok is None:
                continue
            try:
                name, frames, edges = parse_fragment(reply.ok.payload.to_bytes())
            except ValueError:
                self.rejections.add("malformed fragment")
                continue
            rem = self._remotes.get(agent) or _Remote(agent)
            rem.edges = {e.name: e for e in edges}
            rem.frames = frames
            with self._lock:
                self._remotes[agent] = rem
            self._ping(rem, 5)
            return rem
        return None

    def _ping(self, rem: _Remote, n: int) -> None:
        for _ in range(n):
            t0 = self.now_ns()
            replies = list(self.session.get(_key(self.realm, "clock", rem.name), timeout=1.0))
            t1 = self.now_ns()
            for reply in replies:
                if reply.ok is not None and len(reply.ok.payload.to_bytes()) == 8:
                    remote = int.from_bytes(reply.ok.payload.to_bytes(), "little", signed=True)
                    rem.clock.add_round_trip(t0, remote, t1)

    def _worker(self) -> None:
        """Discovery events, one at a time: fetch fragments, update the live set, re-plan.

        A token whose fragment cannot be fetched yet (the agent is still starting, or busy)
        is tried again every 0.5 s for 30 s, then counted as a rejection."""
        import zenoh

        while True:
            item = self._work.get()
            if item[0] == "stop" or self._stop.is_set():
                return
            kind = item[0]
            if kind == "replan":
                self._replan(item[1], item[2])
                continue
            _, agent, edge, t_event, *attempt = item
            if kind == "delete":
                self._seen.get(agent, set()).discard(edge)
                with self._lock:  # status() reads these from other threads
                    gone = self._live.get(edge) == agent
                    if gone:
                        del self._live[edge]
                if gone:
                    self._replan(f"sensor {edge} of agent {agent} left", t_event)
                continue
            if attempt and edge not in self._seen.get(agent, set()):
                continue  # the token went away while we waited
            self._seen.setdefault(agent, set()).add(edge)
            rem = self._remotes.get(agent)
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
                    continue
            with self._lock:
                for name in sorted(self._seen[agent] & set(rem.edges)):
                    e = rem.edges[name]
                    if e.kind == "static":
                        self._statics[name] = e
                    else:
                        self._live[name] = agent
            if self._work.empty():  # re-plan once after a burst of appearances
                self._replan(f"edge {edge} of agent {agent} appeared", t_event)

    def _clock_loop(self) -> None:
        import zenoh

        while not self._stop.wait(2.0):
            with self._lock:
                remotes = [r for r in self._remotes.values() if r.name in self._live.values()]
            for rem in remotes:
                try:
                    self._ping(rem, 1)
                except zenoh.ZError:  # the remote may be gone; next round
                    continue
            with self._lock:  # thinned inputs follow the clock offset's estimate
                for edge, inp in self._thin_in.items():
                    offset = self._offset_ns(edge)
                    if abs(offset - inp.offset_ns) > _REDECLARE_NS:
                        try:
                            self._declare_demands(edge, inp, offset)
                        except zenoh.ZError:
                            continue

    # -- planning -------------------------------------------------------------------------------
    def union_graph(self) -> SpatialRelationshipGraph:
        """Own edges, live remote sensors and every static edge learned so far."""
        g = SpatialRelationshipGraph()
        for f in self.setup.graph.frames:
            g.add_frame(f)
        names = set()
        for e in self.setup.graph.edges:
            g.add_edge(e)
            names.add(e.name)
        for e in self._statics.values():
            if e.name not in names:
                g.add_edge(e)
                names.add(e.name)
        for edge, agent in sorted(self._live.items()):
            e = self._remotes[agent].edges[edge]
            if e.name not in names:
                g.add_edge(e)
                names.add(e.name)
        for rem in self._remotes.values():
            for f in rem.frames:
                g.add_frame(f)
        return g

    def _replan(self, reason: str, t_event_ns: int) -> None:
        """Plan every query on the current union graph; rebuild the dataflow if a plan
        changed. Remote sensors are subscribed when a plan first uses them (a sensor no
        query uses never crosses the network) and stay subscribed, so a later switch back
        finds their replicas current."""
        with self._lock:
            graph = self.union_graph()
            changed, plans, used, pushed, new_events = False, {}, set(), set(), []
            for name, q in self.setup.queries.items():
                st = self.queries[name]
                try:
                    plan = plan_query(graph, q)
                except ValueError as exc:
                    if st.state != "no path" or st.reason != str(exc):
                        st.state, st.reason, st.paths = "no path", str(exc), []
                        st.sink = st.sampler = None
                        changed = True
                        st.events.append(self._event(reason, t_event_ns, st))
                    continue
                plans[name] = plan
                sensors = {s for p in plan.paths for s in p.sensors}
                used |= sensors
                if q.mode == "push":
                    pushed |= sensors
                    st.inputs = frozenset(sensors - self._own)
                paths = [str(p) for p in plan.paths]
                if st.state == "running" and paths == st.paths:
                    continue
                st.state, st.reason, st.paths = "running", "", paths
                new_events.append(self._event(reason, t_event_ns, st))
                st.events.append(new_events[-1])
                changed = True
            if not changed:
                return
            thin = self._thin_periods(plans) if self.cfg.thin else {}
            for edge in sorted(used - self._own):
                if edge in thin:
                    self._subscribe_thin(graph.edge(edge), thin[edge])
                elif self.cfg.pull_via == "replica" or edge in pushed:
                    self._subscribe(graph.edge(edge))
                elif edge not in self._sources:
                    self._ask_per_request(graph.edge(edge))
            net = self._rebuild_base()
            for name, plan in plans.items():
                st = self.queries[name]
                st.generation += 1
                callback = self._result_callback(name) if plan.query.mode == "push" else None
                _, st.sink = plan.build(
                    self._sources,
                    network=net,
                    prefix=f"{name}_g{st.generation}_",
                    callback=callback,
                )
                st.sampler = net.components.get(f"{name}_g{st.generation}_sampler")
            for event in new_events:  # the time the new plans took effect
                event["replan_ms"] = (time.perf_counter_ns() - t_event_ns) * 1e-6

    @staticmethod
    def _event(reason: str, t_event_ns: int, st: QueryState) -> dict:
        return {
            "reason": reason,
            "state": st.state,
            "detail": st.reason,
            "paths": list(st.paths),
            "replan_ms": (time.perf_counter_ns() - t_event_ns) * 1e-6,
        }

    def _replica(self, edge: Edge) -> None:
        if not isinstance(self._filters.get(edge.name), RemoteFilter):
            self._sources[edge.name] = RemoteSource(edge.name)
            self._filters[edge.name] = RemoteFilter(
                f"kf_{edge.name}",
                edge.motion,
                stamp_offset_ns=int(round(edge.stamp_offset_s * 1e9)),
            )

    def _subscribe(self, edge: Edge) -> None:
        """A replica of a remote sensor's filter, fed by a subscription to its states (also
        replacing a per-request node once a push query needs the sensor, or a thinned
        subscription once a query needs every state)."""
        if edge.name in self._subs:
            return
        self._replica(edge)
        inp = self._thin_in.pop(edge.name, None)
        if inp is not None:
            for token in inp.tokens:
                token.undeclare()
            inp.subscriber.undeclare()
        self._subs[edge.name] = self.session.declare_subscriber(
            _key(self.realm, "edge", edge.name),
            lambda sample, name=edge.name: self._on_state(name, sample),
        )

    def _thin_periods(self, plans: dict) -> dict[str, frozenset]:
        """(``thin: true``) The remote sensors that may be received thinned, with the tick
        periods [ns] of the push queries using them: not those a pull query reads from a
        replica, nor those of a push query answering in the past (``time_offset_ms < 0``
        interpolates between states, so it needs them all)."""
        periods: dict[str, set] = {}
        raw: set[str] = set()
        for plan in plans.values():
            q = plan.query
            sensors = {s for p in plan.paths for s in p.sensors} - self._own
            if q.mode == "push" and q.time_offset_s >= 0:
                for e in sensors:
                    periods.setdefault(e, set()).add(int(round(1e9 / q.rate_hz)))
            elif q.mode == "push" or self.cfg.pull_via == "replica":
                raw |= sensors
        return {e: frozenset(p) for e, p in periods.items() if e not in raw}

    def _offset_ns(self, edge: str) -> int:
        """The clock offset (remote minus this agent) of a live remote sensor's agent [ns]."""
        rem = self._remotes.get(self._live.get(edge, ""))
        if rem is None or self.cfg.clock_sync != "estimate" or not rem.clock.known:
            return 0
        return rem.clock.offset_ns

    def _subscribe_thin(self, edge: Edge, periods: frozenset) -> None:
        """A replica fed by a thinned stream: one demand token per tick period (the grid
        mapped onto the sensor agent's clock) and a subscription to the stream."""
        if edge.name in self._subs:
            return  # every state comes already
        self._replica(edge)
        inp = self._thin_in.get(edge.name)
        if inp is not None and inp.periods == periods:
            return
        if inp is None:
            sub = self.session.declare_subscriber(
                thin_key(self.realm, edge.name, self.name),
                lambda sample, name=edge.name: self._on_thin(name, sample),
            )
            inp = self._thin_in[edge.name] = _ThinInput(periods, 0, [], sub)
        inp.periods = periods
        self._declare_demands(edge.name, inp, self._offset_ns(edge.name))

    def _declare_demands(self, edge: str, inp: _ThinInput, offset_ns: int) -> None:
        """(Re)declare the demand tokens of a thinned input: the new ones first, so the
        sensor's agent keeps the stream while the grid moves."""
        old = inp.tokens
        inp.tokens = [
            self.session.liveliness().declare_token(
                demand_key(self.realm, edge, self.name, Grid(p, offset_ns % p))
            )
            for p in sorted(inp.periods)
        ]
        inp.offset_ns = offset_ns
        for token in old:
            token.undeclare()

    def _ask_per_request(self, edge: Edge) -> None:
        """``pull_via: get``: a node asking the sensor's agent ``get/<edge>?t=`` per request."""
        self._sources[edge.name] = RemoteSource(edge.name)
        self._filters[edge.name] = RemoteGet(
            f"kf_{edge.name}",
            edge.motion,
            lambda t_ns, name=edge.name: self._fetch(name, t_ns),
            stamp_offset_ns=int(round(edge.stamp_offset_s * 1e9)),
        )

    def _fetch(self, edge: str, t_ns: int) -> Measurement | None:
        """The remote sensor filter's answer at ``t_ns`` (this agent's clock) by a Zenoh query
        (0.5 s timeout): mapped onto this clock, with the offset's uncertainty through the
        relationship's velocity (a second query 1 ms earlier gives it)."""
        import zenoh

        rem = self._remotes.get(self._live.get(edge, ""))
        if rem is None:
            return None
        offset, sigma = 0, 0.0
        if self.cfg.clock_sync == "estimate":
            if not rem.clock.known:
                return None
            offset, sigma = rem.clock.offset_ns, rem.clock.sigma_s
        try:
            w = remote_get(self.session, self.realm, f"get/{edge}", t_ns + offset, 0.5)
            pose = w.pose
            if sigma > 0:
                b = remote_get(self.session, self.realm, f"get/{edge}", t_ns + offset - 10**6, 0.5)
                xi = twist_between(
                    b.pose.position, b.pose.quaternion, pose.position, pose.quaternion, 1e-3
                )
                pose = UncertainPose(pose.pose, pose.covariance + time_error_covariance(xi, sigma))
        except (ValueError, zenoh.ZError):  # error reply, no reply, undecodable, session gone
            return None
        return Measurement(w.exposure_ns - offset, pose, w.origin_ns - offset)

    # -- data path ------------------------------------------------------------------------------
    def _mapping(self, edge: str) -> tuple[int, float] | None:
        """Clock offset [ns] and its sigma [s] for a remote sensor's stamps (None: counted)."""
        agent = self._live.get(edge)
        rem = self._remotes.get(agent) if agent is not None else None
        if rem is None:
            self.rejections.add("sensor not live")
            return None
        if self.cfg.clock_sync != "estimate":
            return 0, 0.0
        if not rem.clock.known:
            self.rejections.add("clock offset not yet estimated")
            return None
        return rem.clock.offset_ns, rem.clock.sigma_s

    def _on_thin(self, edge: str, sample) -> None:
        """A message of a thinned stream: the tick it completes (attachment) and a state of
        the sensor's filter, or nothing new (heartbeat). The state joins the jitter buffer at
        its host stamp as on the full stream; the tick tells the pump that this input is
        complete up to there (mapped with the offset the demand was declared with)."""
        att = sample.attachment
        tick = att.to_bytes() if att is not None else b""
        if len(tick) != 8:
            self.rejections.add("thinned message without tick")
            return
        payload = sample.payload.to_bytes()
        self.received[0] += 1
        self.received[1] += len(payload) + len(tick)
        self.received[2] += not payload
        try:
            s = wire.decode_state(payload) if payload else None
        except wire.WireError as exc:
            self.rejections.add(exc.reason)
            return
        mapping = self._mapping(edge)
        if mapping is None:
            return
        offset, sigma = mapping
        with self._heap_cv:
            inp = self._thin_in.get(edge)
            if inp is None:
                return  # withdrawn meanwhile
            covered = int.from_bytes(tick, "little", signed=True) - inp.offset_ns
            self._thin_arrivals.append(self.now_ns() - covered)
            if inp.covered_ns is None or covered > inp.covered_ns:
                inp.covered_ns = covered
            if s is not None:
                self._buffer(edge, s, offset, sigma)
            self._heap_cv.notify()

    def _buffer(self, edge: str, s: wire.StateSample, offset: int, sigma: float) -> None:
        """(Holding the lock.) Into the jitter buffer at the state's arrival stamp."""
        arrival = s.host_ns - offset
        if self.now_ns() > arrival + self._reorder_ns:
            self.late_events += 1  # later than the jitter buffer: delivered out of order
        heapq.heappush(self._heap, (arrival, _SENSOR, next(self._seq), (edge, s, offset, sigma)))

    def _on_state(self, edge: str, sample) -> None:
        """A state of another agent's sensor filter: decoded, its stamps mapped onto this
        agent's clock, then adopted by the replica at once or (jitter buffer) at its host
        stamp plus ``reorder_ms``."""
        payload = sample.payload.to_bytes()
        self.received[0] += 1
        self.received[1] += len(payload)
        try:
            s = wire.decode_state(payload)
        except wire.WireError as exc:
            self.rejections.add(exc.reason)
            return
        mapping = self._mapping(edge)
        if mapping is None:
            return
        offset, sigma = mapping
        last = self._last_seq.get(edge)
        if last is not None and s.seq > last + 1:
            self.lost_messages += s.seq - last - 1
        self._last_seq[edge] = s.seq
        if self._reorder_ns <= 0:
            with self._lock:
                self.net.clock.now_ns = self.now_ns()
                self._deliver(edge, s, offset, sigma)
            return
        with self._heap_cv:
            if self.cfg.thin:  # every state sent before it has come (thin: ticks wait for it)
                self._covered[edge] = max(self._covered.get(edge, -1), s.host_ns - offset - 1)
            self._buffer(edge, s, offset, sigma)
            self._heap_cv.notify()

    def _deliver(self, edge: str, s: wire.StateSample, offset_ns: int, sigma_s: float) -> None:
        kf = self._filters.get(edge)
        if isinstance(kf, RemoteFilter):
            kf.adopt(s, offset_ns, sigma_s)

    def _pump(self) -> None:
        """Ticks push-query samplers on this agent's clock and releases reordered
        measurements ``reorder_ms`` after their arrival stamp, in time order (sensor events
        before ticks at equal times, as the single-process scheduler orders them)."""
        period = {
            n: int(round(1e9 / q.rate_hz))
            for n, q in self.setup.queries.items()
            if q.mode == "push"
        }
        with self._heap_cv:
            now = self.now_ns()
            for n, p in period.items():
                heapq.heappush(self._heap, ((now // p + 1) * p, _TICK, next(self._seq), n))
            while not self._stop.is_set():
                if not self._heap:
                    self._heap_cv.wait(0.05)
                    continue
                key, kind, _, payload = self._heap[0]
                now = self.now_ns()
                # thin: a state goes at once (every earlier tick has run); a tick as soon as
                # every remote input of its query is complete up to it
                early = self.cfg.thin and (
                    kind == _SENSOR or (now >= key and self._complete(payload, key))
                )
                wait = (key + self._reorder_ns - now) * 1e-9
                if wait > 0 and not early:
                    self._heap_cv.wait(min(wait, 0.05))
                    continue
                heapq.heappop(self._heap)
                self.net.clock.now_ns = key
                if kind == _SENSOR:
                    self._deliver(*payload)
                    continue
                p = period[payload]
                now = self.now_ns()
                if now - key - self._reorder_ns > max(p, 50_000_000):
                    self.missed_ticks += 1  # the agent was stalled: skip to the present
                    nxt = (now - self._reorder_ns) // p * p + p
                else:
                    self._tick_waits.append(now - key)
                    self._tick(payload, key)
                    nxt = key + p
                heapq.heappush(self._heap, (nxt, _TICK, next(self._seq), payload))

    def _complete(self, query: str, t_ns: int) -> bool:
        """(thin) Every remote input of the query has sent what its tick at ``t_ns`` needs."""
        for e in self.queries[query].inputs:
            inp = self._thin_in.get(e)
            covered = inp.covered_ns if inp is not None else self._covered.get(e)
            if covered is None or covered < t_ns:
                return False
        return True

    def _tick(self, name: str, t_ns: int) -> None:
        st = self.queries[name]
        if st.sampler is not None:
            st.sampler.tick(t_ns)

    def _result_callback(self, name: str):
        pub = self._results[name]
        st = self.queries[name]

        def publish(m: Measurement) -> None:
            st.published += 1
            st.last = m
            if isinstance(st.sink, Recorder):
                st.sink.events.clear()  # results leave on the network; keep memory flat
            buf = wire.encode(
                m.pose,
                seq=st.published,
                exposure_ns=m.t_ns,
                host_ns=self.now_ns(),
                origin_ns=m.origin_ns,
            )
            pub.put(buf)

        return publish

    # -- queryables -----------------------------------------------------------------------------
    def _on_fragment_query(self, query) -> None:
        query.reply(query.key_expr, fragment_json(self.name, self.setup.graph))

    def _on_clock_query(self, query) -> None:
        query.reply(query.key_expr, self.now_ns().to_bytes(8, "little", signed=True))

    def _on_status_query(self, query) -> None:
        query.reply(query.key_expr, json.dumps(self.status()).encode())

    def _time_parameter(self, query) -> int | None:
        try:
            return int(str(query.parameters.get("t")))
        except (TypeError, ValueError):
            return None

    def _on_pull_query(self, query) -> None:
        name = str(query.key_expr).rsplit("/", 1)[-1]
        st = self.queries.get(name)
        if st is None:
            return  # another agent's query
        t = self._time_parameter(query)
        if t is None:
            query.reply_err(b"parameter t=<ns> missing or not an integer")
            return
        if st.state != "running" or not isinstance(st.sink, PullSink):
            query.reply_err(f"query {name}: {st.state} {st.reason}".encode())
            return
        self._reply_measurement(query, lambda: st.sink.get(t))

    def _on_edge_get(self, query) -> None:
        name = str(query.key_expr).rsplit("/", 1)[-1]
        src = self._sources.get(name)
        if src is None or name not in self._own:
            return  # not an own sensor
        t = self._time_parameter(query)
        if t is None:
            query.reply_err(b"parameter t=<ns> missing or not an integer")
            return
        self._reply_measurement(query, lambda: self._filters[name].pull(t))

    def _reply_measurement(self, query, get) -> None:
        with self._lock:
            self.net.clock.now_ns = self.now_ns()
            m = get()
        if m is None:
            query.reply_err(b"no result at that time (see the status counters)")
            return
        query.reply(
            query.key_expr,
            wire.encode(
                m.pose, seq=0, exposure_ns=m.t_ns, host_ns=self.now_ns(), origin_ns=m.origin_ns
            ),
        )

    # -- status ---------------------------------------------------------------------------------
    def status(self) -> dict:
        """Plans, re-plan events, rejections, the replicas of other agents' sensor filters
        (states adopted, rejections) and clock offsets, as plain JSON-able data."""
        with self._lock:
            out = {
                "agent": self.name,
                "realm": self.realm,
                "live_edges": dict(sorted(self._live.items())),
                "statics": sorted(self._statics),
                "rejections": dict(self.rejections.counts),
                "lost_messages": self.lost_messages,
                "tick_wait_ms": _percentiles(self._tick_waits),
                "thin_arrival_ms": _percentiles(self._thin_arrivals),
                "published_states": sum(p.seq for p in self._publishers.values()),
                "received_messages": self.received[0],
                "received_bytes": self.received[1],
                "received_heartbeats": self.received[2],
                "late_events": self.late_events,
                "missed_ticks": self.missed_ticks,
                "skipped_samples": self.skipped_samples,
                "replicas": {
                    n: {"states": f.stats.events_in, "rejections": dict(f.stats.rejections)}
                    for n, f in sorted(self._filters.items())
                    if isinstance(f, RemoteFilter)
                },
                "thin_streams": self._thin.status(),
                "thin_inputs": {
                    e: {"periods_ns": sorted(inp.periods), "offset_ns": inp.offset_ns}
                    for e, inp in sorted(self._thin_in.items())
                },
                "clocks": {
                    n: {"offset_ms": r.clock.offset_ns * 1e-6, "sigma_ms": r.clock.sigma_s * 1e3}
                    for n, r in self._remotes.items()
                    if r.clock.known
                },
                "queries": {},
            }
            for n, st in self.queries.items():
                out["queries"][n] = {
                    "state": st.state,
                    "reason": st.reason,
                    "paths": st.paths,
                    "published": st.published,
                    "events": st.events[-20:],
                }
            return out


def _played_before(arrivals, k: int) -> int:
    """(Recordings) With samples ``0 .. k-1`` played: every sample arriving at or before the
    returned time [ns] has been played (the last sample played: forever)."""
    return int(arrivals[k]) - 1 if k < len(arrivals) else _FOREVER_NS


def _percentiles(values) -> dict:
    """p50 and p99 of recent waits [ns], in ms (``{}`` before the first)."""
    v = sorted(values)
    if not v:
        return {}
    return {"p50": v[len(v) // 2] * 1e-6, "p99": v[min(len(v) - 1, int(0.99 * len(v)))] * 1e-6}


def remote_get(session, realm: str, key: str, t_ns: int, timeout_s: float = 2.0):
    """Ask ``trackflow/<realm>/<key>?t=<t_ns>`` (``query/<name>`` or ``get/<edge>``) over a
    Zenoh session; returns a :class:`trackflow.distributed.wire.WireSample` or raises
    ``ValueError`` with the remote's reason (or "no reply")."""
    errors = []
    for reply in session.get(f"{_key(realm, key)}?t={int(t_ns)}", timeout=timeout_s):
        if reply.ok is not None:
            return wire.decode(reply.ok.payload.to_bytes())
        errors.append(reply.err.payload.to_bytes().decode(errors="replace"))
    raise ValueError(f"{key} at t={t_ns}: " + ("; ".join(errors) or "no reply"))


def set_agent_gc() -> None:
    """Quieter garbage collection for a process that is an agent: everything allocated so
    far (modules, setup, plans) lives as long as the process, so it is frozen out of the
    collector's scans, and the youngest generation is collected less often (the data path
    allocates few objects that form cycles), so collections are rarer and stay short."""
    gc.collect()
    gc.freeze()
    gc.set_threshold(*_GC_THRESHOLDS)


def run_agent(config: AgentConfig, duration_s: float | None = None, on_ready=None) -> dict:
    """Run an agent until ``duration_s`` passes, or (without a duration) until its recordings
    have played, or forever if it has none; SIGTERM and Ctrl-C stop it cleanly. Returns the
    final :meth:`Agent.status`. ``on_ready(agent)`` is called once it is running."""
    import signal

    stop = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    agent = Agent(config).start()
    set_agent_gc()
    try:
        if on_ready is not None:
            on_ready(agent)
        deadline = None if duration_s is None else time.monotonic() + duration_s
        while not stop.is_set():
            if deadline is not None and time.monotonic() >= deadline:
                break
            if (
                deadline is None
                and agent._players
                and not any(th.is_alive() for _, th in agent._players)
            ):
                break
            stop.wait(0.1)
        return agent.status()
    finally:
        agent.close()
        signal.signal(signal.SIGTERM, previous)
