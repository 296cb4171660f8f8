"""The page of a live network, drawn from the shared board (the view process's scene).

Everything is drawn in one anchor frame chosen by the user (the room by default,
:func:`trackflow.viewer.edges.default_anchor`): frames placed by chaining static values and the
newest sensor poses, every sensor's filtered pose and every query's answer with its error
glyphs, the fading trail and the whole path, a floor grid with its scale, labels laid out
without overlaps and a legend. A body whose data stopped (a stale or down sensor, a query
without answers) is drawn grey and its label says for how long. The default camera frames the
selected query's body; with "follow" on the camera moves along with it.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque

import numpy as np

from .attributes_panel import render_attributes
from .batch import HIDDEN, BatchDrawing, BodyFrame
from .board import Board, BoardPose
from .camera import body_glyph_points
from .decor import add_floor_grid, grid_spec
from .edges import EdgeLayout, EdgeMonitor, QueryLayout, ViewLayout
from .export import csv_bytes, save_render
from .glyphs import to_wxyz
from .graph_panel import classify, render_panel
from .labels import LabelLayer, LabelSpec
from .legend import BodyLine, live_legend, sigma_sizes
from .placement import place_frames, to_world
from .scene import GREY, PALETTE, Style
from .server import SECONDS_AXIS, ViewServer, linked_cursor
from .time_plots import nis_data, nis_series

__all__ = ["IDLE_RATE_HZ", "LiveScene"]

#: Points kept of a body's whole path (halved, every other one, when full).
PATH_POINTS = 4000
#: Part of the page the followed body's glyph covers on the default camera: less than a
#: recording's, a live setup's other bodies and frames are around it.
LIVE_COVERAGE = 0.06
#: Frames per second drawn while no browser is connected (keeps trails and plots current).
IDLE_RATE_HZ = 2.0


class LiveScene:
    """The page of a live network, drawn from ``board`` as ``layout`` describes it.

    Attributes
    ----------
    frames_sent : int
        View frames pushed to the page (also written to the board's header).
    anchor : str
        The frame everything is drawn in.
    """

    def __init__(
        self, layout: ViewLayout, board: Board, host: str, port: int, rate_hz: float,
        style: Style | None, send=None, anchor: str | None = None,
    ):  # fmt: skip
        self.layout, self.board, self.rate_hz = layout, board, float(rate_hz)
        self.style = style or Style(axes_length=0.08, magnify=1.0)
        self.send = send or (lambda msg: None)
        self.view = ViewServer(host, port, title="trackflow live")
        self.view.look_at((0.3, 0.0, 0.2), 1.2)
        self.monitor = EdgeMonitor(layout, board)
        self.rejections: dict[str, dict[str, int]] = {}
        self.offsets_ms: dict[str, float] = {}
        #: measured attributes and queries' paths from the main process (attributes_panel)
        self.attributes: dict | None = None
        self.frames_sent = 0
        self.paused = False
        self.show_sensors = True
        self.offset_s = 0.0
        self.anchor = anchor or layout.root
        self.follow = True
        self.show_grid = self.show_labels = True
        self.selected_query = layout.queries[0].name if layout.queries else None
        self.selected_edge = next((e.name for e in layout.edges if not e.static), None)
        self._lock = threading.RLock()
        self._framed = False
        self._move_browsers = False
        self._first_placed: float | None = None
        self.auto_scale = style is None
        self._panel_html = ""
        self._panel_wall = self._plot_wall = self._label_wall = self._aim_wall = 0.0
        self._trails: dict[str, list] = {}
        self._paths: dict[str, list] = {}
        self._followed: tuple[int, np.ndarray] | None = None  # (body, look-at offset from it)
        self._grey_after: dict[str, float] = {}
        self._ages: list[float | None] = []
        self._statics = [
            (e.source, e.target, e.value.quaternion, e.value.position)
            for e in layout.edges
            if e.static and e.value is not None
        ]
        self._sigmas: dict[str, list] = {}
        self._edges = {e.name: e for e in layout.edges}
        self._held: dict[str, BoardPose] = {}  # a query's newest usual answer (held if stale)
        self._aheads: dict[str, deque] = {}  # how far its recent answers were extrapolated
        self._over: dict[str, float] = {}  # a query held (no live path): for how long [s]
        self._last: tuple[list, dict] | None = None  # bodies and frames last drawn
        self.grid = self.grid_spec = None
        self._build_scene()
        self._build_controls()
        self.view.on_camera(self._camera_moved)

    @property
    def url(self) -> str:
        return self.view.url

    # -- construction ----------------------------------------------------------------------------
    def _build_scene(self) -> None:
        scene, st, lay = self.view.scene, self.style, self.layout
        n = len(lay.frames)
        self.frame_axes = scene.add_batched_axes(
            "/frames", np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), np.zeros((n, 3)),
            np.where(np.array(lay.frames) == self.anchor, 1.0, HIDDEN),
            axes_length=st.axes_length * 1.2, axes_radius=st.axes_length * 0.03,
        )  # fmt: skip
        self.bodies: list[EdgeLayout | QueryLayout] = [
            e for e in lay.edges if not e.static and e.slot is not None
        ]
        self.bodies += [q for q in lay.queries if q.now_slot is not None]
        self.colours = [PALETTE[k % len(PALETTE)] for k in range(len(self.bodies))]
        self.batch: BatchDrawing | None = None  # made once the scene's extent is known
        self.labels = LabelLayer(scene, "/labels")

    def _build_controls(self) -> None:
        gui, lay = self.view.gui, self.layout
        with gui.add_folder("View"):
            names = tuple(q.name for q in lay.queries) or ("(none)",)
            self.c_query = gui.add_dropdown("query", names, initial_value=names[0])
            self.c_anchor = gui.add_dropdown("anchor", tuple(lay.frames), initial_value=self.anchor)
            self.c_sigma = gui.add_dropdown("sigma", ("1", "2", "3"), initial_value="1")
            self.c_offset = gui.add_slider(
                "prediction [ms]", min=0.0, max=300.0, step=5.0, initial_value=0.0
            )
            self.c_magnify = gui.add_number("magnify", self.style.magnify, min=1.0, step=1.0)
            self.c_ghost = gui.add_number(
                "ghost magnify", self.style.ghost_magnify, min=1.0, step=1.0
            )
            self.c_sensors = gui.add_checkbox("sensors", True)
            self.c_pause = gui.add_checkbox("pause", False)
        with gui.add_folder("Spatial relationship graph"):
            self.panel = gui.add_html("")
        with gui.add_folder("Legend"):
            self.legend = gui.add_markdown("")
        with gui.add_folder("Scene", expand_by_default=False):
            self.c_follow = gui.add_checkbox("follow body", True)
            self.c_grid = gui.add_checkbox("grid", True)
            self.c_path = gui.add_checkbox("path", self.style.show_path)
            self.c_trail = gui.add_checkbox("trail", self.style.show_trail)
            self.c_labels = gui.add_checkbox("labels", True)
            reframe = gui.add_button("frame the body")
        with gui.add_folder("Save", expand_by_default=False):
            save_png = gui.add_button("save PNG")
            save_csv = gui.add_button("save CSV")
        save_png.on_click(lambda e: None if e.client is None else save_render(e.client))
        save_csv.on_click(
            lambda e: None if e.client is None else e.client.send_file_download(
                f"{self.selected_edge}.csv", self.edge_csv(), save_immediately=True)
        )  # fmt: skip
        for handle, key, conv in (
            (self.c_query, "selected_query", str), (self.c_anchor, "anchor", str),
            (self.c_sigma, "sigma", float), (self.c_magnify, "magnify", float),
            (self.c_ghost, "ghost_magnify", float), (self.c_sensors, "show_sensors", bool),
            (self.c_pause, "paused", bool), (self.c_follow, "follow", bool),
            (self.c_grid, "show_grid", bool), (self.c_path, "show_path", bool),
            (self.c_trail, "show_trail", bool), (self.c_labels, "show_labels", bool),
        ):  # fmt: skip
            handle.on_update(lambda _, h=handle, k=key, c=conv: self.apply(**{k: c(h.value)}))
        self.c_offset.on_update(lambda _: self._offset_moved(self.c_offset.value * 1e-3))
        reframe.on_click(lambda _: self.apply(reframe=True))
        with gui.add_folder("Time plots", expand_by_default=False):
            names = tuple(e.name for e in lay.edges if not e.static) or ("(none)",)
            self.c_edge = gui.add_dropdown("edge", names, initial_value=names[0])
            self.c_edge.on_update(lambda _: self.apply(selected_edge=self.c_edge.value))
            empty = (np.zeros(2), np.zeros(2))
            self.plots = {
                key: gui.add_uplot(
                    scales=SECONDS_AXIS,
                    cursor=linked_cursor("live"),
                    data=empty,
                    series=({"label": "t [s]"}, {"label": label, "stroke": colour}),
                    title=label,
                    aspect=2.5,
                )  # fmt: skip
                for key, label, colour in (
                    ("pos", "position sigma [mm]", "#c0c"),
                    ("ori", "orientation sigma [deg]", "#08c"),
                    ("lat", "latency [ms]", "#d60"),
                )
            }
            self.plots["nis"] = gui.add_uplot(
                scales=SECONDS_AXIS, cursor=linked_cursor("live"),
                data=nis_data(np.zeros(2), np.zeros(2)),
                series=nis_series(), title="NIS (the band: 95 % of a consistent filter's)",
                aspect=2.5,
            )  # fmt: skip

    # -- controls --------------------------------------------------------------------------------
    def _offset_moved(self, offset_s: float) -> None:
        if abs(offset_s - self.offset_s) > 1e-9:
            self.apply(offset_s=offset_s)
            self.send(("offset", offset_s))

    def apply(self, reframe: bool = False, **kw) -> None:
        """Set view state and show it in the controls: ``sigma``, ``magnify``,
        ``ghost_magnify``, ``offset_s``, ``paused``, ``show_sensors``, ``selected_query``,
        ``selected_edge``, ``anchor``, ``follow``, ``show_grid``, ``show_path``,
        ``show_trail``, ``show_labels``; ``reframe`` aims every page's camera at the body
        afresh (as does a new anchor)."""
        with self._lock:
            for k, v in kw.items():
                if k in ("sigma", "magnify", "ghost_magnify"):
                    setattr(self.style, k, float(v))
                elif k in ("show_path", "show_trail"):
                    setattr(self.style, k, bool(v))
                elif k == "anchor":
                    if v in self.layout.frames and v != self.anchor:
                        self._reanchor(v)
                else:
                    setattr(self, k, v)
            if reframe:  # the grid and every page's camera fitted again, paths kept
                self._framed, self._first_placed, self._move_browsers = False, None, True
            if "show_grid" in kw and self.grid is not None:
                self.grid.visible = bool(self.show_grid)
            if "show_labels" in kw:
                self.labels.shown = bool(self.show_labels)
        controls = {
            "sigma": (self.c_sigma, lambda v: str(int(v))),
            "magnify": (self.c_magnify, float),
            "ghost_magnify": (self.c_ghost, float),
            "offset_s": (self.c_offset, lambda v: float(v) * 1e3),
            "paused": (self.c_pause, bool),
            "show_sensors": (self.c_sensors, bool),
            "selected_query": (self.c_query, str),
            "selected_edge": (self.c_edge, str),
            "anchor": (self.c_anchor, str),
            "follow": (self.c_follow, bool),
            "show_grid": (self.c_grid, bool),
            "show_path": (self.c_path, bool),
            "show_trail": (self.c_trail, bool),
            "show_labels": (self.c_labels, bool),
        }
        for k, v in kw.items():
            handle, conv = controls[k]
            if handle.value != conv(v):
                handle.value = conv(v)

    def _reanchor(self, anchor: str) -> None:
        """Draw in ``anchor`` from now on: trails and paths start afresh, the grid and the
        cameras are fitted again."""
        self.anchor = anchor
        self._trails.clear()
        self._paths.clear()
        self._framed = False
        self._first_placed = None
        self._followed = None
        self._move_browsers = True

    # -- drawing ---------------------------------------------------------------------------------
    def clients(self) -> int:
        return len(self.view.server.get_clients())

    def loop(self, stop: threading.Event) -> None:
        """Draw at ``rate_hz`` (``IDLE_RATE_HZ`` while no browser is connected) until ``stop``."""
        nxt = time.perf_counter()
        while not stop.is_set():
            delay = nxt - time.perf_counter()
            if delay > 0 and stop.wait(delay):
                break
            start = time.perf_counter()
            if not self.paused:
                with self._lock:
                    self.render_frame()
            clients = self.clients()
            self.board.clients = clients
            period = 1.0 / (self.rate_hz if clients else min(self.rate_hz, IDLE_RATE_HZ))
            nxt += period
            if nxt < start - 0.25:  # far behind (a busy machine): start afresh, no burst
                nxt = start + period

    def render_frame(self) -> None:
        """Draw one view frame from the board."""
        now_wall = time.perf_counter()
        now_ns, _ = self.board.clock()
        poses = {b.name: self._read(b) for b in self.bodies}
        self._hold_extrapolated(poses, now_ns)
        places = self._place_frames(poses)
        bodies, trails = self._collect(places, poses)
        self._last = (bodies, places)
        if not self._framed:
            self._frame_scene(places, bodies, now_wall)
        colours = self._states(now_ns, poses)
        frames = self.layout.frames
        shown = np.array([f in places for f in frames])
        fq = np.array([places[f][0] if f in places else (0.0, 0.0, 0.0, 1.0) for f in frames])
        fp = np.array([places[f][1] if f in places else (0.0, 0.0, 0.0) for f in frames])
        with self.view.server.atomic():
            self.frame_axes.batched_positions, self.frame_axes.batched_wxyzs = fp, to_wxyz(fq)
            self.frame_axes.batched_scales = np.where(shown, 1.0, HIDDEN)
            if self.batch is not None:
                self.batch.set_colors(colours)
                self.batch.update(bodies, trails)
            if self._framed:
                self._aim(bodies, now_wall)
            if now_wall - self._label_wall > 0.09:  # labels follow at 10 Hz at most
                self._label_wall = now_wall
                self._relabel(bodies, places)
        if now_wall - self._panel_wall > 0.2:
            self._panel_wall = now_wall
            self._update_panel(now_ns)
        if now_wall - self._plot_wall > 0.5:
            self._plot_wall = now_wall
            self._update_plots(poses)
            if self.batch is not None:
                self.batch.update_paths([self._path_array(b.name) for b in self.bodies])
            self._update_legend(poses)
        self.frames_sent += 1
        self.board.frames_sent = self.frames_sent
        st = self.style
        self.view.set_status(
            f"**live** - network t = {_clock_text(now_ns)} - {st.sigma:g} sigma"
            + (f", ellipsoids x{st.magnify:g}" if st.magnify != 1 else "")
            + (f" - predicted +{self.offset_s * 1e3:.0f} ms" if self.offset_s > 0 else "")
            + (f" (ghost x{st.ghost_magnify:g})" if self.offset_s > 0 else "")
            + f" - in frame {self.anchor}"
        )

    def _hold_extrapolated(self, poses: dict[str, BoardPose | None], now_ns: int) -> None:
        """A query's answer is drawn only while it stands on data: while one of its paths has
        no stale sensor (the panel's "stale": no event for three periods and 250 ms), and
        within its filters' extrapolation limit (``max_extrapolation``) past that path's data.
        Otherwise the last answer drawn stays, grey - not one extrapolated on, with its
        ellipsoid ballooning, until the filters refuse."""
        for b in self.bodies:
            pose = poses.get(b.name)
            if not isinstance(b, QueryLayout) or pose is None:
                continue
            ahead = self._extrapolation(b, pose)
            without = self._path_stale_s(b, now_ns)
            if without is not None or ahead > b.max_extrapolation_s(self._edges) + 1e-9:
                self._over[b.name] = max(without or 0.0, ahead)
                poses[b.name] = self._held.get(b.name)
            else:
                self._over.pop(b.name, None)
                # the answer to hold when the data stop: the newest one extrapolated as far
                # as answers usually are (not one of the last, already ballooning, ones)
                hist = self._aheads.setdefault(b.name, deque(maxlen=64))
                hist.append(ahead)
                if ahead <= float(np.median(hist)) + self._slack(b):
                    self._held[b.name] = pose

    def _slack(self, q: QueryLayout) -> float:
        """Two periods of the slowest sensor on ``q``'s paths, and 5 ms [s]."""
        rates = [self._edges[n].rate_hz for n in q.path_edges if n in self._edges]
        periods = [1.0 / r for r in rates if 0 < r < math.inf]
        return 2.0 * max(periods, default=0.0) + 0.005

    def _path_stale_s(self, q: QueryLayout, now_ns: int) -> float | None:
        """None while some path of ``q`` has no stale sensor; else how long its best path
        has been without data [s] (network time since its stalest sensor's last event)."""
        best = None
        for path in q.paths or (q.path_edges,):
            worst = 0.0
            for name in path:
                e = self._edges.get(name)
                if e is None or e.static or e.slot is None:
                    continue
                n = self.board.count(e.slot)
                age = (now_ns - self.board.arrival_ns(e.slot)) * 1e-9 if n else math.inf
                state = classify(static=False, used=True, age_s=None if not n else age,
                                 rate_hz=e.rate_hz, gated_recently=False)  # fmt: skip
                if state == "stale":
                    worst = max(worst, age)
            if worst == 0.0:
                return None
            best = worst if best is None else min(best, worst)
        return best

    def _extrapolation(self, q: QueryLayout, pose: BoardPose) -> float:
        """How far ``pose`` [s] lies past the data of the query's best path (a path's data
        is as new as its stalest sensor's newest event)."""
        newest = None
        for path in q.paths or (q.path_edges,):
            times = []
            for name in path:
                e = self._edges.get(name)
                if e is not None and not e.static and e.slot is not None:
                    times.append(self.board.last_event_ns(e.slot))
            if not times:
                return 0.0  # a path of static values: no extrapolation
            if None in times:
                continue
            t = min(times)
            newest = t if newest is None else max(newest, t)
        return math.inf if newest is None else (pose.t_ns - newest) * 1e-9

    def _camera_moved(self) -> None:
        """A page moved its camera: lay the labels out for it (also while paused)."""
        with self._lock:
            if self._last is not None:
                self._relabel(*self._last)

    def _frame_scene(self, places: dict[str, tuple], bodies: list, now_wall: float) -> None:
        """Once every frame is placed (or 2 s after the first body was, with what is placed):
        with ``auto_scale`` size the glyphs to the scene (axes a tenth of its extent), lay the
        floor grid under it, aim the initial camera at the followed body (and, after a change
        of anchor, move the pages' cameras there), then create the body nodes once."""
        if len(places) < len(self.layout.frames):
            if len(places) < 2:
                return
            if self._first_placed is None:
                self._first_placed = now_wall
            if now_wall - self._first_placed < 2.0:
                return
        pts = [p for _, p in places.values()] + [b.position for b in bodies if b is not None]
        pts = np.array(pts)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        extent = max(float(np.max(hi - lo)), 0.3)
        if self.auto_scale and self.batch is None:
            self.style.axes_length = float(np.clip(0.1 * extent, 0.02, 0.5))
        if self.grid is not None:
            self.grid.remove()
        self.grid_spec = grid_spec(lo, hi)
        self.grid = add_floor_grid(self.view.scene, "/grid", self.grid_spec, self.show_grid)
        k = self._follow_index(bodies)
        if k is None:
            self.view.look_at(0.5 * (lo + hi), extent)
        else:
            self._followed = (k, self._frame_body(bodies[k]) - bodies[k].position)
        if self._move_browsers:
            self.view.reset_cameras()
            self._move_browsers = False
        if self.batch is None and self.bodies:
            self.batch = BatchDrawing(self.view.scene, "/bodies", self.colours, self.style)
        self._framed = True

    def _frame_body(self, body: BodyFrame) -> np.ndarray:
        """Aim the initial camera at ``body`` with some of the scene around it (its glyph
        covers :data:`LIVE_COVERAGE` of the page); returns the point it looks at."""
        pts = body_glyph_points(body.position, body.quaternion, self.style.axes_length)
        return self.view.frame(pts, coverage=LIVE_COVERAGE, centre=body.position)

    def _follow_index(self, bodies: list) -> int | None:
        """The body the camera follows: the selected query's answer, else the first drawn."""
        for k, b in enumerate(self.bodies):
            if b.name == self.selected_query and isinstance(b, QueryLayout) and bodies[k]:
                return k
        return next((k for k, b in enumerate(bodies) if b is not None), None)

    def _aim(self, bodies: list, now_wall: float) -> None:
        """Follow the body: every page's camera looks at the same point relative to it
        (while no page has a camera, the initial camera is framed on it twice a second)."""
        k = self._follow_index(bodies)
        if k is None or not self.follow:
            self._followed = None
            return
        p = bodies[k].position
        if self._followed is None or self._followed[0] != k:
            # a new body, or following again: from where the pages look now
            self._followed = (k, self.view.looked_at() - p)
            return
        if self.view.has_browser_camera:
            self.view.follow(p + self._followed[1])
        elif now_wall - self._aim_wall > 0.5:
            self._aim_wall = now_wall
            self._followed = (k, self._frame_body(bodies[k]) - p)

    def _states(self, now_ns: int, poses: dict[str, BoardPose | None]) -> list:
        """Each body's colour: grey once its data stopped (no event for three periods and
        at least 250 ms of network time, the edges' "stale"); notes how long it has been
        (``self._ages``) and how long it was when first drawn grey."""
        colours, ages = [], []
        for k, b in enumerate(self.bodies):
            slot = b.slot if isinstance(b, EdgeLayout) else b.now_slot
            count = self.board.count(slot)
            age = (now_ns - self.board.arrival_ns(slot)) * 1e-9 if count else None
            stale = poses.get(b.name) is not None and (
                classify(static=False, used=True, age_s=age, rate_hz=b.rate_hz,
                         gated_recently=False) == "stale"
            )  # fmt: skip
            if b.name in self._over:  # answers, but past the data: held, grey
                stale, age = True, max(age or 0.0, self._over[b.name])
            if stale:
                self._grey_after.setdefault(b.name, age)
            else:
                self._grey_after.pop(b.name, None)
            ages.append(age if stale else None)
            colours.append(GREY if stale else self.colours[k])
        self._ages = ages
        return colours

    def _relabel(self, bodies: list, places: dict[str, tuple]) -> None:
        """Body labels first (the selected query's, other queries', sensors'), then the
        frames', then the grid's scale; laid out for the first page's camera."""
        cam = self.view.camera()
        order = sorted(
            range(len(self.bodies)),
            key=lambda k: (self.bodies[k].name != self.selected_query,
                           isinstance(self.bodies[k], EdgeLayout)),
        )  # fmt: skip
        specs = []
        for k in order:
            b, drawn = self.bodies[k], bodies[k]
            age = self._ages[k] if k < len(self._ages) else None
            text = b.name if age is None else f"{b.name} - no data {age:.1f} s"
            pos = np.zeros(3) if drawn is None else drawn.position
            specs.append(LabelSpec(f"body{k}", text, pos, "body", visible=drawn is not None))
        for i, f in enumerate(self.layout.frames):
            p = places.get(f)
            pos = np.zeros(3) if p is None else p[1]
            specs.append(LabelSpec(f"frame{i}", f"frame {f}", pos, "frame", visible=p is not None))
        if self.grid_spec is not None and self.show_grid:
            floor = cam.on_plane(0.2 * cam.width, 0.85 * cam.height, self.grid_spec.center[2])
            if floor is not None:
                specs.append(
                    LabelSpec("scale", self.grid_spec.text, self.grid_spec.mark(floor), "note")
                )
        self.labels.update(specs, cam)

    def _read(self, b: EdgeLayout | QueryLayout) -> BoardPose | None:
        return self.board.read_pose(b.slot if isinstance(b, EdgeLayout) else b.now_slot)

    def _place_frames(self, poses: dict[str, BoardPose | None]) -> dict[str, tuple]:
        """Placement ``T_anchor_frame`` as ``(quaternion (4,), position (3,))`` of every
        frame reachable from the anchor through static values and the newest sensor poses."""
        values = list(self._statics)
        for e in self.layout.edges:
            p = None if e.static else poses.get(e.name)
            if p is not None:
                values.append((e.source, e.target, p.quaternion, p.position))
        return place_frames(self.anchor, values)

    def _collect(self, places: dict[str, tuple], poses: dict[str, BoardPose | None]):
        """Every body's pose (and prediction) in the anchor frame, with its trail (and its
        whole path, kept)."""
        keep = max(2, int(self.style.trail_s * self.rate_hz))
        todo = []  # (body index, frame placement, pose, prediction or None)
        for k, b in enumerate(self.bodies):
            pose, ahead = poses[b.name], None
            if isinstance(b, EdgeLayout):
                if not self.show_sensors:
                    pose = None
            elif b.ahead_slot is not None and self.offset_s > 0 and b.name not in self._over:
                ahead = self.board.read_pose(b.ahead_slot)
                # only the prediction made with this answer (an unanswered pull leaves the
                # previous one on the board)
                due = None if pose is None else pose.t_ns + round(self.offset_s * 1e9)
                if ahead is not None and (due is None or abs(ahead.t_ns - due) > 1_000_000):
                    ahead = None
            if pose is not None and b.source in places:
                todo.append((k, places[b.source], pose, ahead))
        bodies: list[BodyFrame | None] = [None] * len(self.bodies)
        trails: list[np.ndarray | None] = [None] * len(self.bodies)
        if not todo:
            return bodies, trails
        fq = np.array([t[1][0] for t in todo])
        fp = np.array([t[1][1] for t in todo])
        world = to_world(fq, fp, [t[2] for t in todo])
        has = [i for i, t in enumerate(todo) if t[3] is not None]
        pred = to_world(fq[has], fp[has], [todo[i][3] for i in has]) if has else None
        row = {i: j for j, i in enumerate(has)}
        step = 0.01 * self.style.axes_length  # a path point per 1 % of an axis moved
        for i, (k, *_rest) in enumerate(todo):
            ghost = None
            if pred is not None and i in row:
                j = row[i]
                ghost = (pred[0][j], pred[1][j], pred[2][j])
            p = world[0][i]
            bodies[k] = BodyFrame(p, world[1][i], world[2][i], predicted=ghost)
            name = self.bodies[k].name
            trail = self._trails.setdefault(name, [])
            trail.append(p)
            del trail[:-keep]
            trails[k] = np.array(trail)
            path = self._paths.setdefault(name, [])
            if not path or np.linalg.norm(p - path[-1]) > step:
                path.append(p)
                if len(path) > PATH_POINTS:
                    del path[1::2]
        return bodies, trails

    def _path_array(self, name: str) -> np.ndarray | None:
        path = self._paths.get(name)
        return np.array(path) if path and len(path) > 1 else None

    def _update_panel(self, now_ns: int) -> None:
        st = self.monitor.statuses(now_ns, self.rejections, self.offsets_ms, self.selected_query)
        html = render_panel(self.layout.frames, st) + render_attributes(self.attributes)
        if html != self._panel_html:
            self._panel_html = html
            self.panel.content = html

    def _update_legend(self, poses: dict[str, BoardPose | None]) -> None:
        lines = []
        for k, b in enumerate(self.bodies):
            pose = poses.get(b.name)
            age = self._ages[k] if k < len(self._ages) else None
            colour = GREY if age is not None else self.colours[k]
            kind = "sensor" if isinstance(b, EdgeLayout) else "query"
            lines.append(
                BodyLine(b.name, kind, colour, None if pose is None else pose.covariance,
                         age, self._grey_after.get(b.name))
            )  # fmt: skip
        text = live_legend(lines, self.style, self.grid_spec, self.anchor, self.offset_s)
        if text != self.legend.content:
            self.legend.content = text

    def _update_plots(self, poses: dict[str, BoardPose | None]) -> None:
        e = next((e for e in self.layout.edges if e.name == self.selected_edge), None)
        if e is None or e.slot is None:
            return
        t, lat, nis = self.board.read_ring(e.slot)
        if len(t) < 2:
            return
        pose = poses.get(e.name)
        ring = self._sigmas.setdefault(e.name, [])
        if pose is not None and (not ring or ring[-1][0] != pose.t_ns * 1e-9):
            pos_mm, ori_deg = sigma_sizes(pose.covariance, 1.0)
            ring.append((pose.t_ns * 1e-9, pos_mm, ori_deg))
            del ring[:-300]
        if len(ring) >= 2:
            s = np.array(ring)
            self.plots["pos"].data = (s[:, 0], s[:, 1])
            self.plots["ori"].data = (s[:, 0], s[:, 2])
        ts = t * 1e-9
        self.plots["lat"].data = (ts, lat * 1e-6)
        self.plots["nis"].data = nis_data(ts, nis)

    def edge_csv(self) -> bytes:
        """The selected edge's recent updates as CSV (what its time plots show): the
        measurement time [s, network clock], the delivery latency [ms] and the NIS (NaN:
        none formed)."""
        e = next((e for e in self.layout.edges if e.name == self.selected_edge), None)
        if e is None or e.slot is None:
            return csv_bytes(["t_s", "latency_ms", "nis"], [[], [], []])
        t, lat, nis = self.board.read_ring(e.slot)
        return csv_bytes(["t_s", "latency_ms", "nis"], [t * 1e-9, lat * 1e-6, nis], digits=15)

    def report(self) -> dict:
        """What the page shows, as plain data (tests and tools): the anchor, the labels and
        the camera they were laid out for (:meth:`LabelLayer.report`), every body's colour
        and how long it has been without data, the grid's scale."""
        with self._lock:
            bodies = []
            for k, b in enumerate(self.bodies):
                age = self._ages[k] if k < len(self._ages) else None
                bodies.append({
                    "name": b.name,
                    "kind": "sensor" if isinstance(b, EdgeLayout) else "query",
                    "grey": age is not None,
                    "no_data_s": age,
                    "grey_after_s": self._grey_after.get(b.name),
                    "extrapolated_s": self._over.get(b.name),
                    "colour": list(GREY if age is not None else self.colours[k]),
                })  # fmt: skip
            return {
                "anchor": self.anchor,
                "browser_camera": self.view.has_browser_camera,
                "bodies": bodies,
                "grid": None if self.grid_spec is None else self.grid_spec.text,
                **self.labels.report(),
            }

    def close(self) -> None:
        self.view.close()


def _clock_text(now_ns: int) -> str:
    """The network clock for the status line: seconds from the start of a replayed or
    simulated run, the UTC time of day on a live run's host clock (Unix time)."""
    if now_ns > 10**18:  # after 2001 on the Unix clock: a live run
        t = time.gmtime(now_ns // 1_000_000_000)
        return f"{time.strftime('%H:%M:%S', t)}.{now_ns // 1_000_000 % 1000:03d} UTC"
    return f"{now_ns * 1e-9:.2f} s"
