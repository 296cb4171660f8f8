"""A trackflow agent: one process's part of a distributed tracking setup on Eclipse Zenoh.

Key space (``<realm>`` and names: letters, digits, ``_``, ``-``)::

    trackflow/<realm>/alive/<agent>/<edge>   liveliness token per edge the agent provides
    trackflow/<realm>/fragment/<agent>       queryable: the agent's SRG fragment (JSON)
    trackflow/<realm>/clock/<agent>          queryable: the agent's clock reading (int64 ns)
    trackflow/<realm>/states/<agent>         pub/sub: the agent's sensor filters' states, one
                                             message per dispatch round (docs/wire.md, v3)
    trackflow/<realm>/demand/<edge>/<consumer>/<period_ns>/<phase_ns>
                                             liveliness token: a consumer's tick grid (thin)
    trackflow/<realm>/thin/<edge>/<consumer> pub/sub: the states that grid needs (thinning.py)
    trackflow/<realm>/get/<edge>?t=<ns>      queryable: the sensor filter's get(t) (wire)
    trackflow/<realm>/query/<query>?t=<ns>   queryable: a pull query's get(t) (wire)
    trackflow/<realm>/result/<query>         pub/sub: a push query's results (wire)
    trackflow/<realm>/status/<agent>         queryable: plans, re-plans and counters (JSON)

An agent is a composition of the parts every runtime of trackflow uses. Its own sensors are
the setup's: a sensor with a ``recording:`` is played on the agent's clock from ``start_ns``,
one with an ``input:`` is a live tracker (NatNet, DTrack, VRPN, optical: the same inputs as
``trackflow run``), one with neither is fed through :meth:`Agent.feed`; the setup's ``imus:``
are played like recordings and aid the plans' filters of the bodies they are on. Each own
sensor's Kalman filter runs here (answering ``get/<edge>``) and publishes its state after
every measurement. Every agent assembles the union graph of the live fragments
(:mod:`~trackflow.distributed.discovery`) and plans its queries with
:meth:`trackflow.dataflow.Setup.plan` on it; another agent's sensor enters a plan through a
replica of that sensor's filter (:mod:`~trackflow.distributed.remote_inputs`). All events -
own samples, remote states, query ticks, thinned streams' deadlines - are dispatched by one
:class:`trackflow.dataflow.Scheduler` on the agent's clock. When a token disappears the
affected queries re-plan at once (or report "no path" with the reason).
"""

from __future__ import annotations

import collections
import json
import threading
import time
from dataclasses import dataclass, field

from ..dataflow import (
    KEPT_EVENTS,
    Component,
    KalmanFilter,
    Measurement,
    Network,
    PathSwitch,
    PlayerSource,
    PullSink,
    Recorder,
    RecordingPlayer,
    Scheduler,
    Ticker,
    TimedSource,
    WallTime,
    keep_newest,
    warm_up,
)
from ..dataflow._component import _Clock
from ..errors import InputError, ServiceError
from ..graph import Edge
from ..math import UncertainPose
from ..optional import require
from ..ros2 import close_publishers, open_publishers
from ..trackers.inputs import make_inputs, warm_up_inputs
from ..trackers.runtime import InputSource, LiveSource, LiveSources, measured_attributes
from . import wire
from .config import AgentConfig, security, zenoh_config
from .discovery import Discovery, realm_key
from .fragment import fragment_json
from .remote_inputs import RemoteInputs, RemoteSource, remote_get
from .replica import RemoteFilter, StateBatch, StatePublisher
from .replica import warm_up as warm_up_replicas
from .thinning import ThinStreams, parse_demand

__all__ = ["Agent", "QueryState", "RemoteSource", "remote_get", "run_agent"]

_REDECLARE_NS = 50_000  # a thinned input's demand follows the clock offset to within 50 us
_FOREVER_NS = 2**62  # (progress of a recording played to its end)


@dataclass
class QueryState:
    """The current plan of one of the agent's queries and its history of re-plans."""

    name: str
    state: str = "waiting"  # "running", "no path"
    reason: str = ""
    paths: list[str] = field(default_factory=list)
    fallbacks: list[str] = field(default_factory=list)  # failover: the fallback paths
    plan: object = None  # the current plan (None: waiting, or no path)
    sink: object = None
    sampler: object = None
    generation: int = 0
    #: the newest re-plan events (status shows the last 20; a long run keeps memory flat)
    events: collections.deque = field(default_factory=lambda: collections.deque(maxlen=KEPT_EVENTS))
    published: int = 0
    last: Measurement | None = None
    inputs: frozenset = frozenset()  # remote sensors of the plan (thin: ticks wait for them)


