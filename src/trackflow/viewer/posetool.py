"""The PoseTool in the browser (thesis 8.1.2-8.1.4): tune a Kalman predictor by hand.

Sliders set the motion model (derivative counts, the log10 white-noise density on the highest
derivative of position and of orientation) and the prediction horizon. Every change
recomputes, in a worker thread that drops a computation overtaken by a newer change (thesis
8.1.5: "a worker thread is automatically stopped and restarted"), the filtered and predicted
curves and the error table, scored on the part of the recording after the tuning data. The
table puts the hand setting beside the automatic tuning's choice
(:func:`trackflow.evaluation.tune_model`, run once in the background on the first part) and
the linear / no-prediction baselines, so a person sees why the tuning chose what it chose.

The error plot (the position prediction error over time) sits under the table, in view; the
residual plot shows one axis of the filtered and predicted positions minus the recording's,
in millimetres (the positions themselves would overlap at the scale of the room). The
recording and its automatic tuning (:class:`PoseTool`) are shared by every browser tab; each
tab has its own controls and computation (:class:`PoseToolPage` on a
:class:`~trackflow.viewer.tabs.PerTab` page)::

    tool = PoseTool(stream, tune_fraction=0.5)
    tabs = PerTab(ViewServer(port=0), lambda page: PoseToolPage(tool, page))
"""

from __future__ import annotations

import threading
import time

import numpy as np

from ..errors import ServiceError
from ..evaluation import (
    KalmanPredictor,
    Trajectory,
    default_gap,
    default_predictor,
    evaluate_predictors,
    predict_kalman,
    tune_model,
)
from ..filters import MotionModel
from ..io import PoseStream
from .decor import add_floor_grid, faint, grid_spec, path_segments
from .server import SECONDS_AXIS, linked_cursor

__all__ = ["AXES", "PoseTool", "PoseToolPage", "manual_predictor"]

#: the residual plot's axis choices
AXES = ("x", "y", "z")


def manual_predictor(
    base: KalmanPredictor, n_dp: int, n_do: int, log_pos: float, log_ori: float
) -> KalmanPredictor:
    """``base``'s measurement noise and gate with a white-noise model of ``n_dp`` position and
    ``n_do`` orientation derivatives, driven on the highest ones by densities ``10**log_pos``
    [m/s^n_dp/sqrt(s)] and ``10**log_ori`` [rad/s^n_do/sqrt(s)]; the value levels get the
    measurement sigmas (as :func:`trackflow.evaluation.default_predictor` does)."""
    noise = (
        [base.pos_sigma] + [0.0] * (n_dp - 1) + [10.0**log_pos]
        + [base.ori_sigma] + [0.0] * (n_do - 1) + [10.0**log_ori]
    )  # fmt: skip
    model = MotionModel(n_dp, n_do, noise=tuple(noise), kind="white_noise")
    return KalmanPredictor(model, base.pos_sigma, base.ori_sigma, base.gate_probability)


def _table(rows: dict[str, object], h_ms: int) -> str:
    head = (
        f"<b>prediction errors at {h_ms} ms</b>"
        '<table style="font-size:12px;width:100%;border-collapse:collapse">'
        "<tr><th align=left>predictor</th><th>pos avg</th><th>pos rms</th>"
        "<th>ori avg</th><th>ori rms</th><th>n</th></tr>"
    )
    body = []
    for name, s in rows.items():
        if s is None:
            body.append(f"<tr><td>{name}</td><td colspan=5>(running)</td></tr>")
            continue
        body.append(
            f"<tr><td>{name}</td><td>{s.pos_avg_mm:.2f} mm</td><td>{s.pos_rms_mm:.2f} mm</td>"
            f"<td>{s.ori_avg_deg:.3f}&deg;</td><td>{s.ori_rms_deg:.3f}&deg;</td><td>{s.n}</td></tr>"
        )
    return head + "".join(body) + "</table>"


def _describe(d: dict) -> str:
    """One line for a predictor's ``as_dict()`` (derivative, learned or partwise)."""
    fam = d.get("family")
    if fam == "partwise":
        return f"position: {_describe(d['position'])}, orientation: {_describe(d['orientation'])}"
    if fam == "twist_ar":
        return f"learned increment model of order {d.get('order')}"
    if fam == "derivative":
        noise = ", ".join(f"{v:.3g}" for v in d.get("noise", []))
        return f"derivatives n_dp={d.get('n_dp')}, n_do={d.get('n_do')}, noise ({noise})"
    return str(d)


