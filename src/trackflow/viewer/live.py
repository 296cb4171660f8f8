"""The live view of a running :class:`trackflow.dataflow.Network` (thesis 8.2).

:func:`attach_view` wires :class:`~trackflow.viewer.monitor.Tap` components behind every
sensor filter (or source) and behind two samplers per query that the view adds (one at the
query's own time offset, one at that offset plus the prediction slider), then starts a
separate thread that, at the view rate (30-60 Hz), turns what the taps hold into scene and
panel updates. The dataflow thread never waits for the view: it only hands over references.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from ..dataflow import KalmanFilter, Network, Plan, RecordingPlayer, Sampler, Setup
from ..math import Pose, UncertainPose, quat_multiply
from .batch import BatchDrawing, BodyFrame
from .glyphs import to_wxyz
from .graph_panel import EdgeStatus, classify, render_panel
from .monitor import Tap
from .scene import PALETTE, Style, frame_node
from .server import SECONDS_AXIS, ViewServer

__all__ = ["LiveView", "attach_view"]


@dataclass
class _Edge:
    """One monitored SRG edge: its description, the tap and the components behind it."""

    name: str
    source: str
    target: str
    static: bool
    tap: Tap | None = None
    player: RecordingPlayer | None = None
    kalman: KalmanFilter | None = None
    value: UncertainPose | None = None  # static edges
    rate_hz: float = math.inf
    offset_ms: float = math.nan
    trail: list = field(default_factory=list)
    gated_seen: int = 0
    gated_at: float = -math.inf
    rate_count: int = 0
    rate_wall: float = 0.0
    rate_est: float = math.nan


@dataclass
class _QueryView:
    name: str
    source: str
    target: str
    path_edges: tuple[str, ...]
    now: Tap | None = None
    ahead: Tap | None = None
    ahead_sampler: _ViewSampler | None = None
    base_offset_ns: int = 0
    trail: list = field(default_factory=list)
    error: str = ""


class LiveView:
    """A viser page following a network; made by :func:`attach_view`.

    Attributes
    ----------
    frames_sent : int
        View frames pushed to the page so far (the decimated rate is ``frames_sent`` over the
        running time).
    frame_cost_s : float
        Smoothed wall time of drawing one frame [s].
    frames_skipped : int
        Frames not drawn because the dataflow ran more than ``max_lag_s`` (20 ms) late.
    """

    def __init__(
        self,
        network: Network,
        edges: list[_Edge],
        queries: list[_QueryView],
        frames: list[str],
        root: str,
        *,
        host: str,
        port: int,
        rate_hz: float,
        style: Style | None,
        cpu_share: float = 0.15,
    ):
        if not 1.0 <= rate_hz <= 120.0:
            raise ValueError(f"view rate must be in [1, 120] Hz, got {rate_hz}")
        self.network, self.edges, self.queries = network, edges, queries
        self.frames, self.root = frames, root
        self.rate_hz = float(rate_hz)
        self.style = style or Style(axes_length=0.08, magnify=1.0)
        self.view = ViewServer(host, port, title="trackflow live")
        self.view.look_at((0.3, 0.0, 0.2), 1.2)
        self.frames_sent = 0
        self.frames_skipped = 0
        self.max_lag_s = 0.02
        self._lag_ref: int | None = None
        self._lag_now = 0
        self._skip_note = 0.0
        self.frame_cost_s = 0.0
        self.cpu_share = float(cpu_share)
        if not 0.0 < self.cpu_share <= 1.0:
            raise ValueError(f"cpu_share must be in (0, 1], got {cpu_share}")
        self.paused = False
        self.show_sensors = True
        self.selected_query = queries[0].name if queries else None
        self.selected_edge = next((e.name for e in edges if not e.static), None)
        self._stop = threading.Event()
        self._lock = threading.RLock()
        self._panel_html = ""
        self._framed = False
        self._panel_wall = 0.0
        self._plot_wall = 0.0
        self._build_scene()
        self._build_controls()
        self._thread = threading.Thread(target=self._loop, daemon=True, name="trackflow-view")
        self._thread.start()

    @property
    def url(self) -> str:
        return self.view.url

    # -- construction ----------------------------------------------------------------------------
    def _build_scene(self) -> None:
        scene, st = self.view.scene, self.style
        self.frame_nodes = {
            f: frame_node(scene, f"/{f}", st.axes_length * 1.2, f) for f in self.frames
        }
        for f, node in self.frame_nodes.items():
            node.visible = f == self.root
        self.bodies = [e for e in self.edges if not e.static and e.tap is not None]
        self.bodies += [q for q in self.queries if q.now is not None]
        colours = [PALETTE[k % len(PALETTE)] for k in range(len(self.bodies))]
        self.batch = BatchDrawing(scene, "/bodies", colours, st) if self.bodies else None
        self.labels = [
            scene.add_label(f"/bodies/label_{k}", b.name, visible=False)
            for k, b in enumerate(self.bodies)
        ]
        self._label_wall = 0.0

    def _build_controls(self) -> None:
        gui = self.view.gui
        with gui.add_folder("View"):
            names = tuple(q.name for q in self.queries) or ("(none)",)
            self.c_query = gui.add_dropdown("query", names, initial_value=names[0])
            self.c_sigma = gui.add_dropdown("sigma", ("1", "2", "3"), initial_value="1")
            self.c_offset = gui.add_slider(
                "prediction [ms]", min=0.0, max=300.0, step=5.0, initial_value=0.0
            )
            self.c_magnify = gui.add_number("magnify", self.style.magnify, min=1.0, step=1.0)
            self.c_sensors = gui.add_checkbox("sensors", True)
            self.c_pause = gui.add_checkbox("pause", False)
        self.c_query.on_update(lambda _: self._set(selected_query=self.c_query.value))
        self.c_sigma.on_update(lambda _: self.set_sigma(float(self.c_sigma.value)))
        self.c_offset.on_update(lambda _: self.set_offset(self.c_offset.value * 1e-3))
        self.c_magnify.on_update(lambda _: self.set_magnify(float(self.c_magnify.value)))
        self.c_sensors.on_update(lambda _: self._set(show_sensors=bool(self.c_sensors.value)))
        self.c_pause.on_update(lambda _: self._set(paused=bool(self.c_pause.value)))
        with gui.add_folder("Spatial relationship graph"):
            self.panel = gui.add_html("")
        with gui.add_folder("Time plots", expand_by_default=False):
            names = tuple(e.name for e in self.edges if not e.static) or ("(none)",)
            self.c_edge = gui.add_dropdown("edge", names, initial_value=names[0])
            self.c_edge.on_update(lambda _: self._set(selected_edge=self.c_edge.value))
            empty = (np.zeros(2), np.zeros(2))
            self.plots = {
                key: gui.add_uplot(
                    scales=SECONDS_AXIS,
                    data=empty,
                    series=({"label": "t [s]"}, {"label": label, "stroke": colour}),
                    title=label,
                    aspect=2.5,
                )  # fmt: skip
                for key, label, colour in (
                    ("pos", "position sigma [mm]", "#c0c"),
                    ("ori", "orientation sigma [deg]", "#08c"),
                    ("lat", "latency [ms]", "#d60"),
                    ("nis", "NIS", "#333"),
                )
            }

    # -- controls (also the Python API) ------------------------------------------------------------
    def _set(self, **kw) -> None:
        with self._lock:
            for k, v in kw.items():
                setattr(self, k, v)

    def _set_style(self, **kw) -> None:
        with self._lock:
            for k, v in kw.items():
                setattr(self.style, k, v)

    def set_sigma(self, sigma: float) -> None:
        """Sigma level (1, 2 or 3) of every ellipsoid."""
        self._set_style(sigma=float(sigma))
        if self.c_sigma.value != str(int(sigma)):
            self.c_sigma.value = str(int(sigma))

    def set_magnify(self, magnify: float) -> None:
        """Draw every ellipsoid ``magnify`` times its size (1: true to scale)."""
        self._set_style(magnify=float(magnify))
        if self.c_magnify.value != float(magnify):
            self.c_magnify.value = float(magnify)

    def set_offset(self, offset_s: float) -> None:
        """Prediction offset [s]: each query is also drawn this far ahead of its own time."""
        off = int(round(max(0.0, float(offset_s)) * 1e9))
        for q in self.queries:
            if q.ahead_sampler is not None:
                q.ahead_sampler.offset_ns = q.base_offset_ns + off  # one int store
                q.ahead_sampler.enabled = off > 0
        self._set(offset_s=off * 1e-9)
        if abs(self.c_offset.value - off * 1e-6) > 1e-9:
            self.c_offset.value = off * 1e-6

    offset_s = 0.0

    # -- the view thread -------------------------------------------------------------------------
    def _loop(self) -> None:
        """Render at ``rate_hz`` at most, and never more than ``cpu_share`` of the wall time:
        a frame that took ``c`` seconds is followed by at least ``c / cpu_share`` seconds
        before the next, so a slow machine gets fewer view frames, not a slower dataflow. While
        the dataflow runs late (:meth:`dataflow_lag_s` above ``max_lag_s``) no frame is drawn."""
        period = 1.0 / self.rate_hz
        nxt = time.perf_counter()
        while not self._stop.is_set():
            delay = nxt - time.perf_counter()
            if delay > 0 and self._stop.wait(delay):
                break
            start = time.perf_counter()
            lag = 0.0 if self.paused else self.dataflow_lag_s()
            if self.paused or lag > self.max_lag_s:
                if not self.paused:
                    self.frames_skipped += 1
                    if start - self._skip_note > 1.0:  # say why the picture stands still
                        self._skip_note = start
                        self.view.set_status(
                            f"**live** - view held: the dataflow runs {lag * 1e3:.0f} ms late"
                        )
                nxt = start + period
                continue
            with self._lock:
                self.render_frame()
            cost = time.perf_counter() - start
            self.frame_cost_s = 0.9 * self.frame_cost_s + 0.1 * cost
            nxt = max(nxt + period, start + cost / self.cpu_share)

    def dataflow_lag_s(self) -> float:
        """How late the network dispatches its events on the wall clock [s], relative to the
        least-late dispatch seen in this run; 0 while nothing was dispatched in the last 100 ms
        (an idle or finished network, or a virtual-clock run that has ended)."""
        c = self.network.clock
        now_ns, wall_ns = c.now_ns, c.dispatch_wall_ns
        if not wall_ns or time.perf_counter_ns() - wall_ns > 100_000_000:
            return 0.0  # nothing dispatched for 100 ms: an idle (or finished) network is not late
        offset = wall_ns - now_ns
        if self._lag_ref is None or now_ns < self._lag_now or offset < self._lag_ref:
            self._lag_ref = offset  # first event, a new run, or a less late one
        self._lag_now = now_ns
        return (offset - self._lag_ref) * 1e-9

    def render_frame(self) -> None:
        """Draw one view frame from what the taps hold (called by the view thread)."""
        now_wall = time.perf_counter()
        now_ns = self.network.clock.now_ns
        places = self._place_frames()
        if not self._framed and len(places) == len(self.frames):
            # aim the initial camera of later clients at the frames once all are placed
            pts = np.array([p.position for p in places.values()])
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            self.view.look_at(0.5 * (lo + hi), max(float(np.max(hi - lo)), 0.3))
            self._framed = True
        bodies, trails = self._collect(places)
        # Between the phases of a frame the view sleeps for zero seconds: that releases the
        # interpreter lock, so a dataflow thread waiting for it runs now instead of after the
        # interpreter's switch interval (5 ms), and a frame never holds the dataflow up for
        # longer than one phase.
        time.sleep(0)
        with self.view.server.atomic():
            for f, node in self.frame_nodes.items():
                pose = places.get(f)
                node.visible = pose is not None
                if pose is not None:
                    node.position, node.wxyz = pose.position, to_wxyz(pose.quaternion)
            if self.batch is not None:
                self.batch.update(bodies, trails)
            if now_wall - self._label_wall > 0.5:  # labels follow at 2 Hz
                self._label_wall = now_wall
                for label, b in zip(self.labels, bodies):
                    label.visible = b is not None
                    if b is not None:
                        label.position = b.position + [0.0, 0.0, self.style.axes_length * 0.6]
        time.sleep(0)
        if now_wall - self._panel_wall > 0.2:
            self._panel_wall = now_wall
            self._update_panel(now_ns, now_wall)
        if now_wall - self._plot_wall > 0.5:
            self._plot_wall = now_wall
            self._update_plots()
        self.frames_sent += 1
        self.view.set_status(
            f"**live** - network t = {now_ns * 1e-9:.2f} s - {self.style.sigma:g} sigma"
            + (f", ellipsoids x{self.style.magnify:g}" if self.style.magnify != 1 else "")
            + (f" - predicted +{self.offset_s * 1e3:.0f} ms" if self.offset_s > 0 else "")
        )

    def _place_frames(self) -> dict[str, Pose]:
        """World placement ``T_root_frame`` of every frame reachable from the root through
        static values and the newest measurements."""
        known: dict[str, Pose] = {self.root: Pose.identity()}
        values = []
        for e in self.edges:
            if e.static and e.value is not None:
                values.append((e.source, e.target, e.value.pose))
            elif e.tap is not None and e.tap.latest is not None:
                values.append((e.source, e.target, e.tap.latest.pose.pose))
        changed = True
        while changed:
            changed = False
            for a, b, T_a_b in values:
                if a in known and b not in known:
                    known[b] = known[a] @ T_a_b
                    changed = True
                elif b in known and a not in known:
                    known[a] = known[b] @ T_a_b.inverse()
                    changed = True
        return known

    def _collect(self, places: dict[str, Pose]):
        """Every body's pose (and prediction) in the world frame, with its trail."""
        bodies: list[BodyFrame | None] = []
        trails: list[np.ndarray | None] = []
        keep = max(2, int(self.style.trail_s * self.rate_hz))
        for b in self.bodies:
            frame = places.get(b.source)
            if isinstance(b, _Edge):
                m = b.tap.latest
                b.tap.request_filtered()
                pose = None
                if m is not None and self.show_sensors:
                    pose = b.tap.filtered if b.tap.filtered is not None else m.pose
                ahead = None
            else:
                m = b.now.latest
                pose = None if m is None else m.pose
                a = b.ahead.latest if (b.ahead is not None and self.offset_s > 0) else None
                ahead = None if a is None else a.pose
            if pose is None or frame is None:
                bodies.append(None)
                trails.append(None)
                continue
            world = _to_world(frame, pose)
            pred = None if ahead is None else _to_world(frame, ahead)
            bodies.append(BodyFrame(*world, predicted=pred))
            b.trail.append(world[0])
            del b.trail[:-keep]
            trails.append(np.array(b.trail))
        return bodies, trails

    def edge_statuses(self, now_ns: int | None = None) -> list[EdgeStatus]:
        """The panel's view of every edge and of every query without a path."""
        now_ns = self.network.clock.now_ns if now_ns is None else now_ns
        now_wall = time.perf_counter()
        q = next((q for q in self.queries if q.name == self.selected_query), None)
        on_path = set(q.path_edges) if q else set()
        used = {n for qq in self.queries for n in qq.path_edges} if self.queries else None
        out = []
        for e in self.edges:
            if e.static:
                out.append(
                    EdgeStatus(e.name, e.source, e.target, "static", on_path=e.name in on_path)
                )
                continue
            rej: dict[str, int] = {}
            for comp in (e.player, e.kalman):
                if comp is not None:
                    for k, v in dict(comp.stats.rejections).items():
                        rej[k] = rej.get(k, 0) + v
            gated = rej.get("filter rejected update", 0)
            if gated > e.gated_seen:
                e.gated_seen, e.gated_at = gated, now_wall
            tap = e.tap
            age = None if tap is None or tap.latest is None else (now_ns - tap.arrival_ns) * 1e-9
            if tap is not None:
                if now_wall - e.rate_wall >= 1.0:
                    if e.rate_wall > 0:
                        e.rate_est = (tap.count - e.rate_count) / (now_wall - e.rate_wall)
                    e.rate_count, e.rate_wall = tap.count, now_wall
            recent = list(tap.recent)[-50:] if tap is not None else []
            lat = float(np.median([r[1] for r in recent])) * 1e-6 if recent else math.nan
            state = classify(
                static=False,
                used=used is None or e.name in used,
                age_s=age,
                rate_hz=e.rate_hz,
                gated_recently=now_wall - e.gated_at < 1.0,
            )
            out.append(
                EdgeStatus(e.name, e.source, e.target, state, e.rate_est, lat, e.offset_ms, rej,
                           e.name in on_path)
            )  # fmt: skip
        for qq in self.queries:
            if qq.error:
                out.append(EdgeStatus(qq.name, qq.source, qq.target, "no path"))
        return out

    def _update_panel(self, now_ns: int, now_wall: float) -> None:
        html = render_panel(self.frames, self.edge_statuses(now_ns))
        if html != self._panel_html:
            self._panel_html = html
            self.panel.content = html

    def _update_plots(self) -> None:
        e = next((e for e in self.edges if e.name == self.selected_edge), None)
        if e is None or e.tap is None:
            return
        recent = list(e.tap.recent)
        if len(recent) < 2:
            return
        arr = np.array(recent, dtype=float)
        t = arr[:, 0] * 1e-9
        pose = e.tap.filtered
        # the ring holds time, latency and NIS; sigmas come from the newest filtered poses,
        # kept per view frame in a small ring of their own
        ring = getattr(e, "_sig", None)
        if ring is None:
            ring = e._sig = []  # type: ignore[attr-defined]
        if pose is not None and e.tap.latest is not None:
            c = pose.covariance
            pos_mm = math.sqrt(max(np.linalg.eigvalsh(c[:3, :3])[-1], 0.0)) * 1e3
            ori_deg = math.degrees(math.sqrt(max(np.linalg.eigvalsh(c[3:, 3:])[-1], 0.0)))
            ring.append((e.tap.latest.t_ns * 1e-9, pos_mm, ori_deg))
            del ring[:-300]
        if len(ring) >= 2:
            s = np.array(ring)
            self.plots["pos"].data = (s[:, 0], s[:, 1])
            self.plots["ori"].data = (s[:, 0], s[:, 2])
        self.plots["lat"].data = (t, arr[:, 1] * 1e-6)
        self.plots["nis"].data = (t, np.nan_to_num(arr[:, 2]))

    def close(self) -> None:
        """Stop the view thread and the server (the network keeps its taps; they are cheap)."""
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.view.close()