class _QueryTicks(Ticker):
    """A push query's ticks on the agent's clock, released ``reorder_ms`` after their time
    (the jitter buffer); with ``thin: true`` as soon as every remote input has sent what the
    tick needs. A tick more than a period (at least 50 ms) late is skipped (a stalled
    agent catches up with the present instead of answering its backlog)."""

    def __init__(self, agent: Agent, st: QueryState, period: int, first: int, delay: int):
        super().__init__(st.name, self._run, period, first, None, max(period, 50_000_000), delay)
        self.agent, self.st = agent, st
        self.waits: collections.deque = collections.deque(maxlen=4096)  # tick -> run [ns]

    def early(self, t_ns: int, now_ns: int) -> bool:
        agent = self.agent
        return agent.cfg.thin and now_ns >= t_ns and agent.remote.complete(self.st.inputs, t_ns)

    def _run(self, t_ns: int) -> None:
        self.waits.append(self.agent.now_ns() - t_ns)
        if self.st.sampler is not None:
            self.st.sampler.tick(t_ns)


class _OwnRecording(PlayerSource):
    """An own sensor's recording played on the agent's clock; the agent's thinned streams
    follow how far it has played (:attr:`played_until`)."""

    @property
    def played_until(self) -> int:
        """Every sample arriving at or before this time [ns] has been played."""
        k = self.played
        return int(self.arrivals[k]) - 1 if k < len(self.arrivals) else _FOREVER_NS


