"""An agent's inputs from other agents' sensors: replicas fed by subscriptions.

A plan that uses another agent's sensor gets a replica of that sensor's filter
(:class:`~trackflow.distributed.replica.RemoteFilter`), fed by one of three ways:

* the full stream: every state the filter makes, in its agent's batches on
  ``states/<agent>`` (one subscription per agent, whatever number of its sensors is used),
* a thinned stream ``thin/<edge>/<consumer>`` (``thin: true``: only the states the
  consumer's tick grid needs, declared with demand tokens; thinning.py), or
* per request (``pull_via: get``: a node asking ``get/<edge>?t=`` when a pull query needs it).

Each state's stamps are mapped onto this agent's clock with the measured offset (its
uncertainty enters the covariance) and the state is handed to the agent's scheduler, at once
or through the jitter buffer (``reorder_ms``).
"""

from __future__ import annotations

import collections
from dataclasses import dataclass

from ..dataflow import BACKLOG_NS, SAMPLE, Component, Measurement, Scheduler
from ..errors import InputError
from ..graph import Edge
from ..math import UncertainPose
from . import wire
from .clock import time_error_covariance, twist_between
from .discovery import Discovery, realm_key
from .plausibility import Sequences, state_problem
from .replica import RemoteFilter, RemoteGet
from .thinning import Grid, demand_key, thin_key

__all__ = ["RemoteInputs", "RemoteSource", "remote_get"]


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
class ThinInput:
    """(Consumer side) a remote sensor received thinned: its demand tokens and coverage."""

    periods: frozenset
    offset_ns: int
    tokens: list
    subscriber: object
    covered_ns: int | None = None


