"""``trackflow view RECORDING``: a recording on a timeline with its filtered error.

The recording is filtered once by the untuned default Kalman predictor of
:mod:`trackflow.evaluation` (noise estimated from the data); the view shows, at the chosen
time, the measured pose, the filtered pose with its position and orientation error glyphs, a
fading trail and - with a prediction offset - the pose predicted that far ahead from the state
at the chosen time, drawn beside the recording at that later time. A slider scrubs the
timeline; a play button plays it at a chosen speed. Keys: space plays or pauses, the left
and right arrows step a frame, ``[`` and ``]`` halve and double the speed
(:mod:`trackflow.viewer.shortcuts`); a click on a time plot goes to its time.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..evaluation import KalmanPredictor, default_gap, default_predictor
from ..io import PoseStream
from ..math import Pose, UncertainPose
from .camera import body_glyph_points
from .decor import add_floor_grid, grid_spec
from .export import csv_bytes, save_render
from .labels import LabelLayer, LabelSpec
from .legend import recording_legend
from .scene import PALETTE, PoseDrawing, Style, frame_node
from .server import ViewServer, linked_cursor, span_axis
from .shortcuts import add_shortcuts
from .time_plots import nis_data, nis_series

__all__ = ["RecordingTrack", "RecordingView", "auto_ghost_magnify", "auto_magnify"]

#: the label of the recording view's "go to" field (a click on a time plot types into it)
SEEK = "go to [s]"
#: the recording view's keys: key -> (the button it presses, what it does)
KEYS = {
    " ": ("play / pause", "play or pause"),
    "ArrowLeft": ("\u25c0", "a frame back"),
    "ArrowRight": ("\u25b6", "a frame on"),
    "[": ("slower", "half speed"),
    "]": ("faster", "double speed"),
}


@dataclass
class RecordingTrack:
    """A recording ``T_a_b`` with its Kalman-filtered poses, ready to draw.

    Attributes
    ----------
    stream : PoseStream
    t : ndarray (N,)
        Times relative to the first sample [s].
    filtered : UncertainPose (N,)
        Posterior at every sample, 6x6 covariance over ``(dt, dtheta)``.
    nis : ndarray (N,)
        Normalised innovation squared per sample (NaN where none was formed).
    predictor : KalmanPredictor
    """

    stream: PoseStream
    t: np.ndarray
    filtered: UncertainPose
    nis: np.ndarray
    predictor: KalmanPredictor
    _predictions: dict = field(default_factory=dict, repr=False)

    @classmethod
    def from_stream(cls, stream: PoseStream, predictor: KalmanPredictor | None = None):
        """Filter ``stream`` (restarting after gaps, :func:`trackflow.evaluation.default_gap`)."""
        if len(stream.t_ns) < 3:
            raise InputError(f"recording {stream.source}->{stream.target}: fewer than 3 samples")
        t = (stream.t_ns - stream.t_ns[0]).astype(float) * 1e-9
        p, q = np.asarray(stream.position, float), np.asarray(stream.quaternion, float)
        pred = predictor or default_predictor(t, p, q)
        res = pred.run(t, pred.measurements(p, q), (0.0,), default_gap(t), covariance=True)
        return cls(stream, t, res.filtered, np.asarray(res.nis, float), pred)

    @property
    def duration(self) -> float:
        return float(self.t[-1])

    def index(self, t_s: float) -> int:
        """Index of the newest sample at or before ``t_s`` [s] (clipped to the recording)."""
        return int(np.clip(np.searchsorted(self.t, t_s, side="right") - 1, 0, len(self.t) - 1))

    def measured(self, k: int) -> Pose:
        return Pose(self.stream.position[k], self.stream.quaternion[k])

    def predicted(self, offset_s: float) -> UncertainPose:
        """Poses predicted ``offset_s`` ahead of every sample (cached per offset), (N,)."""
        key = round(float(offset_s), 4)
        if key not in self._predictions:
            p = np.asarray(self.stream.position, float)
            q = np.asarray(self.stream.quaternion, float)
            meas = self.predictor.measurements(p, q)
            res = self.predictor.run(self.t, meas, (key,), default_gap(self.t), covariance=True)
            if len(self._predictions) > 16:
                self._predictions.clear()
            self._predictions[key] = res.predictions[key]
        return self._predictions[key]

    def prediction_errors(self, offset_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Measured against predicted error of the position predicted ``offset_s`` ahead:
        ``(t, error_mm, sigma_mm)`` at the samples whose target time ``t + offset_s`` lies
        within the recording, where ``error_mm`` = |predicted - recorded position| (the
        recording interpolated linearly at the target time) and ``sigma_mm`` the predicted
        RMS error ``sqrt(trace P_pos)`` (the expected size of that error, measurement noise
        of the recording aside)."""
        pred = self.predicted(offset_s)
        target = self.t + float(offset_s)
        ok = target <= self.t[-1]
        p = np.asarray(self.stream.position, float)
        truth = np.stack([np.interp(target[ok], self.t, p[:, i]) for i in range(3)], axis=1)
        err = np.linalg.norm(np.asarray(pred.position, float)[ok] - truth, axis=1) * 1e3
        cov = np.asarray(pred.covariance, float)[ok]
        sigma = np.sqrt(np.trace(cov[:, :3, :3], axis1=1, axis2=2)) * 1e3
        return self.t[ok], err, sigma

    def csv(self) -> bytes:
        """The filtered track as CSV: time [s] from the first sample, position [m],
        quaternion (x, y, z, w), the largest position and orientation sigma [mm, deg] and
        the NIS (NaN where none was formed), one row per sample."""
        f = self.filtered
        pos_mm, ori_deg = self.sigmas()
        header = ["t_s", "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw", "sigma_pos_mm",
                  "sigma_ori_deg", "nis"]  # fmt: skip
        cols = [self.t, *np.asarray(f.position).T, *np.asarray(f.quaternion).T, pos_mm,
                ori_deg, self.nis]  # fmt: skip
        return csv_bytes(header, cols)

    def sigmas(self) -> tuple[np.ndarray, np.ndarray]:
        """Largest 1-sigma position semi-axis [mm] and orientation sigma [deg] per sample."""
        c = self.filtered.covariance
        pos = np.sqrt(np.linalg.eigvalsh(c[:, :3, :3])[:, -1]) * 1e3
        ori = np.degrees(np.sqrt(np.linalg.eigvalsh(c[:, 3:, 3:])[:, -1]))
        return pos, ori