def _to_world(T_w_a: Pose, pose: UncertainPose):
    """``T_w_a @ pose`` with ``T_w_a`` exact: position, quaternion and covariance in the world
    frame (the translation error rotates with ``R_w_a``; the body-frame rotation error does
    not change)."""
    r = T_w_a.rotation_matrix
    pos = r @ np.asarray(pose.position, float) + T_w_a.position
    quat = quat_multiply(T_w_a.quaternion, pose.quaternion)
    c = np.array(pose.covariance, float)
    c[:3, :] = r @ c[:3, :]
    c[:, :3] = c[:, :3] @ r.T
    return pos, quat, c


def _tap_after(network: Network, comp, name: str, kalman=None) -> Tap:
    tap = network.add(Tap(name, kalman=kalman))
    network.connect(comp, tap, mode="push")
    return tap


def _component(network: Network, plan: Plan, prefix: str, node_id: str):
    comp = network.components.get(prefix + node_id) or network.components.get(node_id)
    if comp is None:
        raise ValueError(f"query {plan.query.name!r}: no component {node_id!r} in the network")
    return comp


def _query_ends(network: Network, plan: Plan, prefix: str):
    """``(pull-able component feeding the query's sink, the query's own sampler or None)``."""
    src = plan.node(plan.output).inputs[0][0]
    sampler = None
    if plan.node(src).kind == "sampler":
        sampler = _component(network, plan, prefix, src)
        src = plan.node(src).inputs[0][0]
    return _component(network, plan, prefix, src), sampler


