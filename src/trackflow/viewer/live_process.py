"""The view process of a live network: the viser page, drawn from the shared board.

:func:`main` runs in its own process (started by :func:`trackflow.viewer.attach_view`, at a
lower scheduling priority): it attaches the :class:`~trackflow.viewer.board.Board`, serves the
page, and draws at the view rate (30-60 Hz; 2 Hz while no browser is connected) from the poses
and rings the taps wrote. Nothing here holds the dataflow process's interpreter lock: the
dataflow and the view share only memory and a pipe. Messages on the pipe:

* to the view: ``("stats", rejections, offsets_ms)`` (a few times a second, when they
  changed), ``("set", {name: value})`` (the Python API's controls), ``("stop",)``;
* from the view: ``("ready", url)`` or ``("failed", message)`` once, ``("offset", seconds)``
  when the prediction slider moves (the dataflow process moves its prediction samplers).
"""

from __future__ import annotations

import logging
import math
import os
import sys
import threading
import time

import numpy as np

from ..errors import InputError
from ..math import quat_conjugate, quat_multiply, quat_to_matrix
from .batch import HIDDEN, BatchDrawing, BodyFrame
from .board import Board, BoardPose
from .edges import EdgeLayout, EdgeMonitor, QueryLayout, ViewLayout
from .glyphs import to_wxyz
from .graph_panel import render_panel
from .scene import PALETTE, Style
from .server import SECONDS_AXIS, ViewServer

__all__ = ["LiveScene", "main"]

#: Frames per second drawn while no browser is connected (keeps trails and plots current).
IDLE_RATE_HZ = 2.0