def auto_magnify(
    track: RecordingTrack, extent: float, sigma: float = 1.0, axes_length: float | None = None
) -> float:
    """A power of ten (at least 1) for the filter's ellipsoids.

    Without ``axes_length``: the one making the median position ellipsoid about 3 % of the
    scene ``extent``. With it: the largest keeping the median position ellipsoid and the median
    orientation disc (the axis tip's displacement, ``axes_length`` times the angle) within a
    quarter of the axes length, so that the body's glyph stays readable at the camera's
    distance."""
    pos_mm, ori_deg = track.sigmas()
    r = max(float(np.nanmedian(pos_mm)) * 1e-3 * sigma, 1e-9)
    if axes_length is None:
        return float(10.0 ** max(0, round(np.log10(0.03 * extent / r))))
    tip = axes_length * np.radians(float(np.nanmedian(ori_deg))) * sigma
    return float(10.0 ** max(0, np.floor(np.log10(0.25 * axes_length / max(r, tip, 1e-9)))))


def auto_ghost_magnify(
    track: RecordingTrack, offset_s: float, axes_length: float, sigma: float = 1.0
) -> float:
    """The prediction ghost's own magnification: the largest power of ten (at least 1) that
    keeps its median position ellipsoid within a quarter of the axes length.

    A prediction's error is centimetres where the filter's is a fraction of a millimetre, so
    the filter's magnification would blow the ghost up over the whole view."""
    if offset_s <= 0:
        return 1.0
    c = track.predicted(offset_s).covariance[:, :3, :3]
    r = np.sqrt(np.clip(np.linalg.eigvalsh(c)[:, -1], 0.0, None))
    r_med = max(float(np.nanmedian(r)) * sigma, 1e-9)
    return float(10.0 ** max(0, np.floor(np.log10(0.25 * axes_length / r_med))))


