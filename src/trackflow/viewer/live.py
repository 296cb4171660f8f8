"""The live view of a running :class:`trackflow.dataflow.Network` (thesis 8.2).

:func:`attach_view` wires :class:`~trackflow.viewer.monitor.Tap` components behind every
sensor (behind its filter when it has one) and behind each query's answers (a push query's
own sampler; a pull query gets a view sampler at the view rate); while a prediction offset
is set, a query's tap also pulls the query's output that far ahead (the prediction ghost), at
most at the view rate. The taps write into a shared memory
:class:`~trackflow.viewer.board.Board`; a separate view process
(:mod:`trackflow.viewer.live_process`, started here at a lower scheduling priority) serves the
page and draws from the board at the view rate. The dataflow thread never waits for the view
and never shares an interpreter lock with it: per event it does a few scalar stores, and at
most at the view rate one filter prediction and a pose record. A feeder thread in the
dataflow process hands the network clock and the counted rejections over a few times a second
and applies the prediction slider of the pages (one offset for every tab).
"""

from __future__ import annotations

import math
import os
import queue
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from pathlib import Path

import numpy as np

from ..dataflow import KalmanFilter, Network, PathSwitch, Plan, RecordingPlayer, Sampler, Setup
from ..errors import InputError, MissingExtraError, PlanError, ServiceError
from ..optional import available
from .attributes_panel import gather
from .board import Board
from .edges import EdgeLayout, EdgeMonitor, QueryLayout, ViewLayout, default_anchor
from .graph_panel import EdgeStatus
from .live_process import PRIORITIES
from .monitor import Tap
from .scene import Style

__all__ = ["LiveView", "SensorInfo", "attach_view"]

#: ``() -> {edge name: {"rejections": {reason: count}, "offset_ms": float}}``: what a live
#: runtime knows of its sensors beyond the network (a tracker's rejected packets, its measured
#: clock offset), merged into the graph panel.
SensorInfo = Callable[[], dict[str, dict]]

_FEED_PERIOD_S = 0.1
_STATS_EVERY = 5  # feeder periods between rejection reports
_ATTRIBUTES_EVERY = 20  # ... and between measured attributes (each costs a few ms)


def _start_process(timeout_s: float):
    """Start the view process (``python -m trackflow.viewer.live_process FD``) connected by a
    socket pair; returns ``(Popen, Connection)``. A fresh interpreter rather than
    :mod:`multiprocessing`: nothing of the caller's main module is re-imported (a script
    without a ``__main__`` guard works), and no process with running threads is forked."""
    here, there = socket.socketpair()
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[2])  # the directory holding trackflow
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "trackflow.viewer.live_process", str(there.fileno())],
            pass_fds=(there.fileno(),), env=env, stdin=subprocess.DEVNULL,
        )  # fmt: skip
    finally:
        there.close()
    here.setblocking(True)
    return proc, Connection(os.dup(here.fileno())), here