class RemoteInputs:
    """The replicas of other agents' sensors and the subscriptions feeding them.

    ``sources`` and ``filters`` are the agent's (edge -> component); replicas are added to
    them. States reach the replicas through ``sched`` in time order.
    """

    def __init__(self, agent, sched: Scheduler, discovery: Discovery, sources, filters):
        self.agent = agent
        self.cfg = agent.cfg
        self.sched = sched
        self.discovery = discovery
        self.sources: dict[str, Component] = sources
        self.filters: dict[str, Component] = filters
        self.rejections: wire.Rejections = agent.rejections
        self.subs: dict[str, str] = {}  # remote edge on the full stream -> its agent
        self.agents: dict[str, object] = {}  # agent -> the subscription to its batches
        self.thin: dict[str, ThinInput] = {}  # remote edge -> its thinned subscription
        self.covered: dict[str, int] = {}  # thin, full stream: edge -> covered up to [ns]
        self.sequences = Sequences()
        # messages, bytes, heartbeats of remote sensors' streams; states taken from them
        self.received = [0, 0, 0, 0]
        self.thin_arrivals: collections.deque = collections.deque(maxlen=4096)
        self.late_events = 0
        self._reorder_ns = int(round(self.cfg.reorder_ms * 1e6))

    @property
    def session(self):
        return self.agent.session

    def agents_followed(self) -> set[str]:
        """The agents whose sensors this agent receives (full or thinned streams): the
        clocks it maps stamps with (:class:`~trackflow.distributed.discovery.Discovery`
        checks only theirs)."""
        with self.sched.lock:
            names = set(self.subs.values())
            names |= {a for e in self.thin if (a := self.discovery.live.get(e)) is not None}
        return names

    # -- wiring ---------------------------------------------------------------------------------
    def replica(self, edge: Edge) -> None:
        if not isinstance(self.filters.get(edge.name), RemoteFilter):
            self.sources[edge.name] = RemoteSource(edge.name)
            self.filters[edge.name] = RemoteFilter(
                f"kf_{edge.name}",
                edge.motion,
                stamp_offset_ns=int(round(edge.stamp_offset_s * 1e9)),
            )

    def subscribe(self, edge: Edge) -> None:
        """A replica of a remote sensor's filter, fed with its states from its agent's
        batches (also replacing a per-request node once a push query needs the sensor, or a
        thinned subscription once a query needs every state). One subscription per agent:
        the first of its sensors declares it, the others share it."""
        rem = self.discovery.agent_of(edge.name)
        if rem is None or self.subs.get(edge.name) == rem.name:
            return  # (gone since the plan was made: the next re-plan wires it)
        self.replica(edge)
        inp = self.thin.pop(edge.name, None)
        if inp is not None:
            for token in inp.tokens:
                token.undeclare()
            inp.subscriber.undeclare()
        if rem.name not in self.agents:
            self.agents[rem.name] = self.session.declare_subscriber(
                realm_key(self.agent.realm, "states", rem.name),
                lambda sample, name=rem.name: self.on_batch(name, sample),
            )
        self.subs[edge.name] = rem.name

    def thin_periods(self, plans: dict, own: set[str]) -> dict[str, frozenset]:
        """(``thin: true``) The remote sensors that may be received thinned, with the tick
        periods [ns] of the push queries using them: not those a pull query reads from a
        replica, nor those of a push query answering in the past (``time_offset_ms < 0``
        interpolates between states, so it needs them all)."""
        periods: dict[str, set] = {}
        raw: set[str] = set()
        for plan in plans.values():
            q = plan.query
            sensors = plan.sensors - own  # a fallback path's too (failover)
            if q.mode == "push" and q.time_offset_s >= 0:
                for e in sensors:
                    periods.setdefault(e, set()).add(int(round(1e9 / q.rate_hz)))
            elif q.mode == "push" or self.cfg.pull_via == "replica":
                raw |= sensors
        return {e: frozenset(p) for e, p in periods.items() if e not in raw}

    def offset_ns(self, edge: str) -> int:
        """This agent's clock minus the remote sensor's agent's [ns] (the
        :mod:`trackflow.timesync` offset: ``host = remote + offset``); 0 while unknown."""
        rem = self.discovery.agent_of(edge)
        if rem is None or self.cfg.clock_sync != "estimate" or not rem.clock.known:
            return 0
        return rem.clock.offset_ns

    def subscribe_thin(self, edge: Edge, periods: frozenset) -> None:
        """A replica fed by a thinned stream: one demand token per tick period (the grid
        mapped onto the sensor agent's clock) and a subscription to the stream."""
        if edge.name in self.subs:
            return  # every state comes already
        self.replica(edge)
        inp = self.thin.get(edge.name)
        if inp is not None and inp.periods == periods:
            return
        if inp is None:
            sub = self.session.declare_subscriber(
                thin_key(self.agent.realm, edge.name, self.agent.name),
                lambda sample, name=edge.name: self.on_thin(name, sample),
            )
            inp = self.thin[edge.name] = ThinInput(periods, 0, [], sub)
        inp.periods = periods
        self.declare_demands(edge.name, inp, self.offset_ns(edge.name))

    def declare_demands(self, edge: str, inp: ThinInput, offset_ns: int) -> None:
        """(Re)declare the demand tokens of a thinned input: the new ones first, so the
        sensor's agent keeps the stream while the grid moves."""
        old = inp.tokens
        inp.tokens = [
            self.session.liveliness().declare_token(
                demand_key(self.agent.realm, edge, self.agent.name, Grid(p, -offset_ns % p))
            )
            for p in sorted(inp.periods)
        ]
        inp.offset_ns = offset_ns
        for token in old:
            token.undeclare()

    def follow_clocks(self, tolerance_ns: int) -> None:
        """(Under the agent's lock) thinned inputs' demands follow the clock offsets."""
        import zenoh

        for edge, inp in self.thin.items():
            offset = self.offset_ns(edge)
            if abs(offset - inp.offset_ns) > tolerance_ns:
                try:
                    self.declare_demands(edge, inp, offset)
                except zenoh.ZError:
                    continue

    def ask_per_request(self, edge: Edge) -> None:
        """``pull_via: get``: a node asking the sensor's agent ``get/<edge>?t=`` per request."""
        self.sources[edge.name] = RemoteSource(edge.name)
        self.filters[edge.name] = RemoteGet(
            f"kf_{edge.name}",
            edge.motion,
            lambda t_ns, name=edge.name: self.fetch(name, t_ns),
            stamp_offset_ns=int(round(edge.stamp_offset_s * 1e9)),
        )

    def fetch(self, edge: str, t_ns: int) -> Measurement | None:
        """The remote sensor filter's answer at ``t_ns`` (this agent's clock) by a Zenoh query
        (0.5 s timeout): mapped onto this clock, with the offset's uncertainty through the
        relationship's velocity (a second query 1 ms earlier gives it)."""
        import zenoh

        rem = self.discovery.agent_of(edge)
        if rem is None:
            return None
        offset, sigma = 0, 0.0
        if self.cfg.clock_sync == "estimate":
            if not rem.clock.known:
                return None
            offset, sigma = rem.clock.offset_ns, rem.clock.sigma_s  # this minus remote
        realm = self.agent.realm
        try:
            w = remote_get(self.session, realm, f"get/{edge}", t_ns - offset, 0.5)
            pose = w.pose
            if sigma > 0:
                b = remote_get(self.session, realm, f"get/{edge}", t_ns - offset - 10**6, 0.5)
                xi = twist_between(
                    b.pose.position, b.pose.quaternion, pose.position, pose.quaternion, 1e-3
                )
                pose = UncertainPose(pose.pose, pose.covariance + time_error_covariance(xi, sigma))
        except (ValueError, zenoh.ZError):  # error reply, no reply, undecodable, session gone
            return None
        return Measurement(w.exposure_ns + offset, pose, w.origin_ns + offset)

    # -- data path ------------------------------------------------------------------------------
    def mapping(self, edge: str) -> tuple[int, float] | None:
        """This agent's clock minus the remote sensor's agent's [ns] (the timesync offset)
        and its sigma [s], mapping the sensor's stamps onto this clock (None: counted)."""
        rem = self.discovery.agent_of(edge)
        if rem is None:
            self.rejections.add("sensor not live")
            return None
        if self.cfg.clock_sync != "estimate":
            return 0, 0.0
        if not rem.clock.known:
            self.rejections.add("clock offset not yet estimated")
            return None
        return rem.clock.offset_ns, rem.clock.sigma_s

    def on_thin(self, edge: str, sample) -> None:
        """A message of a thinned stream: the tick it completes (attachment) and a state of
        the sensor's filter, or nothing new (heartbeat). The state is scheduled at its host
        stamp as on the full stream; the tick tells the query's ticker that this input is
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
        self.received[3] += bool(payload)
        try:
            s = wire.decode_state(payload) if payload else None
        except wire.WireError as exc:
            self.rejections.add(exc.reason)
            return
        mapping = self.mapping(edge)
        if mapping is None:
            return
        offset, sigma = mapping
        with self.sched.lock:
            inp = self.thin.get(edge)
            if inp is None:
                return  # withdrawn meanwhile
            covered = int.from_bytes(tick, "little", signed=True) + inp.offset_ns
            self.thin_arrivals.append(self.agent.now_ns() - covered)
            if inp.covered_ns is None or covered > inp.covered_ns:
                inp.covered_ns = covered
            if s is not None and self._plausible(edge, s, offset, sigma):
                self._schedule(edge, s, offset, sigma, 0)
            self.sched.wake()

    def on_batch(self, agent: str, sample) -> None:
        """A batch of another agent's sensor filters' states: each state of a sensor this
        agent replicates is taken (:meth:`on_state`); a state of a sensor that another agent
        provides is counted (``state of another agent's sensor``), the rest are not
        needed here."""
        payload = sample.payload.to_bytes()
        self.received[0] += 1
        self.received[1] += len(payload)
        try:
            entries = wire.decode_batch(payload)
        except wire.WireError as exc:
            self.rejections.add(exc.reason)
            return
        live = self.discovery.live
        for edge, state in entries:
            if self.subs.get(edge) == agent:
                self.on_state(edge, state)
            elif live.get(edge, agent) != agent:
                self.rejections.add("state of another agent's sensor")

    def on_state(self, edge: str, payload: bytes) -> None:
        """A state of another agent's sensor filter (a version-2 message): decoded, its
        stamps mapped onto this agent's clock, then adopted by the replica at once or
        (jitter buffer) at its host stamp plus ``reorder_ms``."""
        self.received[3] += 1
        try:
            s = wire.decode_state(payload)
        except wire.WireError as exc:
            self.rejections.add(exc.reason)
            return
        mapping = self.mapping(edge)
        if mapping is None:
            return
        offset, sigma = mapping
        if not self._plausible(edge, s, offset, sigma):
            return
        if self.agent.now_ns() - (s.stamp_ns + offset) > BACKLOG_NS:
            # a sender that stalled and now flushes what it held: no use for any answer
            self.rejections.add("older than the backlog window")
            return
        if self._reorder_ns <= 0:
            with self.sched.arrival(self.agent.now_ns()) as arr:
                if arr is not None:  # at its dispatch time (the dataflow's clock is set)
                    arr.deliver(1, lambda _i, _j, _a: self.deliver(edge, s, offset, sigma))
            return
        with self.sched.lock:
            if self.cfg.thin:  # every state sent before it has come (thin: ticks wait for it)
                self.covered[edge] = max(self.covered.get(edge, -1), s.host_ns + offset - 1)
            self._schedule(edge, s, offset, sigma, 0 if self.cfg.thin else self._reorder_ns)

    @property
    def lost_messages(self) -> int:
        """States missing from the remote sensors' sequences (gaps, not jumps)."""
        return self.sequences.lost

    def _plausible(self, edge: str, s: wire.StateSample, offset: int, sigma: float) -> bool:
        """:mod:`.plausibility` of a decoded state; a counted rejection if not."""
        why = state_problem(s.stamp_ns + offset, self.agent.now_ns(), sigma, s.p)
        if why is None and not self.sequences.take(edge, s.seq):
            why = "sequence jump"
        if why is not None:
            self.rejections.add(why)
            return False
        return True

    def _schedule(self, edge, s: wire.StateSample, offset: int, sigma: float, delay: int) -> None:
        """(Holding the lock.) To the scheduler at the state's arrival stamp, released
        ``delay`` after it (the jitter buffer)."""
        arrival = s.host_ns + offset
        if self.agent.now_ns() > arrival + self._reorder_ns:
            self.late_events += 1  # later than the jitter buffer: delivered out of order
        self.sched.post(arrival, lambda _t: self.deliver(edge, s, offset, sigma), SAMPLE, delay)

    def deliver(self, edge: str, s: wire.StateSample, offset_ns: int, sigma_s: float) -> None:
        kf = self.filters.get(edge)
        if isinstance(kf, RemoteFilter):
            kf.last_judged = []
            kf.adopt(s, offset_ns, sigma_s)
            for why in kf.last_judged:  # the innovation check's reasons, agent-wide too
                self.rejections.add(why)

    def complete(self, inputs: frozenset, t_ns: int) -> bool:
        """(thin) Every remote input has sent what a tick at ``t_ns`` needs."""
        for e in inputs:
            inp = self.thin.get(e)
            covered = inp.covered_ns if inp is not None else self.covered.get(e)
            if covered is None or covered < t_ns:
                return False
        return True

    def status(self) -> dict:
        return {
            "replicas": {
                n: {
                    "states": f.stats.events_in,
                    "rejections": dict(f.stats.rejections),
                    "innovations": f.innovations.status(),
                }
                for n, f in sorted(self.filters.items())
                if isinstance(f, RemoteFilter)
            },
            "thin_inputs": {
                e: {"periods_ns": sorted(inp.periods), "offset_ns": inp.offset_ns}
                for e, inp in sorted(self.thin.items())
            },
        }


def remote_get(session, realm: str, key: str, t_ns: int, timeout_s: float = 2.0):
    """Ask ``trackflow/<realm>/<key>?t=<t_ns>`` (``query/<name>`` or ``get/<edge>``) over a
    Zenoh session; returns a :class:`trackflow.distributed.wire.WireSample` or raises
    ``ValueError`` with the remote's reason (or "no reply")."""
    errors = []
    for reply in session.get(f"{realm_key(realm, key)}?t={int(t_ns)}", timeout=timeout_s):
        if reply.ok is not None:
            return wire.decode(reply.ok.payload.to_bytes())
        errors.append(reply.err.payload.to_bytes().decode(errors="replace"))
    raise InputError(f"{key} at t={t_ns}: " + ("; ".join(errors) or "no reply"))
