"""The network of components and its scheduler (virtual clock or wall clock).

Both modes dispatch the same kinds of events in the same order - sensor samples at their
arrival time (sample stamp + latency) and sampler ticks - and every component runs in the
dispatching thread, so results depend only on the order of events. The virtual clock orders
them exactly (sensor events before ticks at equal times, then insertion order) and runs as
fast as possible; the real-time mode plays every source in its own thread, sleeping until the
arrival time on the wall clock, so near-simultaneous events can swap order and results agree
within a tolerance instead of bit for bit.
"""

from __future__ import annotations

import heapq
import queue
import threading
import time

from ._component import Component, _Clock
from ._processing import Sampler
from ._sources import RecordingPlayer

__all__ = ["Network"]

_SENSOR, _TICK = 0, 1


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

    def __init__(self):
        self.components: dict[str, Component] = {}
        self.clock = _Clock()
        self._edges: list[tuple[str, str, str, int]] = []

    def add(self, component: Component) -> Component:
        """Add a component (names must be unique); returns it."""
        if component.name in self.components:
            raise ValueError(f"duplicate component name {component.name!r}")
        component.clock = self.clock
        self.components[component.name] = component
        return component

    def __getitem__(self, name: str) -> Component:
        try:
            return self.components[name]
        except KeyError:
            raise ValueError(f"no component {name!r} in the network") from None

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
                raise ValueError(f"component {c.name!r} is not part of this network")
        pull_ok = src.pull_out and dst.pull_in != 0
        push_ok = src.push_out and dst.push_in != 0
        if mode is None:
            mode = "pull" if pull_ok else "push"
        if mode not in ("pull", "push") or not (pull_ok if mode == "pull" else push_ok):
            raise ValueError(
                f"cannot connect {src.describe()} to {dst.describe()} by {mode}: no matching ports"
            )
        self._check_acyclic(src, dst)
        if mode == "push":
            n = sum(1 for e in self._edges if e[1] == dst.name and e[2] == "push")
            if 0 < dst.push_in <= n:
                raise ValueError(f"{dst.name!r} accepts only {dst.push_in} push input(s)")
            p = n if port is None else int(port)
            src.consumers.append((dst, p))
            self._edges.append((src.name, dst.name, "push", p))
        else:
            if 0 < dst.pull_in <= len(dst.inputs):
                raise ValueError(f"{dst.name!r} accepts only {dst.pull_in} pull input(s)")
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
                raise ValueError(f"connecting {src.name!r} -> {dst.name!r} would create a cycle")
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
    def _players(self) -> list[RecordingPlayer]:
        return [c for c in self.components.values() if isinstance(c, RecordingPlayer)]

    def _samplers(self) -> list[Sampler]:
        return [c for c in self.components.values() if isinstance(c, Sampler)]

    def _span(self, until_ns: int | None) -> tuple[int, int]:
        players = self._players()
        if not players:
            raise ValueError("the network has no sensor or recording to run")
        arrivals = [p.arrivals() for p in players if len(p.t_ns)]
        if not arrivals:
            raise ValueError("every recording in the network is empty")
        start = min(int(a.min()) for a in arrivals)
        end = max(int(a.max()) for a in arrivals) if until_ns is None else int(until_ns)
        return start, end

    def reset(self) -> None:
        for c in self.components.values():
            c.reset()

    def run(self, until_ns: int | None = None, realtime: bool = False, speed: float = 1.0):
        """Play every source and tick every sampler until ``until_ns`` (default: last arrival).

        Parameters
        ----------
        realtime : bool
            False: virtual clock, as fast as possible, deterministic. True: wall clock, every
            source in its own thread; ``speed`` > 1 plays faster than real time.
        """
        start, end = self._span(until_ns)
        self.reset()
        try:
            if realtime:
                self._run_realtime(start, end, float(speed))
            else:
                self._run_virtual(start, end)
        finally:
            for c in self.components.values():
                c.finish()
        return self

    def _run_virtual(self, start: int, end: int) -> None:
        heap: list = []
        seq = 0
        iters = [p.events() for p in self._players()]

        def refill(i: int) -> None:
            nonlocal seq
            nxt = next(iters[i], None)
            if nxt is not None and nxt[0] <= end:
                heapq.heappush(heap, (nxt[0], _SENSOR, i, seq, nxt[1]))
                seq += 1

        for i in range(len(iters)):
            refill(i)
        samplers = self._samplers()
        for s_idx, s in enumerate(samplers):
            t0 = self._first_tick(s, start)
            if t0 <= end:
                heapq.heappush(heap, (t0, _TICK, s_idx, seq, None))
                seq += 1
        players = self._players()
        clock = self.clock
        while heap:
            t, kind, i, _, payload = heapq.heappop(heap)
            clock.now_ns = t
            clock.dispatch_wall_ns = time.perf_counter_ns()
            if kind == _SENSOR:
                players[i].deliver(payload)
                refill(i)
            else:
                s = samplers[i]
                s.tick(t)
                if t + s.period_ns <= end:
                    heapq.heappush(heap, (t + s.period_ns, _TICK, i, seq, None))
                    seq += 1

    @staticmethod
    def _first_tick(s: Sampler, start: int) -> int:
        if s.start_ns >= start:
            return s.start_ns
        return s.start_ns + -((s.start_ns - start) // s.period_ns) * s.period_ns

    def _run_realtime(self, start: int, end: int, speed: float) -> None:
        if not speed > 0:
            raise ValueError("speed must be > 0")
        q: queue.Queue = queue.Queue()
        wall0 = time.perf_counter_ns()
        stop = threading.Event()

        def wall_at(t: int) -> float:
            return wall0 + (t - start) / speed

        def play(i: int, player: RecordingPlayer) -> None:
            for arrival, idx in player.events():
                if arrival > end or stop.is_set():
                    break
                delay = (wall_at(arrival) - time.perf_counter_ns()) * 1e-9
                if delay > 0:
                    time.sleep(delay)
                q.put((arrival, i, idx))
            q.put((None, i, None))

        players = self._players()
        threads = [
            threading.Thread(target=play, args=(i, p), daemon=True) for i, p in enumerate(players)
        ]
        samplers = self._samplers()
        next_tick = [self._first_tick(s, start) for s in samplers]
        running = len(threads)
        for th in threads:
            th.start()
        clock = self.clock
        try:
            while running or any(t <= end for t in next_tick):
                k = min(range(len(samplers)), key=lambda j: next_tick[j], default=None)
                due = next_tick[k] if k is not None and next_tick[k] <= end else None
                timeout = None
                if due is not None:
                    timeout = max(0.0, (wall_at(due) - time.perf_counter_ns()) * 1e-9)
                try:
                    arrival, i, idx = q.get(timeout=timeout) if running else (None, -1, None)
                    if i < 0:
                        raise queue.Empty
                except queue.Empty:
                    if due is None:
                        break
                    if running == 0:
                        delay = (wall_at(due) - time.perf_counter_ns()) * 1e-9
                        if delay > 0:
                            time.sleep(delay)
                    clock.now_ns = due
                    clock.dispatch_wall_ns = time.perf_counter_ns()
                    samplers[k].tick(due)
                    next_tick[k] += samplers[k].period_ns
                    continue
                if arrival is None:
                    running -= 1
                    continue
                clock.now_ns = arrival
                clock.dispatch_wall_ns = time.perf_counter_ns()
                players[i].deliver(idx)
        finally:
            stop.set()
            for th in threads:
                th.join(timeout=5.0)
