"""A realm watched read-only and kept current: what ``trackflow view --realm NAME`` draws.

A :class:`RealmWatch` joins a realm's Zenoh key space with a session of its own and declares
nothing (no token, queryable or publisher: an observer). It keeps, behind one lock:

* the agents alive (their ``agent/<name>`` liveliness tokens) and the sensors each
  advertises live (``alive/<agent>/<edge>`` tokens), as Zenoh reports them;
* each agent's fragment of the graph (its edges, fetched once per join): their union is the
  realm's graph;
* each agent's status (its ``status/<name>`` queryable, asked of every agent at once,
  :func:`~trackflow.distributed.realm_status.agent_statuses`) every ``period_s`` on a thread
  of its own, and at once when an agent joins: inputs, measured attributes, queries with
  their paths, switches and re-plans;
* the newest answer of every query (``result/<agent>/<query>``, decoded with
  :func:`trackflow.distributed.wire.decode`; a message that does not decode is a counted
  rejection);
* the realm's events in order, each with its host time: an agent that joins or leaves, a
  sensor that goes up or down, a query re-planned or switched (with the agent's reason).
  Re-plans arrive as they happen (each agent publishes them on ``event/<agent>``); the
  status poll finds the same events again (taken once) and those of an agent whose message
  was lost.

:meth:`RealmWatch.snapshot` gives all of it as plain data (:mod:`trackflow.viewer.realm_page`
draws it; nothing here knows the viewer).
"""

from __future__ import annotations

import json
import threading
import time
from collections import deque

from .discovery import alive_token, realm_key
from .fragment import first_fragment
from .realm_status import agent_statuses
from .wire import Rejections, WireError, decode

__all__ = ["RealmWatch"]

#: events the watch remembers (the newest)
EVENTS = 200