class LiveScene:
    """The page of a live network, drawn from ``board`` as ``layout`` describes it.

    Attributes
    ----------
    frames_sent : int
        View frames pushed to the page (also written to the board's header).
    """

    def __init__(
        self, layout: ViewLayout, board: Board, host: str, port: int, rate_hz: float,
        style: Style | None,
        send=None,
    ):  # fmt: skip
        self.layout, self.board, self.rate_hz = layout, board, float(rate_hz)
        self.style = style or Style(axes_length=0.08, magnify=1.0)
        self.send = send or (lambda msg: None)
        self.view = ViewServer(host, port, title="trackflow live")
        self.view.look_at((0.3, 0.0, 0.2), 1.2)
        self.monitor = EdgeMonitor(layout, board)
        self.rejections: dict[str, dict[str, int]] = {}
        self.offsets_ms: dict[str, float] = {}
        self.frames_sent = 0
        self.paused = False
        self.show_sensors = True
        self.offset_s = 0.0
        self.selected_query = layout.queries[0].name if layout.queries else None
        self.selected_edge = next((e.name for e in layout.edges if not e.static), None)
        self._lock = threading.RLock()
        self._framed = False
        self._first_placed: float | None = None
        self.auto_scale = style is None
        self._panel_html = ""
        self._panel_wall = self._plot_wall = self._label_wall = 0.0
        self._trails: dict[str, list] = {}
        self._statics = [
            (e.source, e.target, e.value.quaternion, e.value.position)
            for e in layout.edges
            if e.static and e.value is not None
        ]
        self._sigmas: dict[str, list] = {}
        self._build_scene()
        self._build_controls()

    @property
    def url(self) -> str:
        return self.view.url

    # -- construction ----------------------------------------------------------------------------
    def _build_scene(self) -> None:
        scene, st, lay = self.view.scene, self.style, self.layout
        n = len(lay.frames)
        self.frame_axes = scene.add_batched_axes(
            "/frames", np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), np.zeros((n, 3)),
            np.where(np.array(lay.frames) == lay.root, 1.0, HIDDEN),
            axes_length=st.axes_length * 1.2, axes_radius=st.axes_length * 0.05,
        )  # fmt: skip
        self.frame_labels = [
            scene.add_label(f"/frame_labels/{f}", f, visible=f == lay.root) for f in lay.frames
        ]
        self.bodies: list[EdgeLayout | QueryLayout] = [
            e for e in lay.edges if not e.static and e.slot is not None
        ]
        self.bodies += [q for q in lay.queries if q.now_slot is not None]
        self.batch: BatchDrawing | None = None  # made once the scene's extent is known
        self.labels = [
            scene.add_label(f"/bodies/label_{k}", b.name, visible=False)
            for k, b in enumerate(self.bodies)
        ]

    def _build_controls(self) -> None:
        gui, lay = self.view.gui, self.layout
        with gui.add_folder("View"):
            names = tuple(q.name for q in lay.queries) or ("(none)",)
            self.c_query = gui.add_dropdown("query", names, initial_value=names[0])
            self.c_sigma = gui.add_dropdown("sigma", ("1", "2", "3"), initial_value="1")
            self.c_offset = gui.add_slider(
                "prediction [ms]", min=0.0, max=300.0, step=5.0, initial_value=0.0
            )
            self.c_magnify = gui.add_number("magnify", self.style.magnify, min=1.0, step=1.0)
            self.c_sensors = gui.add_checkbox("sensors", True)
            self.c_pause = gui.add_checkbox("pause", False)
        self.c_query.on_update(lambda _: self.apply(selected_query=self.c_query.value))
        self.c_sigma.on_update(lambda _: self.apply(sigma=float(self.c_sigma.value)))
        self.c_offset.on_update(lambda _: self._offset_moved(self.c_offset.value * 1e-3))
        self.c_magnify.on_update(lambda _: self.apply(magnify=float(self.c_magnify.value)))
        self.c_sensors.on_update(lambda _: self.apply(show_sensors=bool(self.c_sensors.value)))
        self.c_pause.on_update(lambda _: self.apply(paused=bool(self.c_pause.value)))
        with gui.add_folder("Spatial relationship graph"):
            self.panel = gui.add_html("")
        with gui.add_folder("Time plots", expand_by_default=False):
            names = tuple(e.name for e in lay.edges if not e.static) or ("(none)",)
            self.c_edge = gui.add_dropdown("edge", names, initial_value=names[0])
            self.c_edge.on_update(lambda _: self.apply(selected_edge=self.c_edge.value))
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

    # -- controls --------------------------------------------------------------------------------
    def _offset_moved(self, offset_s: float) -> None:
        if abs(offset_s - self.offset_s) > 1e-9:
            self.apply(offset_s=offset_s)
            self.send(("offset", offset_s))

    def apply(self, **kw) -> None:
        """Set view state (``sigma``, ``magnify``, ``offset_s``, ``paused``, ``show_sensors``,
        ``selected_query``, ``selected_edge``) and show it in the controls."""
        with self._lock:
            for k, v in kw.items():
                if k in ("sigma", "magnify"):
                    setattr(self.style, k, float(v))
                else:
                    setattr(self, k, v)
        controls = {
            "sigma": (self.c_sigma, lambda v: str(int(v))),
            "magnify": (self.c_magnify, float),
            "offset_s": (self.c_offset, lambda v: float(v) * 1e3),
            "paused": (self.c_pause, bool),
            "show_sensors": (self.c_sensors, bool),
            "selected_query": (self.c_query, str),
            "selected_edge": (self.c_edge, str),
        }
        for k, v in kw.items():
            handle, conv = controls[k]
            if handle.value != conv(v):
                handle.value = conv(v)

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
        places = self._place_frames(poses)
        if not self._framed:
            self._frame_scene(places, now_wall)
        bodies, trails = self._collect(places, poses)
        frames = self.layout.frames
        shown = np.array([f in places for f in frames])
        fq = np.array([places[f][0] if f in places else (0.0, 0.0, 0.0, 1.0) for f in frames])
        fp = np.array([places[f][1] if f in places else (0.0, 0.0, 0.0) for f in frames])
        with self.view.server.atomic():
            self.frame_axes.batched_positions, self.frame_axes.batched_wxyzs = fp, to_wxyz(fq)
            self.frame_axes.batched_scales = np.where(shown, 1.0, HIDDEN)
            if self.batch is not None:
                self.batch.update(bodies, trails)
            if now_wall - self._label_wall > 0.09:  # labels follow at 10 Hz at most
                self._label_wall = now_wall
                lift = np.array([0.0, 0.0, self.style.axes_length * 0.6])
                for label, b in zip(self.labels, bodies):
                    label.visible = b is not None
                    if b is not None:
                        label.position = b.position + lift
                for label, on, p in zip(self.frame_labels, shown, fp):
                    label.visible = bool(on)
                    label.position = p - lift
        if now_wall - self._panel_wall > 0.2:
            self._panel_wall = now_wall
            self._update_panel(now_ns)
        if now_wall - self._plot_wall > 0.5:
            self._plot_wall = now_wall
            self._update_plots(poses)
        self.frames_sent += 1
        self.board.frames_sent = self.frames_sent
        self.view.set_status(
            f"**live** - network t = {_clock_text(now_ns)} - {self.style.sigma:g} sigma"
            + (f", ellipsoids x{self.style.magnify:g}" if self.style.magnify != 1 else "")
            + (f" - predicted +{self.offset_s * 1e3:.0f} ms" if self.offset_s > 0 else "")
        )

    def _frame_scene(self, places: dict[str, tuple], now_wall: float) -> None:
        """Once every frame is placed (or 2 s after the first body was, with what is placed):
        aim the initial camera of later clients at the frames and, with ``auto_scale``, size
        the glyphs to the scene (axes a tenth of its extent), then create the body nodes."""
        if len(places) < len(self.layout.frames):
            if len(places) < 2:
                return
            if self._first_placed is None:
                self._first_placed = now_wall
            if now_wall - self._first_placed < 2.0:
                return
        pts = np.array([p for _, p in places.values()])
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        extent = max(float(np.max(hi - lo)), 0.3)
        self.view.look_at(0.5 * (lo + hi), extent)
        if self.auto_scale:
            self.style.axes_length = float(np.clip(0.1 * extent, 0.02, 0.5))
        colours = [PALETTE[k % len(PALETTE)] for k in range(len(self.bodies))]
        if self.bodies:
            self.batch = BatchDrawing(self.view.scene, "/bodies", colours, self.style)
        self._framed = True

    def _read(self, b: EdgeLayout | QueryLayout) -> BoardPose | None:
        return self.board.read_pose(b.slot if isinstance(b, EdgeLayout) else b.now_slot)

    def _place_frames(self, poses: dict[str, BoardPose | None]) -> dict[str, tuple]:
        """World placement ``T_root_frame`` as ``(quaternion (4,), position (3,))`` of every
        frame reachable from the root through static values and the newest sensor poses."""
        known = {self.layout.root: (np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3))}
        values = list(self._statics)
        for e in self.layout.edges:
            p = None if e.static else poses.get(e.name)
            if p is not None:
                values.append((e.source, e.target, p.quaternion, p.position))
        rot = {self.layout.root: np.eye(3)}  # R_root_frame of the placed frames
        changed = True
        while changed:
            changed = False
            for a, b, q_ab, t_ab in values:
                if a in known and b not in known:
                    q_a, t_a = known[a]
                    known[b] = (quat_multiply(q_a, q_ab), rot[a] @ t_ab + t_a)
                    rot[b] = quat_to_matrix(known[b][0])
                    changed = True
                elif b in known and a not in known:
                    q_b, t_b = known[b]
                    q_a = quat_multiply(q_b, quat_conjugate(q_ab))
                    rot[a] = quat_to_matrix(q_a)
                    known[a] = (q_a, t_b - rot[a] @ t_ab)
                    changed = True
        return known

    def _collect(self, places: dict[str, tuple], poses: dict[str, BoardPose | None]):
        """Every body's pose (and prediction) in the world frame, with its trail."""
        keep = max(2, int(self.style.trail_s * self.rate_hz))
        todo = []  # (body index, frame placement, pose, prediction or None)
        for k, b in enumerate(self.bodies):
            pose, ahead = poses[b.name], None
            if isinstance(b, EdgeLayout):
                if not self.show_sensors:
                    pose = None
            elif b.ahead_slot is not None and self.offset_s > 0:
                ahead = self.board.read_pose(b.ahead_slot)
            if pose is not None and b.source in places:
                todo.append((k, places[b.source], pose, ahead))
        bodies: list[BodyFrame | None] = [None] * len(self.bodies)
        trails: list[np.ndarray | None] = [None] * len(self.bodies)
        if not todo:
            return bodies, trails
        fq = np.array([t[1][0] for t in todo])
        fp = np.array([t[1][1] for t in todo])
        world = _to_world(fq, fp, [t[2] for t in todo])
        has = [i for i, t in enumerate(todo) if t[3] is not None]
        pred = _to_world(fq[has], fp[has], [todo[i][3] for i in has]) if has else None
        row = {i: j for j, i in enumerate(has)}
        for i, (k, *_rest) in enumerate(todo):
            ghost = None
            if pred is not None and i in row:
                j = row[i]
                ghost = (pred[0][j], pred[1][j], pred[2][j])
            bodies[k] = BodyFrame(world[0][i], world[1][i], world[2][i], predicted=ghost)
            trail = self._trails.setdefault(self.bodies[k].name, [])
            trail.append(world[0][i])
            del trail[:-keep]
            trails[k] = np.array(trail)
        return bodies, trails

    def _update_panel(self, now_ns: int) -> None:
        st = self.monitor.statuses(now_ns, self.rejections, self.offsets_ms, self.selected_query)
        html = render_panel(self.layout.frames, st)
        if html != self._panel_html:
            self._panel_html = html
            self.panel.content = html

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
            c = pose.covariance
            pos_mm = math.sqrt(max(np.linalg.eigvalsh(c[:3, :3])[-1], 0.0)) * 1e3
            ori_deg = math.degrees(math.sqrt(max(np.linalg.eigvalsh(c[3:, 3:])[-1], 0.0)))
            ring.append((pose.t_ns * 1e-9, pos_mm, ori_deg))
            del ring[:-300]
        if len(ring) >= 2:
            s = np.array(ring)
            self.plots["pos"].data = (s[:, 0], s[:, 1])
            self.plots["ori"].data = (s[:, 0], s[:, 2])
        ts = t * 1e-9
        self.plots["lat"].data = (ts, lat * 1e-6)
        self.plots["nis"].data = (ts, np.nan_to_num(nis))

    def close(self) -> None:
        self.view.close()