class _ThinDeadlines(TimedSource):
    """(Sensor side) completes the ticks of the thinned streams when no state did it
    before: each stream's pending state (or a heartbeat) is sent once the tick (plus the
    grace of recordings) has passed."""

    def __init__(self, agent: Agent):
        self.name, self.agent = "thin streams", agent

    def next_ns(self) -> int | None:
        due = self.agent.thin.next_due
        return None if due >= _FOREVER_NS else due

    def fire(self, t_ns: int) -> None:
        # the scheduler's time, not the wall clock's: a live state stamped before the wall's
        # now but still waiting for the scheduler's lock is dispatched after ``t_ns`` (its
        # arrival moves past it) and so answers the next tick; completing ticks up to the
        # wall's now would leave it late, a second message for an already completed tick
        self.agent.thin.flush(t_ns, self.agent.now_ns())


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
        self._clock_offset_ns = int(round(config.clock_offset_ms * 1e6))
        self._reorder_ns = int(round(config.reorder_ms * 1e6))
        self._clock = _Clock()
        self.sched = Scheduler(self._clock, WallTime(self.now_ns))
        self._lock = self.sched.lock
        self._publishers: dict[str, StatePublisher] = {}
        self._states: StateBatch | None = None  # the own sensors' states, a round at a time
        self._own: set[str] = set()
        self.queries = {n: QueryState(n) for n in self.setup.queries}
        self._ticks: dict[str, _QueryTicks] = {}
        self._stop = threading.Event()
        self._sources: dict[str, Component] = {}
        self._filters: dict[str, KalmanFilter] = {}
        self._recordings: list[_OwnRecording] = []
        self._inputs: list = []  # live trackers of own sensors (trackers.inputs.LiveInput)
        self._grace_ns = int(round(config.thin_grace_ms * 1e6))
        self.discovery = Discovery(
            self.name, self.realm, self._lock, self.rejections, self._replan,
            self._clocks_measured, lambda: self.remote.agents_followed(),
        )  # fmt: skip
        self.remote = RemoteInputs(self, self.sched, self.discovery, self._sources, self._filters)
        self.thin = ThinStreams(  # (sensor side) consumers' thinned streams of own sensors
            config.realm,
            lambda key: self.session.declare_publisher(key, express=False),  # batched
            self._grace,
            self._played_until,
        )
        self._thin_deadlines = _ThinDeadlines(self)
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None
        self.net = Network(self._clock)
        self.session = None
        self._event_pub = None  # re-plan events, as they happen (event/<agent>; start())
        self.security = "not started"  # how its Zenoh links are protected (start())
        #: push queries published as ROS 2 topics (``ros2:``; trackflow.ros2.AnswerPublisher)
        self.ros2: dict = {}

    # -- clock ----------------------------------------------------------------------------------
    def now_ns(self) -> int:
        """This agent's clock [ns]: Unix time (plus the configured test offset)."""
        return time.time_ns() + self._clock_offset_ns

    # -- life cycle -----------------------------------------------------------------------------
    def start(self) -> Agent:
        zenoh = require("zenoh", extra="distributed", feature="trackflow agent")

        conf = zenoh_config(self.cfg)
        self.security = security(conf)[0]  # loopback, tls+acl or (told so) insecure
        try:
            self.session = zenoh.open(conf)
        except zenoh.ZError as exc:
            listen = conf.get_json("listen/endpoints")
            raise ServiceError(
                f"agent {self.name!r}: cannot open the Zenoh session (listen {listen}): {exc}"
            ) from None
        s, r = self.session, self.realm
        try:
            self.ros2 = open_publishers(self.setup.ros2)  # own sessions, to the ROS 2 router
        except BaseException:
            self.session.close()
            self.session = None
            raise
        warm_up_replicas()  # compiled kernels are typed, not sized: one model warms them for all
        self._own_sensors()
        self._declare(s, r)
        now = self.now_ns()
        for n, q in self.setup.queries.items():
            if q.mode == "push":
                p = int(round(1e9 / q.rate_hz))
                ticks = _QueryTicks(self, self.queries[n], p, (now // p + 1) * p, self._reorder_ns)
                self._ticks[n] = self.sched.add(ticks)
        if self._own:
            self.sched.add(self._thin_deadlines)
        self._thread = threading.Thread(target=self._run, name=f"{self.name}-events", daemon=True)
        self._thread.start()
        self.discovery.start(s, self.now_ns)
        if self._own:  # consumers' tick grids for thinned streams of the own sensors
            self._demands = s.liveliness().declare_subscriber(
                realm_key(r, "demand", "**"), self._on_demand, history=True
            )
        return self

    def _declare(self, s, r: str) -> None:
        """The agent's queryables, liveliness tokens and result publishers."""
        self._decl = [
            s.declare_queryable(realm_key(r, "fragment", self.name), self._on_fragment_query),
            s.declare_queryable(realm_key(r, "clock", self.name), self._on_clock_query),
            s.declare_queryable(realm_key(r, "status", self.name), self._on_status_query),
        ]
        self._decl += [  # only what this agent can answer
            s.declare_queryable(realm_key(r, "query", n), self._on_pull_query)
            for n, q in self.setup.queries.items()
            if q.mode == "pull"
        ]
        self._decl += [
            s.declare_queryable(realm_key(r, "get", n), self._on_edge_get) for n in self._own
        ]
        self._tokens = [
            s.liveliness().declare_token(realm_key(r, "alive", self.name, e.name))
            for e in self.setup.graph.edges
        ]
        self._tokens.append(s.liveliness().declare_token(realm_key(r, "agent", self.name)))
        self._event_pub = s.declare_publisher(realm_key(r, "event", self.name))
        self._results = {
            n: s.declare_publisher(realm_key(r, "result", self.name, n))  # unique per agent
            for n, q in self.setup.queries.items()
            if q.mode == "push"
        }

    def _run(self) -> None:
        """The agent's one event loop (the scheduler); an error stops the agent's data path
        and is shown in :meth:`status`."""
        try:
            self.sched.run(stop=self._stop, calm=True)
        except Exception as exc:
            self.error = exc

    def close(self) -> None:
        """Stop every thread and close the Zenoh session (tokens disappear for the others)."""
        self._stop.set()
        self.sched.wake()
        self.discovery.stop()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if self.session is not None:
            self.session.close()
            self.session = None
        close_publishers(self.ros2)
        self.ros2 = {}

    def __enter__(self) -> Agent:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def recordings_done(self) -> bool:
        """Whether the agent has recordings and every one of them has played."""
        return bool(self._recordings) and all(r.next_ns() is None for r in self._recordings)

    def wait(self, timeout_s: float | None = None) -> None:
        """Block until the recordings have played (or ``timeout_s``; forever without
        recordings and timeout)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while not self._stop.is_set():
            if self._recordings and self.recordings_done():
                return
            if deadline is not None and time.monotonic() >= deadline:
                return
            self._stop.wait(0.05)

    # -- own sensors ----------------------------------------------------------------------------
    def _own_sensors(self) -> None:
        """A source, its Kalman filter (answering get/<edge>) and the publisher of its states
        per own sensor: recordings and IMUs are played on the agent's clock from
        ``start_ns``, live trackers (``input:``) are opened, the rest are fed by
        :meth:`feed`."""
        skip_before = self.now_ns() - 100_000_000  # a restarted agent skips its past
        players = self.setup.players()
        live: dict[str, LiveSource] = {}
        for edge in self.setup.graph.edges:
            if edge.kind != "measured":
                continue
            if edge.name in players:
                src = self._shifted(players[edge.name])
                self._recordings.append(_OwnRecording(src, None, skip_before))
            elif edge.name in self.setup.inputs:
                src = live[edge.name] = LiveSource(edge.name)
            else:
                src = RemoteSource(edge.name)
                src.kind = "live source"
            self._sources[edge.name] = src
            kf = self._filters[edge.name] = self._make_filter(edge)
            self._own.add(edge.name)
            pub = self._publishers[edge.name] = StatePublisher(
                f"publish_{edge.name}", kf, self._batch().slot(edge.name)
            )
            pub.tap = lambda h_ns, buf, name=edge.name: self._offer_thin(name, h_ns, buf)
        for name in self.setup.imus:  # IMUs aid the plans' filters of their bodies
            if name in players:
                src = self._sources[name] = self._shifted(players[name])
                self._recordings.append(_OwnRecording(src, None, skip_before))
        with self._lock:
            self._rebuild_base()
        for rec in self._recordings:
            self.sched.add(rec)
        if live:
            warm_up(self.net)
            warm_up_inputs()
            specs = {e: (self.setup.inputs[e], self.setup.graph.edge(e).covariance) for e in live}
            delivery = LiveSources(live)
            for inp in make_inputs(specs):
                self._inputs.append(self.sched.add(InputSource(inp, delivery, {})))

    def _batch(self) -> StateBatch:
        """The own sensors' states leave as one message per dispatch round (made at the
        first own sensor)."""
        if self._states is None:
            # express: a round's message leaves at once, not held back for later ones
            pub = self.session.declare_publisher(
                realm_key(self.realm, "states", self.name), express=True
            )
            self._states = StateBatch(pub)
            self.sched.drained.append(self._states.flush)
        return self._states

    def _shifted(self, player: RecordingPlayer) -> RecordingPlayer:
        """The player with its recording time 0 at ``start_ns`` on the agent's clock."""
        player.t_ns = player.t_ns + self.cfg.start_ns
        return player

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
        net = Network(self._clock)
        for name, src in self._sources.items():
            src.consumers = []
            net.add(src)
            kf = self._filters.get(name)
            if kf is None:  # an IMU: the plans connect it
                continue
            kf.consumers = []
            net.add(kf)
            if isinstance(kf, RemoteFilter):
                continue
            net.connect(src, kf, mode="push")
            pub = self._publishers.get(name)
            if pub is not None:  # states taken before local inference (see StatePublisher)
                pub.consumers = []
                net.add(pub)
                net.connect(kf, pub, mode="push", port=0)
                net.connect(src, pub, mode="push", port=1)
        self.net = net
        return net

    def feed(self, edge: str, t_ns: int, pose: UncertainPose) -> None:
        """Push a live measurement of an own sensor (stamped ``t_ns`` on this agent's clock)."""
        src = self._sources.get(edge)
        if not isinstance(src, RemoteSource) or edge not in self._own:
            raise InputError(f"agent {self.name!r} has no live sensor {edge!r}")
        m = Measurement(int(t_ns), pose, int(t_ns))
        with self.sched.arrival(self.now_ns()) as arr:
            if arr is not None:  # at its dispatch time: the clock the dataflow reads is set
                arr.deliver(1, lambda _i, _j, _a: src.deliver(m))

    def get(self, query: str, t_ns: int) -> Measurement | None:
        """``get(t)`` of one of this agent's pull queries (``None``: no path or no result;
        the status says why)."""
        st = self.queries.get(query)
        if st is None:
            raise InputError(f"agent {self.name!r} has no query {query!r}")
        with self._lock:
            if not isinstance(st.sink, PullSink):
                return None
            self._clock.now_ns = self.now_ns()
            return st.sink.get(int(t_ns))

    # -- thinned streams of own sensors (sensor side) ------------------------------------------
    def _played_until(self, edge: str) -> int | None:
        for rec in self._recordings:
            if rec.name == edge:
                return rec.played_until
        return None

    def _on_demand(self, sample) -> None:
        """A consumer's tick grid for one of this agent's sensors appeared (PUT) or went away
        (DELETE: withdrawn, or the consumer died). Garbage is a counted rejection."""
        import zenoh

        key = str(sample.key_expr)
        if sample.kind == zenoh.SampleKind.DELETE:
            with self._lock:
                self.thin.withdraw(key)
            return
        try:
            edge, consumer, grid = parse_demand(key, self.realm)
        except ValueError as exc:
            self.rejections.add(str(exc))
            return
        if edge not in self._own:
            own_edges = {e.name for e in self.setup.graph.edges}
            known = edge in self.discovery.statics or edge in own_edges
            if known:
                self.rejections.add("demand for a static edge")
            elif edge not in self.discovery.live:  # (also before this agent met the owner)
                self.rejections.add("demand for unknown edge")
            return  # another agent's sensor: its agent serves it
        with self._lock:
            refused = self.thin.declare(key, edge, consumer, grid, self.now_ns())
            if refused:
                self.rejections.add(refused)
            self.sched.reschedule(self._thin_deadlines)

    def _offer_thin(self, edge: str, h_ns: int, buf: bytes) -> None:
        """(Under the agent's lock, from the state publisher.) A new state of an own sensor,
        made at the dispatch time ``h_ns``: ticks due by then are completed at it too (see
        :meth:`_ThinDeadlines.fire` for why not at the wall clock's now)."""
        self.thin.offer(edge, h_ns, buf, h_ns)

    def _grace(self, edge: str) -> int:
        """How long after a tick a state made before it may still come [ns]: a live sensor's
        states are stamped when the agent takes them, so never; a recording's are stamped
        with their scheduled arrival, and the event loop may run late."""
        return self._grace_ns if isinstance(self._sources.get(edge), RecordingPlayer) else 0

    def _clocks_measured(self) -> None:
        """(Discovery thread, every 2 s) thinned inputs follow the clock offsets' estimates."""
        with self._lock:
            self.remote.follow_clocks(_REDECLARE_NS)

    # -- planning -------------------------------------------------------------------------------
    def union_graph(self):
        """Own edges, live remote sensors and every static edge learned so far."""
        return self.discovery.union_graph(self.setup.graph)

    def _replan(self, reason: str, t_event_ns: int, departed: frozenset | None = None) -> None:
        """Plan every query on the current union graph; rebuild the dataflow if a plan
        changed. When only sensors left (``departed``), a query whose plan uses none of them
        (fallbacks included) keeps it unplanned: losing edges cannot better a path, and one
        without a path cannot gain one. Remote sensors are subscribed when a plan first uses
        them (a sensor no query uses never crosses the network) and stay subscribed, so a
        later switch back finds their replicas current. Each query's new plan is an event in
        its status and, as it happens, a message on ``event/<agent>`` (:meth:`_announce`)."""
        announce: list[tuple[str, dict]] = []
        with self._lock:
            self._replan_locked(reason, t_event_ns, announce, departed)
        self._announce(announce)

    def _replan_locked(self, reason: str, t_event_ns: int, announce: list, departed) -> None:
        """:meth:`_replan` under the lock; the events made go to ``announce``."""
        graph = self.union_graph()
        changed, plans, used, pushed, new_events = False, {}, set(), set(), []
        for name, q in self.setup.queries.items():
            st = self.queries[name]
            if departed is not None and st.state == "no path":
                continue
            try:
                keep = departed is not None and st.plan is not None
                plan = st.plan if keep and not st.plan.sensors & departed else self._plan(q, graph)
            except ValueError as exc:
                if st.state != "no path" or st.reason != str(exc):
                    st.state, st.reason, st.paths = "no path", str(exc), []
                    st.fallbacks, st.plan = [], None
                    st.sink = st.sampler = None
                    changed = True
                    st.events.append(self._event(reason, t_event_ns, st))
                    announce.append((name, st.events[-1]))
                continue
            plans[name] = st.plan = plan
            used |= plan.sensors  # a fallback's sensors too: its replicas stay warm
            if q.mode == "push":
                pushed |= plan.sensors
                # thinned ticks wait for the preferred path's inputs only
                preferred = {s for p in plan.paths for s in p.sensors}
                st.inputs = frozenset(preferred - self._own)
            paths = [str(p) for p in plan.paths]
            fallbacks = [str(p) for p in plan.fallbacks]
            if st.state == "running" and (paths, fallbacks) == (st.paths, st.fallbacks):
                continue  # a new fallback (another tracker of the body) rebuilds too
            st.state, st.reason, st.paths = "running", "", paths
            st.fallbacks = fallbacks
            new_events.append(self._event(reason, t_event_ns, st))
            st.events.append(new_events[-1])
            announce.append((name, new_events[-1]))
            changed = True
        if not changed:
            return
        self._wire_remote(graph, plans, used, pushed)
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
            keep_newest([st.sink])  # an agent runs for hours: bounded answer stores
            st.sink.reset()  # (a fresh sink: its stores become deques of that length)
        for event in new_events:  # the time the new plans took effect
            event["replan_ms"] = (time.perf_counter_ns() - t_event_ns) * 1e-6

    def _announce(self, events: list[tuple[str, dict]]) -> None:
        """Publish re-plan events ``(query, event)`` on ``event/<agent>`` (JSON: the event of
        the status with ``"query"`` added), so a realm's watcher shows them at once instead
        of at its next status poll."""
        pub = self._event_pub
        if pub is None:
            return
        for name, event in events:
            pub.put(json.dumps({"query": name, **event}).encode())

    def _plan(self, q, graph):
        """The setup's planner on the union graph; an IMU of this agent on a body that only
        another agent's sensor measures is refused (the IMU aids the filter of the sensor
        next to it, and a replica's states come filtered already)."""
        plan = self.setup.plan(q, graph=graph)
        for node in plan.nodes:
            if node.kind == "switch":  # another agent's sensor: the window it advertises
                for path in node.params["sensors"]:
                    for e, _ in path:
                        stale = None if e in self._own else self.discovery.stale_s(e)
                        if stale is not None:
                            node.params["stale_ns"][e] = int(round(stale * 1e9))
            edge = node.params.get("edge")
            if node.kind == "kalman" and "imu" in node.params and edge not in self._own:
                line = self.setup.lines.get(f"imus.{node.params['imu']}", 0)
                where = f"{self.setup.source}:{line}" if line else self.setup.source
                raise InputError(
                    f"{where}: imus: {node.params['imu']!r} is on the body of sensor {edge!r} "
                    "of another agent; an IMU aids only this agent's own sensors"
                )
        return plan

    def _wire_remote(self, graph, plans: dict, used: set, pushed: set) -> None:
        """Replicas (and their subscriptions) for the remote sensors the plans use."""
        thin = self.remote.thin_periods(plans, self._own) if self.cfg.thin else {}
        for edge in sorted(used - self._own):
            if edge in thin:
                self.remote.subscribe_thin(graph.edge(edge), thin[edge])
            elif self.cfg.pull_via == "replica" or edge in pushed:
                self.remote.subscribe(graph.edge(edge))
            elif edge not in self._sources:
                self.remote.ask_per_request(graph.edge(edge))

    @staticmethod
    def _event(reason: str, t_event_ns: int, st: QueryState) -> dict:
        return {
            "t_ns": time.time_ns(),  # when it happened (host clock), for a realm's view
            "reason": reason,
            "state": st.state,
            "detail": st.reason,
            "paths": list(st.paths),
            "fallbacks": list(st.fallbacks),
            "replan_ms": (time.perf_counter_ns() - t_event_ns) * 1e-6,
        }

    def _result_callback(self, name: str):
        pub = self._results[name]
        st = self.queries[name]
        ros2 = self.ros2.get(name)

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
                path=m.path,
            )
            pub.put(buf)
            if ros2 is not None:
                ros2(m)

        return publish

    # -- queryables -----------------------------------------------------------------------------
    def _on_fragment_query(self, query) -> None:
        stale = {e: spec.stale_s for e, spec in self.setup.inputs.items()}
        query.reply(query.key_expr, fragment_json(self.name, self.setup.graph, stale_s=stale))

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
            self._clock.now_ns = self.now_ns()
            m = get()
        if m is None:
            query.reply_err(b"no result at that time (see the status counters)")
            return
        query.reply(
            query.key_expr,
            wire.encode(
                m.pose,
                seq=0,
                exposure_ns=m.t_ns,
                host_ns=self.now_ns(),
                origin_ns=m.origin_ns,
                path=m.path,
            ),
        )

    # -- status ---------------------------------------------------------------------------------
    @property
    def states(self) -> StateBatch | None:
        """Where the own sensors' states leave (``None``: the agent has no sensor)."""
        return self._states

    @property
    def publishers(self) -> dict[str, StatePublisher]:
        """The state publishers of the own sensors' filters, by sensor."""
        return dict(self._publishers)

    @property
    def filters(self) -> dict[str, Component]:
        """Every sensor's filter node in this agent: own filters and replicas, by edge."""
        return dict(self._filters)

    def status(self) -> dict:
        """Plans, re-plan events, rejections, the replicas of other agents' sensor filters
        (states adopted, rejections) and clock offsets, as plain JSON-able data."""
        with self._lock:
            ticks = list(self._ticks.values())
            waits = [w for t in ticks for w in t.waits]
            rem = self.remote
            out = {
                "agent": self.name,
                "realm": self.realm,
                "security": self.security,
                "live_edges": dict(sorted(self.discovery.live.items())),
                "statics": sorted(self.discovery.statics),
                "rejections": dict(self.rejections.counts),
                "lost_messages": rem.lost_messages,
                "tick_wait_ms": _percentiles(waits),
                "thin_arrival_ms": _percentiles(rem.thin_arrivals),
                "published_states": sum(p.seq for p in self._publishers.values()),
                "published_messages": 0 if self._states is None else self._states.messages,
                "received_messages": rem.received[0],
                "received_bytes": rem.received[1],
                "received_heartbeats": rem.received[2],
                "received_states": rem.received[3],
                "late_events": rem.late_events,
                "missed_ticks": sum(t.missed for t in ticks),
                "skipped_samples": sum(r.skipped for r in self._recordings),
                **rem.status(),
                "thin_streams": self.thin.status(),
                "clocks": self.discovery.clocks(),
                "inputs": {
                    b.name: b.status.summary(time.time_ns(), b.spec.stale_s)
                    for src in self._inputs
                    for b in src.input.bodies
                },
                "queries": {},
                "ros2": {n: p.status() for n, p in self.ros2.items()},
                "attributes": measured_attributes(self.net, self.setup.graph, sorted(self._own)),
            }
            if self.error is not None:
                out["error"] = f"{type(self.error).__name__}: {self.error}"
            for n, st in self.queries.items():
                out["queries"][n] = {
                    "state": st.state,
                    "reason": st.reason,
                    "paths": st.paths,
                    "fallbacks": st.fallbacks,
                    "published": st.published,
                    "events": list(st.events)[-20:],
                }
                switch = self.net.components.get(f"{n}_g{st.generation}_switch")
                if isinstance(switch, PathSwitch):  # failover: current path, its switches
                    out["queries"][n].update(switch.summary())
            return out


