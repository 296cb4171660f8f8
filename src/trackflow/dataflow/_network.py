"""The network of components; :meth:`Network.run` drives it on the one scheduler.

Recordings' samples arrive at their arrival time (sample stamp + latency) and samplers tick
at their rate, both as event sources of :class:`trackflow.dataflow.Scheduler`, which
dispatches them in one order (a sample before a tick at equal times, then insertion order)
on a virtual clock (as fast as possible) or on the wall clock (each event waits for its
time). Every component runs in the dispatching thread, so results depend only on the order
of events, and the two modes give the same answers.
"""

from __future__ import annotations

import time as _time

from ..errors import InputError
from ..scheduler import Scheduler, Ticker, WallTime
from ._component import Component, _Clock
from ._processing import Sampler
from ._sources import PlayerSource, RecordingPlayer

__all__ = ["Network"]


class Network:
    """Components and their push/pull connections; :meth:`run` drives them.

    Examples
    --------
    >>> from trackflow import Pose, UncertainPose
    >>> from trackflow.dataflow import Network, StaticPose, PullSink
    >>> net = Network()
    >>> s = net.add(StaticPose("calib", UncertainPose.exact(Pose.identity())))
    >>> app = net.add(PullSink("app"))
    >>> net.connect(s, app)
    >>> app.get(5).t_ns
    5
    """

    def __init__(self, clock: _Clock | None = None):
        self.components: dict[str, Component] = {}
        #: the time every component reads (a runtime may share one across networks)
        self.clock = _Clock() if clock is None else clock
        self._edges: list[tuple[str, str, str, int]] = []

    def add(self, component: Component) -> Component:
        """Add a component (names must be unique); returns it."""
        if component.name in self.components:
            raise InputError(f"duplicate component name {component.name!r}")
        component.clock = self.clock
        self.components[component.name] = component
        return component

    def __getitem__(self, name: str) -> Component:
        try:
            return self.components[name]
        except KeyError:
            raise InputError(f"no component {name!r} in the network") from None

    def connect(
        self, src: Component, dst: Component, mode: str | None = None, port: int | None = None
    ) -> None:
        """Connect ``src`` to ``dst``.

        ``mode`` is ``"pull"`` (``dst`` calls ``src.pull``), ``"push"`` (``src`` calls
        ``dst.push``) or ``None``: pull when both ends have pull ports, else push. ``port``
        is the push input index (default: the next free one).

        Raises ``ValueError`` for components of another network, incompatible ports, too many
        inputs or a connection that would close a cycle.
        """
        for c in (src, dst):
            if self.components.get(c.name) is not c:
                raise InputError(f"component {c.name!r} is not part of this network")
        pull_ok = src.pull_out and dst.pull_in != 0
        push_ok = src.push_out and dst.push_in != 0
        if mode is None:
            mode = "pull" if pull_ok else "push"
        if mode not in ("pull", "push") or not (pull_ok if mode == "pull" else push_ok):
            raise InputError(
                f"cannot connect {src.describe()} to {dst.describe()} by {mode}: no matching ports"
            )
        self._check_acyclic(src, dst)
        if mode == "push":
            n = sum(1 for e in self._edges if e[1] == dst.name and e[2] == "push")
            if 0 < dst.push_in <= n:
                raise InputError(f"{dst.name!r} accepts only {dst.push_in} push input(s)")
            p = n if port is None else int(port)
            src.consumers.append((dst, p))
            self._edges.append((src.name, dst.name, "push", p))
        else:
            if 0 < dst.pull_in <= len(dst.inputs):
                raise InputError(f"{dst.name!r} accepts only {dst.pull_in} pull input(s)")
            dst.inputs.append(src)
            self._edges.append((src.name, dst.name, "pull", len(dst.inputs) - 1))

    def _check_acyclic(self, src: Component, dst: Component) -> None:
        # Data flows src -> dst; a path dst -> ... -> src would close a loop.
        succ: dict[str, list[str]] = {}
        for a, b, _, _ in self._edges:
            succ.setdefault(a, []).append(b)
        stack, seen = [dst.name], set()
        while stack:
            n = stack.pop()
            if n == src.name:
                raise InputError(f"connecting {src.name!r} -> {dst.name!r} would create a cycle")
            if n not in seen:
                seen.add(n)
                stack.extend(succ.get(n, []))

    @property
    def connections(self) -> list[tuple[str, str, str, int]]:
        """``(source, destination, "push"|"pull", port)`` of every connection."""
        return list(self._edges)

    def stats(self) -> dict[str, dict]:
        """Statistics summary per component."""
        return {name: c.stats.summary() for name, c in self.components.items()}

    # -- running --------------------------------------------------------------------------------
    def players(self) -> list[RecordingPlayer]:
        """The recordings (and simulated sensors) of the network."""
        return [c for c in self.components.values() if isinstance(c, RecordingPlayer)]

    def samplers(self) -> list[Sampler]:
        """The samplers (push queries' ticks) of the network."""
        return [c for c in self.components.values() if isinstance(c, Sampler)]

    def span(self, until_ns: int | None = None) -> tuple[int, int]:
        """``(first arrival, until_ns or last arrival)`` of the recordings [ns]."""
        players = self.players()
        if not players:
            raise InputError("the network has no sensor or recording to run")
        arrivals = [p.arrivals() for p in players if len(p.t_ns)]
        if not arrivals:
            raise InputError("every recording in the network is empty")
        start = min(int(a.min()) for a in arrivals)
        end = max(int(a.max()) for a in arrivals) if until_ns is None else int(until_ns)
        return start, end

    def reset(self) -> None:
        for c in self.components.values():
            c.reset()

    def finish(self) -> None:
        """End of a run: every component flushes (recorders close their files)."""
        for c in self.components.values():
            c.finish()

    def scheduler(
        self,
        start_ns: int,
        end_ns: int | None = None,
        time: WallTime | None = None,
        max_tick_lag_ns: int | None = None,
    ) -> Scheduler:
        """A :class:`Scheduler` on this network's clock with every recording and sampler of
        the network as an event source (samplers tick from ``start_ns`` on their grid, up to
        ``end_ns``); a runtime adds its live sources to it."""
        sched = Scheduler(self.clock, time)
        for p in self.players():
            sched.add(PlayerSource(p, end_ns))
        for s in self.samplers():
            first = Ticker.first_at_or_after(s.start_ns, s.period_ns, start_ns)
            sched.add(Ticker(s.name, s.tick, s.period_ns, first, end_ns, max_tick_lag_ns))
        return sched

    def run(
        self,
        until_ns: int | None = None,
        realtime: bool = False,
        speed: float = 1.0,
        stop=None,
        repeat: bool = False,
    ):
        """Play every source and tick every sampler until ``until_ns`` (default: last arrival).

        Parameters
        ----------
        realtime : bool
            False: virtual clock, as fast as possible. True: wall clock; ``speed`` > 1 plays
            faster than real time. Both dispatch the same events in the same order.
        stop : threading.Event, optional
            Ends a run early when set.
        repeat : bool
            Start over (components reset) after each pass until ``stop`` is set (a live
            view of recordings).
        """
        start, end = self.span(until_ns)
        while True:
            self.reset()
            wall = WallTime(_time.perf_counter_ns, start, speed) if realtime else None
            try:
                self.scheduler(start, end, wall).run(end, stop=stop)
            finally:
                self.finish()
            if not repeat or stop is None or stop.is_set():
                return self