def _residual_title(axis: str) -> str:
    return f"residual: {axis} position minus the recording's"


class PoseTool:
    """One recording checked for the PoseTool, with its automatic tuning (run once, in the
    background, for every page).

    Parameters
    ----------
    stream : PoseStream
    tune_fraction : float
        The first part of the duration the automatic tuning sees; errors are scored on the rest.

    Attributes
    ----------
    recording : Trajectory
        The checked recording (times [s] from its first sample).
    split : float
        Scoring starts here [s].
    base : KalmanPredictor
        The default predictor (noise from the data); the hand settings start from it.
    tuned : Predictor or None
        The tuning's choice once it finished.
    tuning_text : str
        What the tuning found (or that it runs, or why it failed), as Markdown.
    """

    def __init__(self, stream: PoseStream, tune_fraction: float = 0.5):
        t = (stream.t_ns - stream.t_ns[0]).astype(float) * 1e-9
        self.t, self.p = t, np.asarray(stream.position, float)
        self.q = np.asarray(stream.quaternion, float)
        self.title = f"PoseTool: {stream.source} -> {stream.target}"
        self.recording = Trajectory.check(t, self.p, self.q, gap_s=default_gap(t))
        self.split = float(t[-1]) * float(tune_fraction)
        self.base = default_predictor(t, self.p, self.q)
        self.tuned = None
        self.tuning_text = "automatic tuning: running ..."
        self._lock = threading.Lock()
        self._hooks: list = []
        self._done = threading.Event()
        threading.Thread(target=self._tune, daemon=True, name="posetool-tune").start()

    def on_tuned(self, hook) -> None:
        """Call ``hook()`` once the tuning has finished (at once if it has)."""
        with self._lock:
            if not self._done.is_set():
                self._hooks.append(hook)
                return
        hook()

    def forget(self, hook) -> None:
        """No longer call ``hook`` (a closed page)."""
        with self._lock:
            if hook in self._hooks:
                self._hooks.remove(hook)

    @property
    def finished(self) -> bool:
        """Whether the tuning has finished (found a predictor or failed)."""
        return self._done.is_set()

    def _tune(self) -> None:
        try:
            res = tune_model(self.recording.select(self.t <= self.split), horizons=(0.05, 0.1))
        except ValueError as exc:
            self.tuning_text = f"automatic tuning failed: {exc}"
        else:
            self.tuned = res.predictor
            self.tuning_text = (
                f"**automatic tuning** ({res.seconds:.1f} s, {res.n_evaluations} evaluations on "
                f"the first {self.split:.1f} s): {_describe(res.predictor.as_dict())}; robust "
                f"cost relative to linear extrapolation: position {res.cost_position:.3f}, "
                f"orientation {res.cost_orientation:.3f}"
            )
        with self._lock:
            self._done.set()
            hooks, self._hooks = self._hooks, []
        for hook in hooks:
            hook()