def _percentiles(values) -> dict:
    """p50 and p99 of recent waits [ns], in ms (``{}`` before the first)."""
    v = sorted(values)
    if not v:
        return {}
    return {"p50": v[len(v) // 2] * 1e-6, "p99": v[min(len(v) - 1, int(0.99 * len(v)))] * 1e-6}


def run_agent(
    config: AgentConfig,
    duration_s: float | None = None,
    on_ready=None,
    stop: threading.Event | None = None,
    on_status=None,
    status_period_s: float = 1.0,
) -> dict:
    """Run an agent until ``duration_s`` passes, ``stop`` is set (the command line sets it
    on SIGTERM), Ctrl-C, or (without a duration) until its recordings have played, or
    forever if it has none. Returns the final :meth:`Agent.status`. ``on_ready(agent)`` is
    called once it is running, ``on_status(status)`` every ``status_period_s`` while it
    runs (``trackflow agent --status`` keeps its file current with it)."""
    stop = stop or threading.Event()
    agent = Agent(config).start()
    try:
        if on_ready is not None:
            on_ready(agent)
        deadline = None if duration_s is None else time.monotonic() + duration_s
        next_status = time.monotonic() + status_period_s
        while not stop.is_set():
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            if deadline is None and agent.recordings_done():
                break
            if on_status is not None and now >= next_status:
                on_status(agent.status())
                next_status = now + status_period_s
            stop.wait(0.1)
        return agent.status()
    finally:
        agent.close()
