"""The PoseTool in the browser (thesis 8.1.2-8.1.4): tune a Kalman predictor by hand.

Sliders set the motion model (derivative counts, the log10 white-noise density on the highest
derivative of position and of orientation) and the prediction horizon. Every change
recomputes, in a worker thread that drops a computation overtaken by a newer change (thesis
8.1.5: "a worker thread is automatically stopped and restarted"), the filtered and predicted
curves and the error table, scored on the part of the recording after the tuning data. The
table puts the hand setting beside the automatic tuning's choice
(:func:`trackflow.evaluation.tune_model`, run once in the background on the first part) and
the linear / no-prediction baselines, so a person sees why the tuning chose what it chose.
"""

from __future__ import annotations

import threading

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
from .server import SECONDS_AXIS, ViewServer, linked_cursor

__all__ = ["PoseToolPage", "manual_predictor"]


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


class PoseToolPage:
    """A viser page for hand-tuning the Kalman predictor of one recording.

    Parameters
    ----------
    stream : PoseStream
    host, port : str, int
    tune_fraction : float
        The first part of the duration the automatic tuning sees; errors are scored on the rest.
    window_s : float
        Length of the curve window [s].
    """

    def __init__(
        self, stream: PoseStream, host="127.0.0.1", port=8080, tune_fraction=0.5, window_s=4.0
    ):
        t = (stream.t_ns - stream.t_ns[0]).astype(float) * 1e-9
        self.t, self.p = t, np.asarray(stream.position, float)
        self.q = np.asarray(stream.quaternion, float)
        self.gap = default_gap(t)
        self.recording = Trajectory.check(t, self.p, self.q, gap_s=self.gap)
        self.split = float(t[-1]) * float(tune_fraction)
        self.base = default_predictor(t, self.p, self.q)
        self.window_s = float(window_s)
        self.view = ViewServer(host, port, title=f"PoseTool: {stream.source} -> {stream.target}")
        self.tuned = None
        self.tuned_stats: dict = {}
        self.revision = 0
        self._dirty = threading.Event()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._build()
        self._worker = threading.Thread(target=self._work, daemon=True, name="posetool")
        self._worker.start()
        self._tuner = threading.Thread(target=self._tune, daemon=True, name="posetool-tune")
        self._tuner.start()
        self.changed()

    @property
    def url(self) -> str:
        return self.view.url

    def _build(self) -> None:
        gui, m = self.view.gui, self.base.model
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
            last = max(float(self.t[-1]) - self.window_s, 0.0)
            self.start = gui.add_slider(
                "window start [s]", min=0.0, max=round(last, 1), step=0.1,
                initial_value=min(round(self.split, 1), round(last, 1)),
            )  # fmt: skip
        for c in (self.n_dp, self.n_do, self.log_pos, self.log_ori, self.horizon, self.start):
            c.on_update(lambda _: self.changed())
        self.table = gui.add_html("")
        self.tuned_text = gui.add_markdown("automatic tuning: running ...")
        zeros = (np.zeros(2),) * 5
        self.curves = gui.add_uplot(
            scales=SECONDS_AXIS, cursor=linked_cursor("posetool"),
            data=zeros,
            series=(
                {"label": "t [s]"},
                {"label": "measured x [m]", "stroke": "#888"},
                {"label": "filtered x [m]", "stroke": "#08c"},
                {"label": "predicted x (hand) [m]", "stroke": "#c0c"},
                {"label": "predicted x (tuned) [m]", "stroke": "#d60"},
            ),
            title="x position: predictions made one horizon earlier", aspect=1.6,
        )  # fmt: skip
        self.errors = gui.add_uplot(
            scales=SECONDS_AXIS, cursor=linked_cursor("posetool"),
            data=(np.zeros(2),) * 3,
            series=(
                {"label": "t [s]"},
                {"label": "hand error [mm]", "stroke": "#c0c"},
                {"label": "tuned error [mm]", "stroke": "#d60"},
            ),
            title="position prediction error", aspect=2.0,
        )  # fmt: skip

    def settings(self) -> tuple[KalmanPredictor, float]:
        """The hand-set predictor and the horizon [s] the controls describe now."""
        pred = manual_predictor(
            self.base, int(self.n_dp.value), int(self.n_do.value),
            float(self.log_pos.value), float(self.log_ori.value),
        )  # fmt: skip
        return pred, float(self.horizon.value) * 1e-3

    def changed(self) -> None:
        """A control moved: (re)start the recomputation."""
        self._dirty.set()

    def _tune(self) -> None:
        m = self.t <= self.split
        try:
            res = tune_model(self.recording.select(m), horizons=(0.05, 0.1))
        except ValueError as exc:
            self.tuned_text.content = f"automatic tuning failed: {exc}"
            return
        self.tuned = res.predictor
        self.tuned_text.content = (
            f"**automatic tuning** ({res.seconds:.1f} s, {res.n_evaluations} evaluations on the "
            f"first {self.split:.1f} s): {_describe(res.predictor.as_dict())}; robust cost "
            f"relative to linear extrapolation: position {res.cost_position:.3f}, orientation "
            f"{res.cost_orientation:.3f}"
        )
        self.changed()

    def _work(self) -> None:
        while not self._stop.is_set():
            if not self._dirty.wait(timeout=0.2):
                continue
            self._dirty.clear()
            pred, h = self.settings()
            try:
                out = self._compute(pred, h)
            except ValueError as exc:
                self.view.set_status(f"cannot compute: {exc}")
                continue
            if self._dirty.is_set():
                continue  # overtaken by a newer setting: drop this result, start again
            self._publish(*out, h)

    def _compute(self, pred: KalmanPredictor, h: float):
        t, p = self.t, self.p
        rec = self.recording
        rows = {}
        rep = evaluate_predictors(rec, pred, (h,), scored_from=self.split)
        hm = rep.horizons_ms[0]
        rows["Kalman (hand)"] = rep.stats["kalman"][hm]
        tuned = self.tuned
        if tuned is not None:
            rt = evaluate_predictors(rec, tuned, (h,), scored_from=self.split)
            rows["Kalman (tuned)"] = rt.stats["kalman"][hm]
        else:
            rows["Kalman (tuned)"] = None
        rows["linear"] = rep.stats["linear"][hm]
        rows["none"] = rep.stats["none"][hm]
        w0 = float(self.start.value)
        sel = (t >= w0) & (t <= w0 + self.window_s)
        curves = [t[sel], p[sel, 0]]
        filt, _, _ = predict_kalman(rec, pred, (0.0, h))
        curves.append(filt[0][sel, 0])
        err = [t[sel]]
        cloud = {"measured": p[sel]}
        for label, model in (("hand", pred), ("tuned", tuned)):
            if model is None:
                curves.append(np.full(sel.sum(), np.nan))
                err.append(np.full(sel.sum(), np.nan))
                continue
            pp = filt[1] if model is pred else predict_kalman(rec, model, (h,))[0][0]
            ahead = (t + h >= w0) & (t + h <= w0 + self.window_s)
            cloud[label] = pp[ahead]
            # the prediction made at t_k for t_k + h, drawn at its target time
            x_at = np.interp(t[sel], t + h, pp[:, 0], left=np.nan, right=np.nan)
            curves.append(x_at)
            targets = np.stack([np.interp(t[sel], t + h, pp[:, i]) for i in range(3)], axis=1)
            err.append(np.linalg.norm(targets - p[sel], axis=1) * 1e3)
        return rows, hm, curves, err, cloud

    def _publish(self, rows, hm, curves, err, cloud, h) -> None:
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
            if not getattr(self, "_framed", False) and len(cloud["measured"]):
                m = cloud["measured"]
                lo, hi = m.min(axis=0), m.max(axis=0)
                self.view.look_at(0.5 * (lo + hi), float(np.max(hi - lo)))
                self._framed = True
            self.table.content = _table(rows, hm)
            self.curves.data = tuple(np.asarray(c, float) for c in curves)
            self.errors.data = tuple(np.asarray(e, float) for e in err)
            self.view.set_status(
                f"**PoseTool** - revision {self.revision} - horizon {h * 1e3:.0f} ms - scored "
                f"after {self.split:.1f} s"
            )
        self.last_rows = rows

    def wait_tuned(self, timeout_s: float) -> int:
        """Block until the tuning finished and its row is in a published table; returns
        that revision."""
        import time

        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            rows = getattr(self, "last_rows", {})
            if self.tuned is not None and rows.get("Kalman (tuned)") is not None:
                if not self._dirty.is_set():
                    return self.revision
            time.sleep(0.05)
        raise ServiceError(f"the automatic tuning did not finish in {timeout_s:.0f} s")

    def close(self) -> None:
        self._stop.set()
        self._worker.join(timeout=5.0)
        self.view.close()