class LiveView:
    """The dataflow side of a live view (made by :func:`attach_view`): its taps and board,
    the view process, and the controls as a Python API.

    Attributes
    ----------
    url : str
        The page.
    layout : ViewLayout
    pid : int
        The view process.
    """

    def __init__(
        self,
        network: Network,
        layout: ViewLayout,
        board: Board,
        taps: dict[str, list],
        query_taps: list[Tap],
        *,
        host: str,
        port: int,
        rate_hz: float,
        style: Style | None,
        sensor_info: SensorInfo | None = None,
        priority: str = "low",
        timeout_s: float = 120.0,
        filters: dict | None = None,
        switches: dict | None = None,
    ):
        if not 1.0 <= rate_hz <= 120.0:
            raise InputError(f"view rate must be in [1, 120] Hz, got {rate_hz}")
        self.network, self.layout, self.board = network, layout, board
        self._sources = taps  # edge name -> components whose rejections the panel shows
        self._query_taps = query_taps  # they pull the prediction ghost
        self.sensor_info = sensor_info
        self._filters = filters or {}  # sensor -> (its filter, its declared edge)
        self._switches = switches or {}  # query -> its PathSwitch (failover)
        self.rate_hz = float(rate_hz)
        self.monitor = EdgeMonitor(layout, board)
        self._selected_query = layout.queries[0].name if layout.queries else None
        self._paused = False
        self.offset_s = 0.0
        self._stop = threading.Event()
        self._send_lock = threading.Lock()
        self._reports: queue.Queue = queue.Queue()
        opts = {"host": host, "port": int(port), "rate_hz": self.rate_hz, "priority": priority,
                "style": style}  # fmt: skip
        if not available("viser"):  # said here, before a process is started for nothing
            board.close()
            raise MissingExtraError("viser", "viewer", "the viewer")
        self.process, self._conn, self._sock = _start_process(timeout_s)
        try:
            self._conn.send((layout, board.name, opts))
            self.url = self._await_ready(timeout_s)
        except BaseException:
            self._terminate()
            board.close()
            raise
        self.pid = self.process.pid
        self._feeder = threading.Thread(target=self._feed, daemon=True, name="trackflow-feed")
        self._feeder.start()

    def _await_ready(self, timeout_s: float) -> str:
        if not self._conn.poll(timeout_s):  # (the process is ended by the caller)
            raise ServiceError(f"the view process did not start within {timeout_s:.0f} s")
        try:
            msg = self._conn.recv()
        except EOFError:
            raise ServiceError("the view process ended while starting") from None
        if msg[0] != "ready":
            raise ServiceError(f"the view process failed: {msg[1]}")
        return msg[1]

    # -- the feeder thread -----------------------------------------------------------------------
    def rejections(self) -> tuple[dict[str, dict[str, int]], dict[str, float]]:
        """Counted rejections per edge (its source, its filter and, live, its tracker) and the
        measured clock offsets [ms] a live runtime reports."""
        rej: dict[str, dict[str, int]] = {}
        for name, comps in self._sources.items():
            r: dict[str, int] = {}
            for comp in comps:
                for k, v in dict(comp.stats.rejections).items():
                    r[k] = r.get(k, 0) + v
            rej[name] = r
        offsets: dict[str, float] = {}
        if self.sensor_info is not None:
            for name, info in self.sensor_info().items():
                r = rej.setdefault(name, {})
                for k, v in info.get("rejections", {}).items():
                    r[f"tracker: {k}"] = r.get(f"tracker: {k}", 0) + int(v)
                off = info.get("offset_ms")
                if off is not None and math.isfinite(off):
                    offsets[name] = float(off)
        return rej, offsets

    def attributes(self) -> dict:
        """The sensors' measured and declared attributes, their trackers' online delay
        corrections and the queries' paths and switches
        (:func:`trackflow.viewer.attributes_panel.gather`)."""
        corrections, online = {}, {}
        if self.sensor_info is not None:
            for name, info in self.sensor_info().items():
                if info.get("correction_ms") is not None:
                    corrections[name] = float(info["correction_ms"])
                if info.get("online"):
                    online[name] = info["online"]
        return gather(self._filters, self._switches, corrections, online)

    def _feed(self) -> None:
        """Every 100 ms the network clock to the board; every 500 ms the rejections, every
        2 s the measured attributes to the view (when they changed); the page's prediction
        slider to the taps when it moves."""
        clock, last, last_attrs, n = self.network.clock, None, None, 0
        while not self._stop.is_set():
            self.board.set_clock(clock.now_ns, clock.dispatch_wall_ns)
            if n % _STATS_EVERY == 0:
                stats = self.rejections()
                if stats != last:
                    last = stats
                    self._send(("stats", *stats))
            if n % _ATTRIBUTES_EVERY == 0 and (self._filters or self._switches):
                try:
                    attrs = self.attributes()
                except RuntimeError:  # a ring or switch changed while being read: next time
                    attrs = last_attrs
                if attrs != last_attrs:
                    last_attrs = attrs
                    self._send(("attributes", attrs))
            n += 1
            try:
                if self._conn.poll(_FEED_PERIOD_S):
                    msg = self._conn.recv()
                    if msg[0] == "offset":
                        self._move_samplers(float(msg[1]))
                    elif msg[0] == "report":
                        self._reports.put(msg[1])
            except (EOFError, OSError):
                break  # the view process ended

    def _send(self, msg) -> None:
        with self._send_lock:
            try:
                self._conn.send(msg)
            except (BrokenPipeError, OSError):
                pass  # the view process is gone (close() reports nothing more)

    # -- controls (the Python API: every open tab, and the settings of tabs opened later) -------
    @property
    def frames_sent(self) -> int:
        """View frames the view process pushed to its page."""
        return self.board.frames_sent

    @property
    def clients(self) -> int:
        """Browsers connected to the page (as the view process last saw)."""
        return self.board.clients

    @property
    def paused(self) -> bool:
        return self._paused

    @paused.setter
    def paused(self, value: bool) -> None:
        """Stop drawing in every tab (the dataflow runs on; the paths are kept)."""
        self._paused = bool(value)
        self._send(("set", {"paused": self._paused}))

    @property
    def selected_query(self) -> str | None:
        return self._selected_query

    @selected_query.setter
    def selected_query(self, name: str) -> None:
        self._selected_query = name
        self._send(("set", {"selected_query": name}))

    def set_sigma(self, sigma: float) -> None:
        """Sigma level (1, 2 or 3) of every ellipsoid."""
        self._send(("set", {"sigma": float(sigma)}))

    def set_magnify(self, magnify: float) -> None:
        """Draw every ellipsoid ``magnify`` times its size (1: true to scale)."""
        self._send(("set", {"magnify": float(magnify)}))

    def set_anchor(self, frame: str) -> None:
        """Draw the scene in ``frame`` (one of the layout's frames).

        Raises
        ------
        InputError
            If ``frame`` is not a frame of the view.
        """
        if frame not in self.layout.frames:
            raise InputError(f"anchor frame {frame!r} is not one of {self.layout.frames}")
        self._send(("set", {"anchor": frame}))

    def set_scene(self, **shown: bool) -> None:
        """Show or hide parts of the scene: ``follow``, ``show_grid``, ``show_path``,
        ``show_trail``, ``show_labels``, ``show_sensors``."""
        allowed = {"follow", "show_grid", "show_path", "show_trail", "show_labels",
                   "show_sensors"}  # fmt: skip
        unknown = set(shown) - allowed
        if unknown:
            raise InputError(f"no scene part {sorted(unknown)}; one of {sorted(allowed)}")
        self._send(("set", {k: bool(v) for k, v in shown.items()}))

    def scene_report(self, timeout_s: float = 30.0) -> dict:
        """What the oldest open tab shows now
        (:meth:`trackflow.viewer.live_scene.LiveScene.report`): the anchor, every body's
        colour and time without data, the labels and the camera they were laid out for; with
        no tab open, what a new tab starts from (no labels, no camera).

        Raises
        ------
        ServiceError
            If the view process does not answer within ``timeout_s``.
        """
        while not self._reports.empty():
            self._reports.get_nowait()
        self._send(("report",))
        try:
            return self._reports.get(timeout=timeout_s)
        except queue.Empty:
            raise ServiceError(f"the view process did not report within {timeout_s} s") from None

    def set_offset(self, offset_s: float) -> None:
        """Prediction offset [s]: each query is also drawn this far ahead of its own time."""
        self._move_samplers(offset_s)
        self._send(("set", {"offset_s": self.offset_s}))

    def _move_samplers(self, offset_s: float) -> None:
        off = int(round(max(0.0, float(offset_s)) * 1e9))
        for tap in self._query_taps:
            tap.ahead_ns = off  # one int store each
        self.offset_s = off * 1e-9

    def edge_statuses(self, now_ns: int | None = None) -> list[EdgeStatus]:
        """The graph panel's view of every edge and of every query without a path."""
        now_ns = self.network.clock.now_ns if now_ns is None else now_ns
        return self.monitor.statuses(now_ns, *self.rejections(), self._selected_query)

    def wait_frames(self, n: int, timeout_s: float = 30.0) -> bool:
        """Wait until the view process has drawn ``n`` frames (bounded); True if it did."""
        end = time.monotonic() + timeout_s
        while self.frames_sent < n:
            if time.monotonic() > end or self.process.poll() is not None:
                return False
            time.sleep(0.02)
        return True

    def close(self) -> None:
        """Stop the view process and the feeder (the network keeps its taps; they are cheap,
        and write into a board that is gone: do not run the network with them afterwards)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._send(("stop",))
        self._feeder.join(timeout=2.0)
        self._terminate()
        self._conn.close()
        self._sock.close()
        for tap in self._taps():
            tap.board = _ClosedBoard()
        time.sleep(0.02)  # a tap in the middle of a write finishes it (microseconds)
        self.board.close()

    def _taps(self) -> list[Tap]:
        return [c for c in self.network.components.values() if isinstance(c, Tap)]

    def _terminate(self) -> None:
        try:
            self.process.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            self.process.terminate()
            try:
                self.process.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                # SIGKILL cannot be refused, but a process of low priority on a busy machine
                # may wait seconds to be scheduled and die
                self.process.kill()
                self.process.wait(timeout=120.0)


class _ClosedBoard:
    """Stands in for a closed board: taps of a closed view write nothing."""

    def __getattr__(self, name):
        return lambda *a, **k: 0


def _component(network: Network, plan: Plan, prefix: str, node_id: str):
    comp = network.components.get(prefix + node_id) or network.components.get(node_id)
    if comp is None:
        raise PlanError(f"query {plan.query.name!r}: no component {node_id!r} in the network")
    return comp


def _query_ends(network: Network, plan: Plan, prefix: str):
    """``(pull-able component feeding the query's sink, the query's own sampler or None)``."""
    src = plan.node(plan.output).inputs[0][0]
    sampler = None
    if plan.node(src).kind == "sampler":
        sampler = _component(network, plan, prefix, src)
        src = plan.node(src).inputs[0][0]
    return _component(network, plan, prefix, src), sampler


def _sources(network: Network) -> dict:
    """Components that push and are fed by nothing (recording players, simulated and live
    sensors), by name."""
    fed = {c.name for comp in network.components.values() for c, _ in comp.consumers}
    return {
        n: c
        for n, c in network.components.items()
        if c.push_out and n not in fed and not c.inputs and not isinstance(c, Sampler)
    }


class _Wiring:
    """Adds taps and view samplers to a network, one board slot each."""

    def __init__(self, network: Network, rate_hz: float):
        self.network = network
        self.period_ns = int(round(1e9 / rate_hz))
        self.taps: list[tuple[str, object, object]] = []  # (name, behind, kalman)

    def tap(self, comp, name: str | None, kalman=None, ahead=None) -> int:
        """A board slot, with a tap named ``name`` behind ``comp`` (None: a slot only)."""
        self.taps.append((name, comp, kalman, ahead))
        return len(self.taps) - 1

    def build(self) -> tuple[Board, dict[str, Tap]]:
        board = Board.create(len(self.taps))
        taps = {}
        try:
            for slot, (name, comp, kalman, ahead) in enumerate(self.taps):
                if name is not None:
                    tap = Tap(name, board, slot, self.period_ns, kalman, ahead)
                    taps[name] = self.network.add(tap)
                    self.network.connect(comp, tap, mode="push")
        except ValueError:  # a network that has a view already: names taken
            board.close()
            raise
        return board, taps


def attach_view(
    network: Network,
    setup: Setup | None = None,
    plans: dict[str, tuple[Plan, str]] | None = None,
    *,
    host: str = "127.0.0.1",
    port: int = 8080,
    rate_hz: float = 30.0,
    style: Style | None = None,
    errors: dict[str, str] | None = None,
    sensor_info: SensorInfo | None = None,
    priority: str = "low",
    anchor: str | None = None,
) -> LiveView:
    """Attach a browser view to ``network`` (before it runs); returns the :class:`LiveView`.

    Parameters
    ----------
    network : Network
        Any network. A measured edge's sensor is the component named like the edge (a
        recording player, a simulated sensor, a live tracker's source). Without ``setup``
        every source is drawn as a relationship ``world -> source`` (its raw measurements).
    setup : Setup, optional
        The SRG the network was planned from: frames, static values and edge properties.
    plans : dict query name -> (Plan, prefix), optional
        The plans built into ``network`` (with the component-name prefix used): each query's
        answers are drawn and its path highlighted.
    errors : dict query name -> message, optional
        Queries of the setup that have no path (drawn as "no path" in the panel).
    rate_hz : float
        View frames per second (the decimation: taps write a pose at most this often).
    style : Style, optional
        How poses are drawn; default: axes a tenth of the scene's extent (known once the
        frames are placed), ellipsoids true to scale.
    sensor_info : callable, optional
        A live runtime's sensor report (:data:`SensorInfo`), polled a few times a second.
    priority : {"low", "idle", "normal"}
        CPU priority of the view process: ``low`` (default) is niceness +10 - the dataflow
        thread, which sleeps between events, preempts it on every wake-up, while the view still
        gets its frames on a machine busy with other work; ``idle`` draws only with CPU time
        nothing else wants (Linux ``SCHED_IDLE``: fewer frames on a busy machine).
    anchor : str, optional
        The frame the scene is drawn in (the page's "anchor" control changes it); default
        the room (:func:`trackflow.viewer.edges.default_anchor`): a frame named like it,
        else a root of the SRG - not the query's source, which may be a moving body.

    Raises
    ------
    InputError
        A bad rate, priority or anchor frame.
    """
    if not 1.0 <= rate_hz <= 120.0:
        raise InputError(f"view rate must be in [1, 120] Hz, got {rate_hz}")
    if priority not in PRIORITIES:
        raise InputError(f"view priority must be one of {PRIORITIES}, got {priority!r}")
    wiring = _Wiring(network, rate_hz)
    sources = _sources(network)
    edges: list[EdgeLayout] = []
    watched: dict[str, list] = {}
    filters: dict[str, tuple] = {}  # sensor -> (its filter, its edge): measured attributes
    if setup is not None:
        g = setup.graph
        frames = list(g.frames)
        for edge in g.edges:
            if edge.kind == "static":
                edges.append(EdgeLayout(edge.name, edge.source, edge.target, True,
                                        value=edge.value()))  # fmt: skip
                continue
            src = sources.get(edge.name)
            fed = [c for c, _ in src.consumers] if src is not None else []
            # the planner puts the sensor's filter right behind its source
            kf = next((c for c in fed if isinstance(c, KalmanFilter)), None)
            behind = kf if kf is not None else src
            slot = None if behind is None else wiring.tap(behind, f"view:{edge.name}", kf)
            watched[edge.name] = [c for c in (src, kf) if c is not None]
            if kf is not None:
                filters[edge.name] = (kf, edge)
            limit = getattr(kf, "max_extrapolation_ns", None)
            edges.append(
                EdgeLayout(edge.name, edge.source, edge.target, False, slot,
                           rate_hz=float(edge.rate_hz),
                           offset_ms=float(edge.stamp_offset_s) * 1e3,
                           max_extrapolation_s=math.inf if limit is None else limit * 1e-9)
            )  # fmt: skip
        near = next(iter(setup.queries.values())).source if setup.queries else None
        root = default_anchor(frames, edges, near)
    else:
        frames, root = ["world", *sources], "world"
        for name, src in sources.items():
            t = getattr(src, "t_ns", None) if isinstance(src, RecordingPlayer) else None
            rate = float(1e9 / np.median(np.diff(t))) if t is not None and len(t) > 1 else math.inf
            slot = wiring.tap(src, f"view:{name}")
            watched[name] = [src]
            edges.append(EdgeLayout(name, "world", name, False, slot, rate_hz=rate))
    queries: list[QueryLayout] = []
    switches: dict[str, PathSwitch] = {}
    for qname, (plan, prefix) in (plans or {}).items():
        q = plan.query
        for node in plan.nodes:
            if node.kind == "switch":
                switches[qname] = _component(network, plan, prefix, node.id)
        paths = tuple(tuple(s.edge.name for s in p.steps) for p in plan.paths)
        path_edges = tuple(n for p in paths for n in p)
        out, own = _query_ends(network, plan, prefix)
        base = int(round(q.time_offset_s * 1e9))
        if own is None:  # a pull query: the view samples it at the view rate
            own = network.add(Sampler(f"view:{qname}:now", rate_hz, base))
            network.connect(out, own, mode="pull")
        # (a push query is drawn from its own answers: no extra work in the dataflow); the
        # prediction ghost is pulled by the same tap, only while an offset is set
        ahead_slot = wiring.tap(None, None)
        now_slot = wiring.tap(own, f"view:{qname}:now:tap", ahead=(out, ahead_slot))
        rate = float(q.rate_hz) if q.mode == "push" and q.rate_hz else float(rate_hz)
        queries.append(
            QueryLayout(qname, q.source, q.target, path_edges, now_slot, ahead_slot,
                        rate_hz=rate, paths=paths)
        )  # fmt: skip
    for qname, msg in (errors or {}).items():
        q = setup.queries[qname] if setup is not None else None
        if q is not None:
            queries.append(QueryLayout(qname, q.source, q.target, error=msg))
    if anchor is not None:
        if anchor not in frames:
            raise InputError(f"anchor frame {anchor!r} is not a frame of the setup {frames}")
        root = anchor
    board, taps = wiring.build()
    layout = ViewLayout(frames, root, edges, queries, board.n_slots)
    query_taps = [taps[f"view:{q.name}:now:tap"] for q in queries if q.now_slot is not None]
    return LiveView(
        network, layout, board, watched, query_taps, host=host, port=port, rate_hz=rate_hz,
        style=style, sensor_info=sensor_info, priority=priority, filters=filters,
        switches=switches,
    )  # fmt: skip