class _ViewSampler(Sampler):
    """A sampler the view can switch off: a disabled tick costs one attribute test."""

    kind = "view sampler"
    enabled = True

    def tick(self, t_ns: int) -> None:
        if self.enabled:
            super().tick(t_ns)


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
    cpu_share: float = 0.15,
) -> LiveView:
    """Attach a browser view to ``network`` (before it runs); returns the :class:`LiveView`.

    Parameters
    ----------
    network : Network
        Any network. Without ``setup`` every source is drawn as a relationship ``world ->
        source`` (its raw measurements).
    setup : Setup, optional
        The SRG the network was planned from: frames, static values and edge properties.
    plans : dict query name -> (Plan, prefix), optional
        The plans built into ``network`` (with the component-name prefix used): each query is
        drawn (sampled by two view samplers at ``rate_hz``) and its path highlighted.
    errors : dict query name -> message, optional
        Queries of the setup that have no path (drawn as "no path" in the panel).
    rate_hz : float
        View frames per second (the decimation: taps hand over the newest event only).
    cpu_share : float
        Most of the wall time the view thread may spend drawing; a slower machine gets fewer
        frames per second than ``rate_hz``.
    """
    comps = network.components
    players = {c.name: c for c in comps.values() if isinstance(c, RecordingPlayer)}
    edges: list[_Edge] = []
    frames: list[str]
    if setup is not None:
        g = setup.graph
        frames = list(g.frames)
        for edge in g.edges:
            if edge.kind == "static":
                edges.append(_Edge(edge.name, edge.source, edge.target, True, value=edge.value()))
                continue
            player = players.get(edge.name)
            fed = [c for c, _ in player.consumers] if player is not None else []
            # the planner puts the sensor's filter right behind its source
            kf = next((c for c in fed if isinstance(c, KalmanFilter)), None)
            behind = kf if kf is not None else player
            tap = _tap_after(network, behind, f"view:{edge.name}", kf) if behind else None
            edges.append(
                _Edge(edge.name, edge.source, edge.target, False, tap, player, kf,
                      rate_hz=float(edge.rate_hz), offset_ms=float(edge.stamp_offset_s) * 1e3)
            )  # fmt: skip
        root = next(iter(setup.queries.values())).source if setup.queries else frames[0]
    else:
        frames = ["world", *players]
        root = "world"
        for name, player in players.items():
            tap = _tap_after(network, player, f"view:{name}")
            edges.append(_Edge(name, "world", name, False, tap, player, None,
                               rate_hz=float(1e9 / np.median(np.diff(player.t_ns)))
                               if len(player.t_ns) > 1 else math.inf))  # fmt: skip
    queries: list[_QueryView] = []
    for qname, (plan, prefix) in (plans or {}).items():
        q = plan.query
        path_edges = tuple(s.edge.name for p in plan.paths for s in p.steps)
        qv = _QueryView(qname, q.source, q.target, path_edges)
        out, own = _query_ends(network, plan, prefix)
        qv.base_offset_ns = int(round(q.time_offset_s * 1e9))
        if own is not None:  # a push query: its own answers, no extra work in the dataflow
            qv.now = _tap_after(network, own, f"view:{qname}:now:tap")
        else:  # a pull query: the view samples it at the view rate
            now = network.add(_ViewSampler(f"view:{qname}:now", rate_hz, qv.base_offset_ns))
            network.connect(out, now, mode="pull")
            qv.now = _tap_after(network, now, f"view:{qname}:now:tap")
        # the prediction ghost: ticks only while a prediction offset is set
        ahead = _ViewSampler(f"view:{qname}:ahead", rate_hz, qv.base_offset_ns)
        ahead.enabled = False
        qv.ahead_sampler = network.add(ahead)
        network.connect(out, qv.ahead_sampler, mode="pull")
        qv.ahead = _tap_after(network, qv.ahead_sampler, f"view:{qname}:ahead:tap")
        queries.append(qv)
    for qname, msg in (errors or {}).items():
        q = setup.queries[qname] if setup is not None else None
        if q is not None:
            queries.append(_QueryView(qname, q.source, q.target, (), error=msg))
    return LiveView(
        network, edges, queries, frames, root, host=host, port=port, rate_hz=rate_hz,
        style=style, cpu_share=cpu_share,
    )  # fmt: skip