class PoseToolPage:
    """The PoseTool's controls, table, plots and scene on one page (or a whole server).

    Parameters
    ----------
    tool : PoseTool
        The recording and its tuning (shared by the pages).
    view : ViewServer or ClientView
        Where it is shown: a whole server's pages, or one tab's (``PerTab``).
    window_s : float
        Length of the plots' window [s].

    Every change of a control recomputes in this page's worker thread, which drops a
    computation overtaken by a newer change; :attr:`revision` counts what was shown.
    """

    def __init__(self, tool: PoseTool, view, window_s: float = 4.0):
        self.tool, self.view = tool, view
        self.window_s = float(window_s)
        self.revision = 0
        self.last_rows: dict = {}
        self.shows_tuning = False  # whether the last revision shown came after the tuning
        self.shown: tuple | None = None  # the control values the last revision shows
        self._dirty = threading.Event()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._build()
        self._draw_scene()
        self._worker = threading.Thread(target=self._work, daemon=True, name="posetool")
        self._worker.start()
        tool.on_tuned(self.changed)
        self.changed()

    @property
    def url(self) -> str:
        return self.view.url

    def _build(self) -> None:
        gui, m, tool = self.view.gui, self.tool.base.model, self.tool
        self.table = gui.add_html("")
        self.errors = self._time_plot(
            "position prediction error",
            {"label": "hand error [mm]", "stroke": "#c0c"},
            {"label": "tuned error [mm]", "stroke": "#d60"},
        )
        with gui.add_folder("Motion model"):
            self.n_dp = gui.add_dropdown("position derivatives", ("1", "2", "3"), initial_value="2")
            self.n_do = gui.add_dropdown("orientation derivatives", ("1", "2"), initial_value="1")
            self.log_pos = gui.add_slider(
                "log10 position noise", min=-2.0, max=4.0, step=0.1,
                initial_value=round(float(np.log10(m.noise[m.n_dp + 0])), 1),
            )  # fmt: skip
            self.log_ori = gui.add_slider(
                "log10 orientation noise", min=-2.0, max=4.0, step=0.1,
                initial_value=round(float(np.log10(m.noise[-1])), 1),
            )  # fmt: skip
            self.horizon = gui.add_slider(
                "horizon [ms]", min=10.0, max=300.0, step=10.0, initial_value=100.0
            )
            last = max(float(tool.t[-1]) - self.window_s, 0.0)
            self.start = gui.add_slider(
                "window start [s]", min=0.0, max=round(last, 1), step=0.1,
                initial_value=min(round(tool.split, 1), round(last, 1)),
            )  # fmt: skip
            self.axis = gui.add_dropdown("residual axis", AXES, initial_value="x")
        self._controls = (self.n_dp, self.n_do, self.log_pos, self.log_ori, self.horizon,
                          self.start, self.axis)  # fmt: skip
        for c in self._controls:
            c.on_update(lambda _: self.changed())
        self.residuals = self._time_plot(
            _residual_title("x"),
            {"label": "filtered [mm]", "stroke": "#08c"},
            {"label": "predicted (hand) [mm]", "stroke": "#c0c"},
            {"label": "predicted (tuned) [mm]", "stroke": "#d60"},
        )
        self.tuned_text = gui.add_markdown(tool.tuning_text)

    def _time_plot(self, title: str, *series: dict):
        """A plot over the recording's time [s] (cursor linked with the page's other plots)
        with one line per ``series`` (uPlot series options)."""
        return self.view.gui.add_uplot(
            scales=SECONDS_AXIS, cursor=linked_cursor("posetool"),
            data=(np.zeros(2),) * (1 + len(series)),
            series=({"label": "t [s]"}, *series), title=title, aspect=2.4,
        )  # fmt: skip

    def _draw_scene(self) -> None:
        """The floor grid, the whole path as a faint line, the camera on the path."""
        p = self.tool.p
        ok = np.all(np.isfinite(p), axis=1)
        lo, hi = p[ok].min(axis=0), p[ok].max(axis=0)
        scene = self.view.scene
        add_floor_grid(scene, "/grid", grid_spec(lo, hi))
        scene.add_line_segments(
            "/path", path_segments(p).astype(np.float32), faint((90, 90, 90)), thickness=1.5,
            thickness_units="screen",
        )  # fmt: skip
        self.view.look_at(0.5 * (lo + hi), float(np.max(hi - lo)))
        self.view.reset_cameras()

    def settings(self) -> tuple[KalmanPredictor, float]:
        """The hand-set predictor and the horizon [s] the controls describe now."""
        pred = manual_predictor(
            self.tool.base, int(self.n_dp.value), int(self.n_do.value),
            float(self.log_pos.value), float(self.log_ori.value),
        )  # fmt: skip
        return pred, float(self.horizon.value) * 1e-3

    def controls(self) -> tuple:
        """The values of the page's controls now."""
        return tuple(c.value for c in self._controls)

    def changed(self) -> None:
        """A control moved (or the tuning finished): (re)start the recomputation."""
        self._dirty.set()

    def _work(self) -> None:
        while not self._stop.is_set():
            if not self._dirty.wait(timeout=0.2):
                continue
            self._dirty.clear()
            asked = self.controls()
            pred, h = self.settings()
            try:
                out = self._compute(pred, h)
            except ValueError as exc:
                self.view.set_status(f"cannot compute: {exc}")
                continue
            if self._dirty.is_set():
                continue  # overtaken by a newer setting: drop this result, start again
            self._publish(*out, h, asked)

    def _compute(self, pred: KalmanPredictor, h: float):
        tool = self.tool
        t, p, rec = tool.t, tool.p, tool.recording
        finished, tuned = tool.finished, tool.tuned
        rep = evaluate_predictors(rec, pred, (h,), scored_from=tool.split)
        hm = rep.horizons_ms[0]
        rows = {"Kalman (hand)": rep.stats["kalman"][hm], "Kalman (tuned)": None}
        if tuned is not None:
            rt = evaluate_predictors(rec, tuned, (h,), scored_from=tool.split)
            rows["Kalman (tuned)"] = rt.stats["kalman"][hm]
        rows["linear"] = rep.stats["linear"][hm]
        rows["none"] = rep.stats["none"][hm]
        w0 = float(self.start.value)
        sel = (t >= w0) & (t <= w0 + self.window_s)
        a = AXES.index(str(self.axis.value))
        filt, _, _ = predict_kalman(rec, pred, (0.0, h))
        residuals = [t[sel], (filt[0][sel, a] - p[sel, a]) * 1e3]
        err = [t[sel]]
        cloud = {"measured": p[sel]}
        for label, model in (("hand", pred), ("tuned", tuned)):
            if model is None:
                residuals.append(np.full(sel.sum(), np.nan))
                err.append(np.full(sel.sum(), np.nan))
                continue
            pp = filt[1] if model is pred else predict_kalman(rec, model, (h,))[0][0]
            ahead = (t + h >= w0) & (t + h <= w0 + self.window_s)
            cloud[label] = pp[ahead]
            # the prediction made at t_k for t_k + h, compared at its target time
            at = np.stack(
                [np.interp(t[sel], t + h, pp[:, i], left=np.nan, right=np.nan) for i in range(3)],
                axis=1,
            )
            residuals.append((at[:, a] - p[sel, a]) * 1e3)
            err.append(np.linalg.norm(at - p[sel], axis=1) * 1e3)
        return rows, hm, residuals, err, cloud, finished

    def _publish(self, rows, hm, residuals, err, cloud, finished, h, asked) -> None:
        with self._lock:
            self.revision += 1
            scene = self.view.scene
            for name, colour in (("measured", (90, 90, 90)), ("hand", (230, 0, 230)),
                                 ("tuned", (255, 140, 0))):  # fmt: skip
                pts = cloud.get(name)
                if pts is not None and len(pts):
                    scene.add_point_cloud(
                        f"/{name}", np.asarray(pts, np.float32), colour, point_size=0.004
                    )
            self.table.content = _table(rows, hm)
            self.errors.data = tuple(np.asarray(e, float) for e in err)
            self.residuals.data = tuple(np.asarray(c, float) for c in residuals)
            self.residuals.title = _residual_title(str(asked[-1]))
            self.tuned_text.content = self.tool.tuning_text
            self.view.set_status(
                f"**PoseTool** - revision {self.revision} - horizon {h * 1e3:.0f} ms - scored "
                f"after {self.tool.split:.1f} s"
            )
            self.last_rows = rows
            self.shows_tuning = finished
            self.shown = asked

    def wait_settled(self, timeout_s: float) -> int:
        """Block until the revision shown was computed from the controls' values now and
        no change waits; returns that revision."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if self.shown == self.controls() and not self._dirty.is_set():
                return self.revision
            time.sleep(0.05)
        raise ServiceError(f"the page did not show its controls' values in {timeout_s:.0f} s")

    def wait_tuned(self, timeout_s: float) -> int:
        """Block until the tuning finished and a revision computed after it is shown (with
        the tuned row, unless the tuning failed); returns that revision."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if self.shows_tuning and self.shown == self.controls() and not self._dirty.is_set():
                return self.revision
            time.sleep(0.05)
        raise ServiceError(f"the automatic tuning did not finish in {timeout_s:.0f} s")

    def close(self) -> None:
        """Stop this page's worker and clear its part of the view (the server runs on)."""
        self.tool.forget(self.changed)
        self._stop.set()
        self._worker.join(timeout=5.0)
        self.view.clear()