class RecordingView:
    """A viser page showing one recording with a timeline.

    The scene: the floor grid with its scale, the whole path as a faint line, the body with its
    error glyphs and 2 s trail, the frame's axes, labels laid out without overlaps and a
    legend. The default camera frames the body at the shown time (its glyph covers about a
    fifth of the page); with ``follow`` on (the default) the camera moves along with the body
    while it plays or is scrubbed.

    Parameters
    ----------
    track : RecordingTrack
    host, port : str, int
        Where the page is served (``127.0.0.1`` by default; ``port=0`` picks a free one).
    style : Style, optional
        Drawing options; by default the ellipsoids are magnified (:func:`auto_magnify`) and
        the ghost on its own scale (:func:`auto_ghost_magnify`).
    server : ViewServer, optional
        Show the view on this server (cleared first; ``host`` and ``port`` are not used):
        its open pages keep their cameras until :meth:`frame_body` moves them.
        :meth:`close` clears it again and leaves it running.
    """

    def __init__(self, track: RecordingTrack, host="127.0.0.1", port=8080, style=None, server=None):
        self.track = track
        s = track.stream
        self._own_server = server is None
        if server is None:
            server = ViewServer(host, port, title=f"trackflow: {s.source} -> {s.target}")
        else:
            server.clear()
        self.view = server
        pos = np.asarray(s.position, float)
        lo, hi = np.nanmin(pos, axis=0), np.nanmax(pos, axis=0)
        extent = float(np.max(hi - lo))
        self.auto_ghost = style is None
        self.style = style or Style(axes_length=max(extent * 0.08, 0.02))
        if style is None:
            self.style.magnify = auto_magnify(track, extent, axes_length=self.style.axes_length)
        scene = self.view.scene
        self.grid_spec = grid_spec(lo, hi)
        self.grid = add_floor_grid(scene, "/grid", self.grid_spec)
        frame_node(scene, f"/{s.source}", self.style.axes_length * 1.5)
        self.body = PoseDrawing(scene, f"/{s.source}/{s.target}", PALETTE[0], self.style)
        self.body.set_path(track.filtered.position)
        self.measured = scene.add_icosphere(
            f"/{s.source}/{s.target}_measured", radius=self.style.axes_length * 0.02,
            color=(60, 60, 60), opacity=0.6,
        )  # fmt: skip
        self.truth_ahead = scene.add_icosphere(
            f"/{s.source}/{s.target}_recorded_ahead", radius=self.style.axes_length * 0.03,
            color=(0, 0, 0), visible=False,
        )  # fmt: skip
        self.labels = LabelLayer(scene, "/labels")
        self._lock = threading.RLock()
        self._echo = False  # set while the view itself moves the slider
        self.t_s = 0.0
        self.offset_s = 0.0
        self._look_offset: np.ndarray | None = None  # where the camera looks, from the body
        self._playing = threading.Event()
        self._stop = threading.Event()
        self._build_controls()
        self.show(0.0)
        self._player = threading.Thread(target=self._play_loop, daemon=True, name="view-play")
        self._player.start()

    @property
    def url(self) -> str:
        return self.view.url

    # -- controls --------------------------------------------------------------------------------
    def _build_controls(self) -> None:
        gui, tr = self.view.gui, self.track
        with gui.add_folder("Timeline"):
            self.slider = gui.add_slider(
                "time [s]", min=0.0, max=round(tr.duration, 3), step=0.01, initial_value=0.0
            )
            self.play = gui.add_checkbox("play", False)
            self.speed = gui.add_slider("speed", min=0.1, max=4.0, step=0.1, initial_value=1.0)
            self.transport = gui.add_button_group("frame", ("\u25c0", "play / pause", "\u25b6"))
            self.pace = gui.add_button_group("pace", ("slower", "faster"))
            self.go_to = gui.add_text(SEEK, "", hint="a time [s] of the recording; a click on a "
                                      "time plot puts its time here")  # fmt: skip
            add_shortcuts(gui, KEYS, seek=SEEK, now=("time [s]", 0.0, tr.duration))
        with gui.add_folder("Error display"):
            self.sigma = gui.add_dropdown("sigma", ("1", "2", "3"), initial_value="1")
            self.offset = gui.add_slider(
                "prediction [ms]", min=0.0, max=500.0, step=5.0, initial_value=0.0
            )
            self.magnify = gui.add_number("magnify", self.style.magnify, min=1.0, step=1.0)
            self.ghost_magnify = gui.add_number(
                "ghost magnify", self.style.ghost_magnify, min=1.0, step=1.0
            )
            self.show_ori = gui.add_checkbox("orientation error", self.style.show_orientation)
        with gui.add_folder("Scene"):
            self.follow = gui.add_checkbox("follow body", True)
            self.show_grid = gui.add_checkbox("grid", True)
            self.show_path = gui.add_checkbox("path", self.style.show_path)
            self.show_trail = gui.add_checkbox("trail", self.style.show_trail)
            self.show_labels = gui.add_checkbox("labels", True)
            reframe = gui.add_button("frame the body")
        with gui.add_folder("Legend"):
            self.legend = gui.add_markdown("")
        with gui.add_folder("Save"):
            save_png = gui.add_button("save PNG")
            save_csv = gui.add_button("save CSV")
        name = f"{self.track.stream.source}_{self.track.stream.target}"
        save_png.on_click(
            lambda e: None if e.client is None else save_render(e.client, f"{name}.png")
        )
        save_csv.on_click(
            lambda e: None if e.client is None else e.client.send_file_download(
                f"{name}.csv", self.track.csv(), save_immediately=True)
        )  # fmt: skip
        self.slider.on_update(
            lambda _: None if self._echo else self.show(self.slider.value, from_slider=True)
        )
        self.play.on_update(
            lambda _: self._playing.set() if self.play.value else self._playing.clear()
        )
        self.transport.on_click(lambda e: self._transport(e.target.value))
        self.go_to.on_update(lambda _: None if self._echo else self._go_to(self.go_to.value))
        self.pace.on_click(lambda e: self._pace(2.0 if e.target.value == "faster" else 0.5))
        for control in (self.sigma, self.magnify, self.show_ori, self.show_path,
                        self.show_trail, self.show_labels):  # fmt: skip
            control.on_update(lambda _: self._restyle())
        self.ghost_magnify.on_update(lambda _: None if self._echo else self._ghost_set())
        self.show_grid.on_update(lambda _: setattr(self.grid, "visible", self.show_grid.value))
        self.follow.on_update(lambda _: self._refollow())
        reframe.on_click(lambda _: self.frame_body(move_browsers=True))
        self.offset.on_update(
            lambda _: None if self._echo else self.set_offset(self.offset.value * 1e-3)
        )
        self.view.on_camera(self._relabel)
        pos_mm, ori_deg = tr.sigmas()
        self._plots(pos_mm, ori_deg)

    def _plots(self, pos_mm: np.ndarray, ori_deg: np.ndarray) -> None:
        gui, t = self.view.gui, self.track.t
        step = max(1, len(t) // 2000)  # a plot needs no more points than pixels
        linked = linked_cursor("recording")  # one time under the pointer in every plot
        span = span_axis(0.0, self.track.duration)  # one time span: the current-time line
        with gui.add_folder("Time plots", expand_by_default=False):
            for title, y, unit in (
                ("position sigma (largest axis)", pos_mm, "mm"),
                ("orientation sigma (largest axis)", ori_deg, "deg"),
            ):
                gui.add_uplot(
                    scales=span, cursor=linked,
                    data=(t[::step], np.asarray(y[::step], float)),
                    series=({"label": "t [s]"}, {"label": f"{title} {unit}", "stroke": "#c0c"}),
                    title=title, aspect=2.0,
                )  # fmt: skip
            gui.add_uplot(
                scales=span, cursor=linked,
                data=nis_data(t[::step], self.track.nis[::step]),
                series=nis_series("#c0c"), title="NIS (the band: 95 % of a consistent filter's)",
                aspect=2.0,
            )  # fmt: skip
            self.error_plot = gui.add_uplot(
                scales=span, cursor=linked, data=self._no_errors(),
                series=({"label": "t [s]"}, {"label": "measured error [mm]", "stroke": "#c0c"},
                        {"label": "predicted RMS error [mm]", "stroke": "#2a2"}),
                title="prediction error at the prediction offset (set it above)", aspect=2.0,
            )  # fmt: skip

    def _no_errors(self) -> tuple[np.ndarray, ...]:
        """The error plot's data at offset 0: zeros over the recording's time span (the
        plots share one cursor by time)."""
        return (self.track.t[[0, -1]].astype(float), np.zeros(2), np.zeros(2))

    def _update_error_plot(self) -> None:
        """The error plot for the current offset (empty at 0)."""
        if self.offset_s <= 0.0:
            self.error_plot.data = self._no_errors()
            return
        t, err, sigma = self.track.prediction_errors(self.offset_s)
        step = max(1, len(t) // 2000)
        self.error_plot.data = (t[::step], err[::step], sigma[::step])

    def _restyle(self) -> None:
        self.style.sigma = float(self.sigma.value)
        self.style.magnify = float(self.magnify.value)
        self.style.show_orientation = bool(self.show_ori.value)
        self.style.show_path = bool(self.show_path.value)
        self.style.show_trail = bool(self.show_trail.value)
        self.labels.shown = bool(self.show_labels.value)
        if self.auto_ghost:
            self._auto_ghost()
        self.show(self.t_s)

    def _auto_ghost(self) -> None:
        st = self.style
        st.ghost_magnify = auto_ghost_magnify(self.track, self.offset_s, st.axes_length, st.sigma)
        self._set_control(self.ghost_magnify, st.ghost_magnify)

    def _ghost_set(self) -> None:
        """The user chose the ghost's magnification: it is no longer chosen automatically."""
        self.auto_ghost = False
        self.style.ghost_magnify = float(self.ghost_magnify.value)
        self.show(self.t_s)

    def _set_control(self, handle, value) -> None:
        if handle.value != value:
            self._echo = True
            try:
                handle.value = value
            finally:
                self._echo = False

    # -- state -----------------------------------------------------------------------------------
    def set_offset(self, offset_s: float) -> None:
        """Set the prediction offset [s] (0 hides the predicted pose)."""
        self.offset_s = max(0.0, float(offset_s))
        if abs(self.offset.value - self.offset_s * 1e3) > 1e-6:
            self._set_control(self.offset, self.offset_s * 1e3)
        if self.auto_ghost:
            self._auto_ghost()
        self._update_error_plot()
        self.show(self.t_s)

    def set_sigma(self, sigma: float) -> None:
        self.sigma.value = str(int(sigma))
        self._restyle()

    def set_scene(self, **shown: bool) -> None:
        """Show or hide parts of the scene: ``grid``, ``path``, ``trail``, ``labels``,
        ``follow`` (the controls of the "Scene" folder)."""
        handles = {"grid": self.show_grid, "path": self.show_path, "trail": self.show_trail,
                   "labels": self.show_labels, "follow": self.follow}  # fmt: skip
        for name, value in shown.items():
            if name not in handles:
                raise InputError(f"no scene part {name!r}; one of {sorted(handles)}")
            handles[name].value = bool(value)
        self.grid.visible = bool(self.show_grid.value)
        self._restyle()

    def body_points(self) -> np.ndarray:
        """The points bounding the body's glyph at the shown time (4, 3): its position and
        axis tips (what the default camera frames)."""
        pose = self.track.filtered[self.track.index(self.t_s)]
        return body_glyph_points(pose.position, pose.quaternion, self.style.axes_length)

    def frame_body(self, move_browsers: bool = False) -> None:
        """Aim the initial camera at the body (its glyph covers about a fifth of the page);
        ``move_browsers`` moves the cameras of open pages there too."""
        pts = self.body_points()
        self._look_offset = self.view.frame(pts, centre=pts[0]) - pts[0]
        if move_browsers:
            self.view.reset_cameras()
        self._relabel()

    def place_camera(self, position, look_at, move_browsers: bool = False) -> None:
        """The camera at ``position`` looking at ``look_at`` (3,) [m, the recording's source
        frame]; the body is no longer followed (the camera stays where it was put)."""
        with self._lock:
            self.follow.value = False
            self.view.place_camera(position, look_at, move_browsers)
            self._look_offset = np.asarray(look_at, float) - self.body_points()[0]

    def _refollow(self) -> None:
        """Following again: from where the pages look now, relative to the body."""
        if self.follow.value:
            self._look_offset = self.view.looked_at() - self.body_points()[0]

    def _aim(self) -> None:
        """The camera with the body: framed afresh while no page has its own camera yet,
        else (following) moved along with the body."""
        p = self.body_points()[0]
        if self._look_offset is None or not self.view.has_browser_camera:
            if self.follow.value or self._look_offset is None:
                self.frame_body()
            return
        if self.follow.value:
            self.view.follow(p + self._look_offset)

    def _relabel(self) -> None:
        with self._lock:
            s, tr = self.track.stream, self.track
            k = tr.index(self.t_s)
            p = np.asarray(tr.filtered.position[k], float)
            cam = self.view.camera()
            specs = [
                LabelSpec("body", s.target, p, "body"),
                LabelSpec("frame", f"frame {s.source}", np.zeros(3), "frame"),
            ]
            # the grid's scale on the floor in the lower left of the page, where it shows
            floor = cam.on_plane(0.2 * cam.width, 0.85 * cam.height, self.grid_spec.center[2])
            if floor is not None and self.show_grid.value:
                mark = self.grid_spec.mark(floor)
                specs.append(LabelSpec("scale", self.grid_spec.text, mark, "note"))
            self.labels.update(specs, cam)

    def _go_to(self, text: str) -> None:
        """The ``go to`` field (typed, or a click on a time plot): show that time."""
        try:
            t = float(text)
        except ValueError:
            if text.strip():
                self.view.set_status(f"go to: {text!r} is not a time in seconds")
            return
        if np.isfinite(t):
            self.set_playing(False)
            self.show(t)

    def _transport(self, what: str) -> None:
        """A button of the ``frame`` group (or its key): a frame back or on (pausing), or
        play / pause."""
        with self._lock:  # (quick presses run on several threads: each sees the last)
            if what == "play / pause":
                self.set_playing(not self._playing.is_set())
                return
            self.set_playing(False)
            self.step(-1 if what == "\u25c0" else 1)

    def set_playing(self, on: bool) -> None:
        """Play (from the current time, at the speed set) or pause."""
        self._set_control(self.play, bool(on))
        if on:
            self._playing.set()
        else:
            self._playing.clear()

    def set_speed(self, speed: float) -> None:
        """The playing speed (times real time), kept within the speed slider's range."""
        self._set_control(self.speed, float(np.clip(round(speed, 1), 0.1, 4.0)))

    def _pace(self, factor: float) -> None:
        # (viser runs callbacks on a pool: two quick presses must not read one old speed)
        with self._lock:
            self.set_speed(self.speed.value * factor)

    def step(self, frames: int) -> None:
        """Move ``frames`` samples on (negative: back) from the current one."""
        tr = self.track
        with self._lock:  # read and move at once (quick presses run on several threads)
            k = int(np.clip(tr.index(self.t_s) + frames, 0, len(tr.t) - 1))
            self.show(float(tr.t[k]))

    def show(self, t_s: float, from_slider: bool = False) -> None:
        """Draw the recording at time ``t_s`` [s] (relative to its first sample)."""
        tr, st = self.track, self.style
        with self._lock:
            self.t_s = float(np.clip(t_s, 0.0, tr.duration))
            k = tr.index(self.t_s)
            pred = tr.predicted(self.offset_s)[k] if self.offset_s > 0 else None
            k0 = tr.index(self.t_s - st.trail_s)
            self.body.update(tr.filtered[k], pred, tr.filtered.position[k0 : k + 1])
            self.measured.position = np.asarray(tr.stream.position[k], float)
            if pred is not None:
                j = tr.index(tr.t[k] + self.offset_s)
                self.truth_ahead.position = np.asarray(tr.stream.position[j], float)
            self.truth_ahead.visible = pred is not None
            self._aim()
            self._relabel()
            if not from_slider:
                self._set_control(self.slider, round(self.t_s, 2))
            self.legend.content = recording_legend(
                tr.stream.target, tr.filtered[k], st, pred, self.offset_s, self.grid_spec
            )
            self.view.set_status(
                f"**t = {self.t_s:.3f} s** / {tr.duration:.1f} s - sample {k} - "
                f"{st.sigma:g} sigma, ellipsoids x{st.magnify:g}"
                + (
                    f" - predicted +{self.offset_s * 1e3:.0f} ms (ghost x{st.ghost_magnify:g})"
                    if pred is not None
                    else ""
                )
            )

    def _play_loop(self) -> None:
        last = time.monotonic()
        while not self._stop.is_set():
            if not self._playing.wait(timeout=0.2):
                last = time.monotonic()
                continue
            time.sleep(1 / 30)
            now = time.monotonic()
            t = self.t_s + (now - last) * float(self.speed.value)
            last = now
            self.show(0.0 if t > self.track.duration else t)

    def close(self) -> None:
        self._stop.set()
        self._player.join(timeout=2.0)
        if self._own_server:
            self.view.close()
        else:
            self.view.clear()