def _clock_text(now_ns: int) -> str:
    """The network clock for the status line: seconds from the start of a replayed or
    simulated run, the UTC time of day on a live run's host clock (Unix time)."""
    if now_ns > 10**18:  # after 2001 on the Unix clock: a live run
        t = time.gmtime(now_ns // 1_000_000_000)
        return f"{time.strftime('%H:%M:%S', t)}.{now_ns // 1_000_000 % 1000:03d} UTC"
    return f"{now_ns * 1e-9:.2f} s"


def _to_world(q_w_a: np.ndarray, t_w_a: np.ndarray, poses: list[BoardPose]):
    """``T_w_a @ pose`` for n bodies with their frames' placements exact (quaternions
    (n, 4), positions (n, 3)): world positions (n, 3), quaternions (n, 4) and covariances
    (n, 6, 6) (the translation error rotates with ``R_w_a``; the body-frame rotation error
    does not change)."""
    r = quat_to_matrix(q_w_a)
    pos = np.einsum("nij,nj->ni", r, np.array([p.position for p in poses])) + t_w_a
    quat = quat_multiply(q_w_a, np.array([p.quaternion for p in poses]))
    c = np.array([p.covariance for p in poses])
    c[:, :3, :] = r @ c[:, :3, :]
    c[:, :, :3] = c[:, :, :3] @ np.swapaxes(r, -1, -2)
    return pos, quat, c


#: View process priorities: ``low`` is niceness +10, ``idle`` runs only on CPU time no other
#: process wants (Linux ``SCHED_IDLE``; elsewhere the lowest niceness), ``normal`` as is.
PRIORITIES = ("idle", "low", "normal")


def lower_priority(priority: str) -> str:
    """Lower this process's CPU priority (before it starts threads, which inherit it);
    returns what was applied (``SCHED_IDLE``, ``nice +N`` or ``normal``)."""
    if priority not in PRIORITIES:
        raise InputError(f"view priority must be one of {PRIORITIES}, got {priority!r}")
    if priority == "normal":
        return "normal"
    if priority == "idle" and hasattr(os, "SCHED_IDLE"):
        try:
            os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
            return "SCHED_IDLE"
        except OSError:
            pass  # not permitted here: fall back to the lowest niceness
    step = 19 if priority == "idle" else 10
    os.nice(step)
    return f"nice +{step}"


def main(conn) -> None:
    """The view process: receive ``(layout, board name, options)``, serve and draw until
    ``("stop",)`` arrives or the connection closes.

    ``options``: ``host``, ``port``, ``rate_hz``, ``style`` (:class:`Style`), ``priority``
    (:func:`lower_priority`)."""
    send_lock = threading.Lock()

    def send(msg) -> None:
        with send_lock:
            try:
                conn.send(msg)
            except (BrokenPipeError, OSError):
                pass  # the dataflow process is gone; the receiver stops us

    board = None
    try:
        layout, board_name, options = conn.recv()
        lower_priority(options.get("priority", "low"))
        # a browser that opens a speculative connection and drops it is not an error here
        logging.getLogger("websockets.server").setLevel(logging.CRITICAL)
        board = Board.attach(board_name)
        scene = LiveScene(
            layout, board, options["host"], options["port"], options["rate_hz"],
            options["style"], send,
        )  # fmt: skip
    except (EOFError, OSError):
        if board is not None:
            board.close()
        return  # the dataflow process went away before we started
    except Exception as exc:  # reported to the dataflow process, which raises it
        if board is not None:
            board.close()  # its views released, so the interpreter's exit is quiet
        send(("failed", f"{type(exc).__name__}: {exc}"))
        return
    stop = threading.Event()

    def receive() -> None:
        while not stop.is_set():
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                break
            if msg[0] == "stop":
                break
            if msg[0] == "stats":
                scene.rejections, scene.offsets_ms = msg[1], msg[2]
            elif msg[0] == "set":
                scene.apply(**msg[1])
        stop.set()

    receiver = threading.Thread(target=receive, daemon=True, name="trackflow-view-pipe")
    receiver.start()
    send(("ready", scene.url))
    try:
        scene.loop(stop)
    finally:
        scene.close()
        board.close()


if __name__ == "__main__":
    from multiprocessing.connection import Connection

    main(Connection(int(sys.argv[1])))
