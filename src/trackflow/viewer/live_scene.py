"""One browser tab's page of a live network, drawn from the view's shared state.

Everything is drawn in one anchor frame chosen by the user (the room by default,
:func:`trackflow.viewer.edges.default_anchor`): frames placed by chaining static values and the
newest sensor poses, every sensor's filtered pose and every query's answer with its error
glyphs, the fading trail and the whole path, a floor grid with its scale, labels laid out
without overlaps and a legend. A body whose data stopped (a stale or down sensor, a query
without answers) is drawn grey and its label says for how long. The default camera frames the
selected query's body; with "follow" on the camera moves along with it.

Each tab has its own :class:`LiveScene` (:mod:`trackflow.viewer.live_loop`) with its own
controls; what it draws comes from the :class:`~trackflow.viewer.live_state.LiveState` all
tabs share (the poses read once per view frame, the bodies' paths, the prediction offset).
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable

import numpy as np

from .attributes_panel import render_attributes
from .batch import HIDDEN, BatchDrawing, BodyFrame
from .camera import body_glyph_points
from .decor import add_floor_grid, grid_spec
from .edges import EdgeLayout, QueryLayout, ViewLayout
from .export import csv_bytes, save_render
from .glyphs import to_wxyz
from .graph_panel import render_panel
from .labels import LabelLayer, LabelSpec
from .legend import BodyLine, live_legend
from .live_state import Anchored, LiveState, scene_box
from .scene import Style
from .server import SECONDS_AXIS, Pages, linked_cursor
from .time_plots import nis_data, nis_series

__all__ = ["LIVE_COVERAGE", "SETTINGS", "LiveScene", "default_settings"]

#: Part of the page the followed body's glyph covers on the default camera: less than a
#: recording's, a live setup's other bodies and frames are around it.
LIVE_COVERAGE = 0.06
#: A tab's own settings (the keys of :meth:`LiveScene.apply` besides ``offset_s``).
SETTINGS = (
    "sigma", "magnify", "ghost_magnify", "show_path", "show_trail", "paused", "show_sensors",
    "selected_query", "selected_edge", "anchor", "follow", "show_grid", "show_labels",
)  # fmt: skip
_STYLE_KEYS = ("sigma", "magnify", "ghost_magnify", "show_path", "show_trail")
#: How a control's value becomes a setting (the rest are checkboxes: bool).
_FROM_CONTROL = {
    "sigma": float, "magnify": float, "ghost_magnify": float, "selected_query": str,
    "selected_edge": str, "anchor": str,
}  # fmt: skip
#: The prediction slider's hint: the offset is the dataflow process's, one for every tab.
OFFSET_HINT = "shared by every tab: the dataflow process predicts once for all"


def default_settings(layout: ViewLayout, style: Style, anchor: str | None = None) -> dict:
    """The settings a tab starts with: ``style``'s, the layout's root (or ``anchor``), the
    first query and the first measured edge, everything shown, follow on, not paused."""
    return {
        **{k: getattr(style, k) for k in _STYLE_KEYS},
        "paused": False, "show_sensors": True,
        "selected_query": layout.queries[0].name if layout.queries else None,
        "selected_edge": next((e.name for e in layout.edges if not e.static), None),
        "anchor": anchor or layout.root,
        "follow": True, "show_grid": True, "show_labels": True,
    }  # fmt: skip


class LiveScene:
    """One tab's page of a live network: its own controls, drawn from the shared ``state``.

    Parameters
    ----------
    page : Pages
        What it draws on: a tab's :class:`~trackflow.viewer.server.ClientView` (or a whole
        :class:`~trackflow.viewer.server.ViewServer`, every page alike).
    state : LiveState
        What every tab shares; :meth:`render_frame` draws its current tick.
    style : Style, optional
        How poses are drawn (copied: the tab's controls change its own copy).
    settings : dict, optional
        The tab's starting settings (:data:`SETTINGS`; default :func:`default_settings`).
    on_offset : callable, optional
        ``on_offset(seconds)`` when the prediction slider moves (the offset is the dataflow
        process's, shared by every tab); default: it sets ``state.offset_s``.

    Attributes
    ----------
    anchor : str
        The frame everything is drawn in.
    """

    def __init__(
        self, page: Pages, state: LiveState, style: Style | None = None,
        settings: dict | None = None, on_offset: Callable[[float], None] | None = None,
    ):  # fmt: skip
        self.view, self.state = page, state
        self.layout, self.board = state.layout, state.board
        self.style = dataclasses.replace(style or Style(magnify=1.0))
        self.style.axes_length = state.axes_length
        self._on_offset = on_offset or self._set_offset
        self._lock = threading.RLock()
        self._closed = False
        self._framed = False
        self._move_browsers = False
        self._panel_html = ""
        self._panel_wall = self._plot_wall = self._label_wall = self._aim_wall = 0.0
        self._followed: tuple[int, np.ndarray] | None = None  # (body, look-at offset from it)
        self._last: tuple[list, dict] | None = None  # bodies and frames last drawn
        self.grid = self.grid_spec = None
        s = {**default_settings(self.layout, self.style), **(settings or {})}
        for k in _STYLE_KEYS:
            setattr(self.style, k, s[k])
        self.paused, self.show_sensors = bool(s["paused"]), bool(s["show_sensors"])
        self.selected_query, self.selected_edge = s["selected_query"], s["selected_edge"]
        self.anchor = s["anchor"] if s["anchor"] in self.layout.frames else self.layout.root
        self.follow, self.show_grid = bool(s["follow"]), bool(s["show_grid"])
        self.show_labels = bool(s["show_labels"])
        self.view.look_at((0.3, 0.0, 0.2), 1.2)
        self._build_scene()
        self._build_controls()
        self.labels.shown = self.show_labels
        self.view.on_camera(self._camera_moved)

    @property
    def url(self) -> str:
        return self.view.url

    @property
    def bodies(self) -> list[EdgeLayout | QueryLayout]:
        """What is drawn: every sensor with a board slot, then every query with answers."""
        return self.state.bodies

    def _set_offset(self, offset_s: float) -> None:
        self.state.offset_s = offset_s

    # -- construction ----------------------------------------------------------------------------
    def _build_scene(self) -> None:
        scene, st, lay = self.view.scene, self.style, self.layout
        n = len(lay.frames)
        self.frame_axes = scene.add_batched_axes(
            "/frames", np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), np.zeros((n, 3)),
            np.where(np.array(lay.frames) == self.anchor, 1.0, HIDDEN),
            axes_length=st.axes_length * 1.2, axes_radius=st.axes_length * 0.03,
        )  # fmt: skip
        self.batch: BatchDrawing | None = None  # made once the scene's extent is known
        self.labels = LabelLayer(scene, "/labels")

    def _build_controls(self) -> None:
        gui, lay, st = self.view.gui, self.layout, self.style
        with gui.add_folder("View"):
            names = tuple(q.name for q in lay.queries) or ("(none)",)
            query = self.selected_query if self.selected_query in names else names[0]
            self.c_query = gui.add_dropdown("query", names, initial_value=query)
            self.c_anchor = gui.add_dropdown("anchor", tuple(lay.frames), initial_value=self.anchor)
            self.c_sigma = gui.add_dropdown(
                "sigma", ("1", "2", "3"), initial_value=str(int(st.sigma))
            )
            self.c_offset = gui.add_slider(
                "prediction [ms]", min=0.0, max=300.0, step=5.0,
                initial_value=float(np.clip(self.state.offset_s * 1e3, 0.0, 300.0)),
                hint=OFFSET_HINT,
            )  # fmt: skip
            self.c_magnify = gui.add_number("magnify", st.magnify, min=1.0, step=1.0)
            self.c_ghost = gui.add_number("ghost magnify", st.ghost_magnify, min=1.0, step=1.0)
            self.c_sensors = gui.add_checkbox("sensors", self.show_sensors)
            self.c_pause = gui.add_checkbox("pause", self.paused)
        with gui.add_folder("Spatial relationship graph"):
            self.panel = gui.add_html("")
        with gui.add_folder("Legend"):
            self.legend = gui.add_markdown("")
        with gui.add_folder("Scene", expand_by_default=False):
            self.c_follow = gui.add_checkbox("follow body", self.follow)
            self.c_grid = gui.add_checkbox("grid", self.show_grid)
            self.c_path = gui.add_checkbox("path", st.show_path)
            self.c_trail = gui.add_checkbox("trail", st.show_trail)
            self.c_labels = gui.add_checkbox("labels", self.show_labels)
            reframe = gui.add_button("frame the body")
        with gui.add_folder("Save", expand_by_default=False):
            save_png = gui.add_button("save PNG")
            save_csv = gui.add_button("save CSV")
        save_png.on_click(lambda e: None if e.client is None else save_render(e.client))
        save_csv.on_click(
            lambda e: None if e.client is None else e.client.send_file_download(
                f"{self.selected_edge}.csv", self.edge_csv(), save_immediately=True)
        )  # fmt: skip
        self._build_plots()
        for key, (handle, _shown) in self._controls().items():
            if key == "offset_s":
                continue
            conv = _FROM_CONTROL.get(key, bool)
            handle.on_update(lambda _, h=handle, k=key, c=conv: self.apply(**{k: c(h.value)}))
        self.c_offset.on_update(lambda _: self._offset_moved(self.c_offset.value * 1e-3))
        reframe.on_click(lambda _: self.apply(reframe=True))

    def _build_plots(self) -> None:
        gui, lay = self.view.gui, self.layout
        with gui.add_folder("Time plots", expand_by_default=False):
            names = tuple(e.name for e in lay.edges if not e.static) or ("(none)",)
            edge = self.selected_edge if self.selected_edge in names else names[0]
            self.c_edge = gui.add_dropdown("edge", names, initial_value=edge)
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

    def _controls(self) -> dict:
        """``{setting: (control, how the control shows a value)}``."""
        return {
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

    # -- controls --------------------------------------------------------------------------------
    def _offset_moved(self, offset_s: float) -> None:
        if abs(offset_s - self.state.offset_s) > 1e-9:
            self._on_offset(offset_s)

    def apply(self, reframe: bool = False, **kw) -> None:
        """Set this tab's settings (:data:`SETTINGS`) and show them in its controls;
        ``offset_s`` only moves the prediction slider (the offset is shared:
        ``state.offset_s``); ``reframe`` aims the page's camera at the body afresh (as does
        a new anchor)."""
        with self._lock:
            for k, v in kw.items():
                if k in _STYLE_KEYS:
                    setattr(self.style, k, type(getattr(self.style, k))(v))
                elif k == "anchor":
                    if v in self.layout.frames and v != self.anchor:
                        self._reanchor(v)
                elif k in SETTINGS:
                    setattr(self, k, v)
                elif k != "offset_s":
                    raise KeyError(f"no live view setting {k!r}; one of {SETTINGS}")
            if reframe:  # the grid and the page's camera fitted again, paths kept
                self._framed, self._move_browsers = False, True
            if "show_grid" in kw and self.grid is not None:
                self.grid.visible = bool(self.show_grid)
            if "show_labels" in kw:
                self.labels.shown = bool(self.show_labels)
        controls = self._controls()
        for k, v in kw.items():
            handle, shown = controls[k]
            if handle.value != shown(v):
                handle.value = shown(v)

    def _reanchor(self, anchor: str) -> None:
        """Draw in ``anchor`` from now on (with that anchor's paths: the state's history of
        it, fresh if no tab drew in it); the grid and the camera are fitted again."""
        self.anchor = anchor
        self._framed = False
        self._followed = None
        self._move_browsers = True

    # -- drawing ---------------------------------------------------------------------------------
    def render_frame(self) -> None:
        """Draw the state's current tick (nothing while paused or once closed)."""
        with self._lock:
            if not (self._closed or self.paused):
                self._draw(self.state.anchored(self.anchor), time.perf_counter())

    def _draw(self, seen: Anchored, now_wall: float) -> None:
        bodies, trails = self._shown(seen.bodies), self._shown(seen.trails)
        places = seen.places
        self._last = (bodies, places)
        if not self._framed and seen.settled:
            self._frame_scene(places, bodies)
        frames = self.layout.frames
        shown = np.array([f in places for f in frames])
        fq = np.array([places[f][0] if f in places else (0.0, 0.0, 0.0, 1.0) for f in frames])
        fp = np.array([places[f][1] if f in places else (0.0, 0.0, 0.0) for f in frames])
        with self.view.atomic():
            self.frame_axes.batched_positions, self.frame_axes.batched_wxyzs = fp, to_wxyz(fq)
            self.frame_axes.batched_scales = np.where(shown, 1.0, HIDDEN)
            if self.batch is not None:
                self.batch.set_colors([self.state.colour(k) for k in range(len(self.bodies))])
                self.batch.update(bodies, trails)
            if self._framed:
                self._aim(bodies, now_wall)
            if now_wall - self._label_wall > 0.09:  # labels follow at 10 Hz at most
                self._label_wall = now_wall
                self._relabel(bodies, places)
        if now_wall - self._panel_wall > 0.2:
            self._panel_wall = now_wall
            self._update_panel()
        if now_wall - self._plot_wall > 0.5:
            self._plot_wall = now_wall
            self._update_plots()
            if self.batch is not None:
                paths = [self.state.path(self.anchor, b.name) for b in self.bodies]
                self.batch.update_paths(self._shown(paths))
            self._update_legend()
        self.view.set_status(self._status())

    def show_error(self, text: str) -> None:
        """Say on the tab's status line that drawing it failed, and why."""
        if not self._closed:
            self.view.set_status(f"**drawing failed:** {text} (details on the run's stderr)")

    def _shown(self, per_body: list) -> list:
        """``per_body`` with the sensors' entries None while sensors are hidden."""
        if self.show_sensors:
            return per_body
        return [None if isinstance(b, EdgeLayout) else x for b, x in zip(self.bodies, per_body)]

    def _status(self) -> str:
        st, offset_s = self.style, self.state.offset_s
        return (
            f"**live** - network t = {_clock_text(self.state.now_ns)} - {st.sigma:g} sigma"
            + (f", ellipsoids x{st.magnify:g}" if st.magnify != 1 else "")
            + (f" - predicted +{offset_s * 1e3:.0f} ms" if offset_s > 0 else "")
            + (f" (ghost x{st.ghost_magnify:g})" if offset_s > 0 else "")
            + f" - in frame {self.anchor}"
        )

    def _camera_moved(self) -> None:
        """The page moved its camera: lay the labels out for it (also while paused)."""
        with self._lock:
            if self._last is not None and not self._closed:
                self._relabel(*self._last)

    def _frame_scene(self, places: dict[str, tuple], bodies: list) -> None:
        """Once the anchor's scene is settled (its frames placed): lay the floor grid under
        the scene, aim the initial camera at the followed body (and, after a change of
        anchor or "frame the body", move the page's camera there), create the body nodes
        once (sized as the state sized the glyphs)."""
        lo, hi = scene_box(places, bodies)
        extent = max(float(np.max(hi - lo)), 0.3)
        if self.batch is None:
            self.style.axes_length = self.state.axes_length
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
            self.batch = BatchDrawing(self.view.scene, "/bodies", self.state.colours, self.style)
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
        """Follow the body: the page's camera looks at the same point relative to it (while
        the page has no camera, the initial camera is framed on it twice a second)."""
        k = self._follow_index(bodies)
        if k is None or not self.follow:
            self._followed = None
            return
        p = bodies[k].position
        if self._followed is None or self._followed[0] != k:
            # a new body, or following again: from where the page looks now
            self._followed = (k, self.view.looked_at() - p)
            return
        if self.view.has_browser_camera:
            self.view.follow(p + self._followed[1])
        elif now_wall - self._aim_wall > 0.5:
            self._aim_wall = now_wall
            self._followed = (k, self._frame_body(bodies[k]) - p)

    def _relabel(self, bodies: list, places: dict[str, tuple]) -> None:
        """Body labels first (the selected query's, other queries', sensors'), then the
        frames', then the grid's scale; laid out for the page's camera."""
        cam = self.view.camera()
        order = sorted(
            range(len(self.bodies)),
            key=lambda k: (self.bodies[k].name != self.selected_query,
                           isinstance(self.bodies[k], EdgeLayout)),
        )  # fmt: skip
        specs = []
        for k in order:
            b, drawn, age = self.bodies[k], bodies[k], self.state.age(k)
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

    def _update_panel(self) -> None:
        st = self.state
        statuses = st.monitor.statuses(st.now_ns, st.rejections, st.offsets_ms, self.selected_query)
        html = render_panel(self.layout.frames, statuses) + render_attributes(st.attributes)
        if html != self._panel_html:
            self._panel_html = html
            self.panel.content = html

    def _update_legend(self) -> None:
        lines = []
        for k, b in enumerate(self.bodies):
            pose, age = self.state.poses.get(b.name), self.state.age(k)
            kind = "sensor" if isinstance(b, EdgeLayout) else "query"
            lines.append(
                BodyLine(b.name, kind, self.state.colour(k),
                         None if pose is None else pose.covariance, age,
                         self.state.grey_after(b.name))
            )  # fmt: skip
        text = live_legend(lines, self.style, self.grid_spec, self.anchor, self.state.offset_s)
        if text != self.legend.content:
            self.legend.content = text

    def _update_plots(self) -> None:
        e = next((e for e in self.layout.edges if e.name == self.selected_edge), None)
        if e is None or e.slot is None:
            return
        t, lat, nis = self.board.read_ring(e.slot)
        if len(t) < 2:
            return
        s = self.state.sigma_ring(e.name)
        if s is not None:
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
            return {
                "anchor": self.anchor,
                "browser_camera": self.view.has_browser_camera,
                "bodies": self.state.body_reports(),
                "grid": None if self.grid_spec is None else self.grid_spec.text,
                **self.labels.report(),
            }

    def close(self) -> None:
        """Remove the page's part (its scene and controls; a whole server is closed)."""
        with self._lock:
            self._closed = True
        self.view.close()


def _clock_text(now_ns: int) -> str:
    """The network clock for the status line: seconds from the start of a replayed or
    simulated run, the UTC time of day on a live run's host clock (Unix time)."""
    if now_ns > 10**18:  # after 2001 on the Unix clock: a live run
        t = time.gmtime(now_ns // 1_000_000_000)
        return f"{time.strftime('%H:%M:%S', t)}.{now_ns // 1_000_000 % 1000:03d} UTC"
    return f"{now_ns * 1e-9:.2f} s"