class RealmWatch:
    """The realm ``realm`` seen through ``session`` (a Zenoh session), read-only (module
    docstring). Start with :meth:`start`, end with :meth:`close`."""

    def __init__(self, session, realm: str, *, period_s: float = 0.5, timeout_s: float = 1.0):
        self.session, self.realm = session, realm
        self.period_s, self.timeout_s = float(period_s), float(timeout_s)
        self.rejections = Rejections()
        self._lock = threading.Lock()
        self._alive: set[str] = set()
        self._live_edges: dict[str, str] = {}  # edge -> agent advertising it live
        self._fragments: dict[str, tuple[list, list]] = {}  # agent -> (frames, edges)
        self._statuses: dict[str, dict] = {}
        self._answers: dict[str, dict] = {}  # "agent/query" -> the newest answer
        self._events: deque = deque(maxlen=EVENTS)
        self._seen: set[tuple] = set()  # status events already taken
        self._stop = threading.Event()
        self._wake = threading.Event()  # an agent joined: poll now (its fragment, status)
        self._thread: threading.Thread | None = None
        self._handles: list = []

    # -- Zenoh callbacks (Zenoh's threads: short) ------------------------------------------------
    def _event(self, text: str, t_ns: int | None = None) -> None:
        with self._lock:
            self._events.append({"t_ns": time.time_ns() if t_ns is None else int(t_ns),
                                 "text": text})  # fmt: skip

    def _on_agent(self, sample) -> None:
        import zenoh

        name = str(sample.key_expr).rsplit("/", 1)[-1]
        if sample.kind == zenoh.SampleKind.DELETE:
            with self._lock:
                self._alive.discard(name)
                self._fragments.pop(name, None)
            self._event(f"agent {name} left")
        else:
            with self._lock:
                self._alive.add(name)
            self._event(f"agent {name} joined")
            self._wake.set()

    def _on_edge(self, sample) -> None:
        token = alive_token(sample)
        if token is None:
            self.rejections.add("malformed liveliness key")
            return
        agent, edge, gone = token
        if gone:
            with self._lock:
                if self._live_edges.get(edge) == agent:
                    del self._live_edges[edge]
            self._event(f"sensor {edge} of {agent} down")
        else:
            with self._lock:
                self._live_edges[edge] = agent
            self._event(f"sensor {edge} of {agent} up")

    def _on_result(self, sample) -> None:
        parts = str(sample.key_expr).split("/")
        if len(parts) != 5:
            self.rejections.add("malformed result key")
            return
        try:
            m = decode(sample.payload.to_bytes())
        except WireError as exc:
            self.rejections.add(f"result: {exc.reason}")
            return
        p = m.pose
        answer = {
            "t_ns": m.exposure_ns,
            "path": m.path,
            "position": p.position.tolist(),
            "quaternion": p.quaternion.tolist(),
            "covariance": p.covariance.tolist(),
        }
        with self._lock:
            self._answers[f"{parts[3]}/{parts[4]}"] = answer

    def _on_replan(self, sample) -> None:
        """A re-plan event an agent published (``event/<agent>``, JSON)."""
        agent = str(sample.key_expr).rsplit("/", 1)[-1]
        try:
            ev = json.loads(sample.payload.to_bytes())
            query, t_ns = str(ev["query"]), int(ev["t_ns"])
        except (ValueError, KeyError, TypeError):
            self.rejections.add("event: malformed")
            return
        self._take_replans([(agent, query, {**ev, "t_ns": t_ns})])

    def _take_replans(self, replans: list[tuple[str, str, dict]]) -> None:
        """``(agent, query, event)`` re-plans as events, each once (the message and the
        status poll both bring it)."""
        new = []
        with self._lock:
            for agent, q, ev in replans:
                key = (agent, q, "replan", ev.get("t_ns"), ev.get("reason"))
                if ev.get("t_ns") is not None and key not in self._seen:
                    self._seen.add(key)
                    new.append({"t_ns": int(ev["t_ns"]), "text": f"{agent}: query {q} "
                                f"re-planned ({ev.get('reason')}): {ev.get('state')}"})  # fmt: skip
            self._events.extend(sorted(new, key=lambda e: e["t_ns"]))

    # -- the polling thread --------------------------------------------------------------------
    def start(self) -> RealmWatch:
        """Subscribe (with the tokens already declared) and start polling the statuses."""
        s, r = self.session, self.realm
        live = s.liveliness()
        self._handles = [
            live.declare_subscriber(realm_key(r, "agent", "*"), self._on_agent, history=True),
            live.declare_subscriber(realm_key(r, "alive", "**"), self._on_edge, history=True),
            s.declare_subscriber(realm_key(r, "result", "**"), self._on_result),
            s.declare_subscriber(realm_key(r, "event", "*"), self._on_replan),
        ]
        self._thread = threading.Thread(target=self._loop, name="realm-watch", daemon=True)
        self._thread.start()
        return self

    def _loop(self) -> None:
        while not self._stop.is_set():
            self._wake.clear()
            self.poll()
            self._wake.wait(self.period_s)  # or at once when an agent joins (or at close)

    def poll(self) -> None:
        """Ask every agent's status and the fragments of agents not fetched yet (what the
        thread does every ``period_s``)."""
        with self._lock:
            alive = sorted(self._alive)
            missing = [a for a in alive if a not in self._fragments]
        fragments = {  # asked before the statuses are waited for: both at once
            a: self.session.get(realm_key(self.realm, "fragment", a), timeout=self.timeout_s)
            for a in missing
        }
        statuses = agent_statuses(self.session, self.realm, alive, self.timeout_s)
        for agent, replies in fragments.items():
            self._take_fragment(agent, replies)
        replans, new = [], []
        with self._lock:
            self._statuses = statuses
            for agent, st in statuses.items():
                for q, qs in (st.get("queries") or {}).items():
                    replans += [(agent, q, ev) for ev in qs.get("events", [])]
                    for sw in qs.get("switches", []):
                        key = (agent, q, "switch", sw.get("t_ns"), sw.get("to"))
                        if key not in self._seen:
                            self._seen.add(key)
                            move = f"{sw.get('from')} -> {sw.get('to')} ({sw.get('reason')})"
                            new.append({"t_ns": int(sw.get("t_ns", 0)),
                                        "text": f"{agent}: query {q} path {move}"})  # fmt: skip
            self._events.extend(sorted(new, key=lambda e: e["t_ns"]))
        self._take_replans(replans)

    def _take_fragment(self, agent: str, replies) -> None:
        got = first_fragment(replies, self.rejections)
        if got is not None:
            with self._lock:
                self._fragments[agent] = (list(got[0]), list(got[1]))

    def snapshot(self) -> dict:
        """The realm as plain data: ``{"realm", "agents": {name: status (``"alive"``
        added)}, "frames": [...], "edges": [{"name", "source", "target", "kind", "agent",
        "live"}], "answers": {"agent/query": {"t_ns", "path", "position", "quaternion",
        "covariance"}}, "events": [{"t_ns", "text"}] (oldest first), "rejections"}``."""
        with self._lock:
            agents = {a: {**st, "alive": a in self._alive} for a, st in self._statuses.items()}
            for a in self._alive:
                agents.setdefault(a, {"alive": True, "error": "no status yet"})
            frames: list[str] = []
            edges = []
            for agent, (fr, es) in sorted(self._fragments.items()):
                frames += [f for f in fr if f not in frames]
                for e in es:
                    for f in (e.source, e.target):
                        if f not in frames:
                            frames.append(f)
                    edges.append({"name": e.name, "source": e.source, "target": e.target,
                                  "kind": e.kind, "agent": agent,
                                  "live": self._live_edges.get(e.name) == agent})  # fmt: skip
            return {
                "realm": self.realm,
                "agents": agents,
                "frames": frames,
                "edges": edges,
                "answers": dict(self._answers),
                "events": sorted(self._events, key=lambda ev: ev["t_ns"]),
                "rejections": dict(self.rejections.counts),
            }

    def close(self) -> None:
        """Stop polling and undeclare the subscribers."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        for h in self._handles:
            h.undeclare()
        self._handles = []
