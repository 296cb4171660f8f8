"""A live setup's scene as a person reads it, in real headless Chromium (issue 29): labels do
not overlap (the fusion and the demo setup, whose bodies share points), the scene is drawn in
the room, not in the query's moving source frame, and a query's answer is never drawn past
its filters' extrapolation limit.

Label boxes are computed here, independently of the view's own layout: each label's world
position and the camera the page reported (the view's report), projected onto the page's
canvas (its size from the DOM), each box the label's text measured in the page with the font
viser draws labels in, 12 px a line, padded by a fifth of the line height.
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser", reason="the viewer extra (viser) is not installed")
pytest.importorskip("playwright", reason="the viewer extra (playwright) is not installed")

from _shots import doc_shot

from trackflow.viewer import ViewOptions, start_setup

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
W, H = 1024, 640
BROWSER_TIMEOUT_S = 120

# viser's label font (client/src/label/GlyphAtlas.ts, LABEL_FONT_STACK)
_MEASURE_JS = """([items]) => {
  const stack = '-apple-system, BlinkMacSystemFont, "Segoe UI", "Roboto", "Helvetica Neue", '
    + 'Arial, sans-serif';
  const ctx = document.createElement('canvas').getContext('2d');
  return items.map(([text, px]) => {
    ctx.font = `${px}px ${stack}`;
    const probe = ctx.measureText('Mgj');
    return [ctx.measureText(text).width, probe.fontBoundingBoxAscent,
            probe.fontBoundingBoxDescent];
  });
}"""
_CANVAS_JS = """() => {
  const r = document.querySelector('canvas').getBoundingClientRect();
  return [r.width, r.height];
}"""


def label_boxes(page, report: dict) -> dict[str, tuple[float, float, float, float]]:
    """Each shown label's box ``(x0, y0, x1, y1)`` on the page [CSS px]."""
    cam = report["camera"]
    width, height = page.evaluate(_CANVAS_JS)
    rot, pos = np.array(cam["rotation"]), np.array(cam["position"])
    f = 0.5 * height / math.tan(0.5 * cam["fov"])
    labels = report["labels"]
    metrics = page.evaluate(_MEASURE_JS, [[[x["text"], 12.0 * x["scale"]] for x in labels]])
    boxes = {}
    for x, (text_w, ascent, descent) in zip(labels, metrics):
        c = rot.T @ (np.array(x["position"]) - pos)  # camera coordinates (OpenCV axes)
        assert c[2] > 0, f"label {x['text']!r} behind the camera"
        u, v = f * c[0] / c[2] + width / 2, f * c[1] / c[2] + height / 2
        line = ascent + descent
        w, h = text_w + 0.2 * line, line * 1.2  # anchored at its centre
        boxes[x["text"]] = (u - w / 2, v - h / 2, u + w / 2, v + h / 2)
    return boxes


def _settled_report(view, still: bool, timeout_s: float = 90.0) -> dict:
    """The view's report once its labels are laid out for the page's own camera (``still``:
    and two reports half a second apart agree; bounded)."""
    end = time.monotonic() + timeout_s
    last = None
    while time.monotonic() < end:
        rep = view.scene_report()
        if rep["browser_camera"] and rep["camera"] is not None:
            if not still or (last is not None and rep["labels"] == last["labels"]):
                return rep
            last = rep
        time.sleep(0.5)
    raise AssertionError(f"the labels did not settle in {timeout_s} s: {last}")


@pytest.mark.parametrize(
    "name, crowded",
    [("fusion_setup", {"headcam", "head", "art"}), ("demo_setup", {"sheep", "artoolkit"})],
)
def test_no_two_labels_overlap(browser, name, crowded):
    run = start_setup(ROOT / "examples" / f"{name}.yaml", ViewOptions(port=0, rate_hz=20))
    try:
        run.wait_network_time(3.0, timeout_s=300)  # a first run compiles the filters
        page = browser.open(run.view.url, "network t =")
        browser.wait_text(page, "drawn in frame")  # the legend: the scene was framed
        _settled_report(run.view, still=False)
        run.view.paused = True  # hold the frame: the page's camera stops following
        rep = _settled_report(run.view, still=True)
        boxes = label_boxes(page, rep)
        texts = set(boxes)
        # the bodies that share a point are labelled, and so are frames (told apart)
        assert crowded <= {t.split(" - ")[0] for t in texts}, texts
        assert any(t.startswith("frame ") for t in texts), texts
        names = sorted(boxes)
        for i, a in enumerate(names):
            for b in names[:i]:
                A, B = boxes[a], boxes[b]
                apart = A[2] <= B[0] or B[2] <= A[0] or A[3] <= B[1] or B[3] <= A[1]
                assert apart, f"labels {a!r} {A} and {b!r} {B} overlap"
        if os.environ.get("TRACKFLOW_DOC_SHOTS"):  # the picture: a still page (seconds)
            img = browser.capture(page, stable_s=15.0)
            doc_shot(img, f"live_{name.removesuffix('_setup')}")
    finally:
        run.close()


def test_the_scene_is_drawn_in_the_room_and_the_anchor_can_change():
    """The live demo drew everything in the query's source frame (the head): the room swung
    with every head turn. The default anchor is the room; the page's control changes it."""
    setup = ROOT / "examples" / "live_demo.yaml"
    run = start_setup(setup, ViewOptions(port=0, rate_hz=20))
    try:
        run.wait_network_time(2.0, timeout_s=300)
        assert run.view.layout.root == "room"
        # the view process frames the scene (and lays the grid out) once it has drawn bodies:
        # on a loaded machine after the network's first seconds
        end = time.monotonic() + 120
        while (rep := run.view.scene_report())["grid"] is None:
            assert time.monotonic() < end, f"no grid laid out: {rep}"
            time.sleep(0.2)
        assert rep["anchor"] == "room", rep
        run.view.set_anchor("head")
        end = time.monotonic() + 60
        while run.view.scene_report()["anchor"] != "head":
            assert time.monotonic() < end, "the anchor did not change"
            time.sleep(0.2)
        with pytest.raises(ValueError, match="anchor"):
            run.view.set_anchor("nowhere")
    finally:
        run.close()
    with pytest.raises(ValueError, match="anchor"):
        start_setup(setup, ViewOptions(port=0, anchor="nowhere"))


def test_an_answer_without_live_data_is_held_grey_and_its_old_ghost_hidden():
    """A query's answer is drawn while its sensor is live: 0.4 s past the data (the filter
    still answers: its limit is 0.5 s) or 1 s past it with a ballooned covariance, the last
    answer drawn on live data stays, grey, and no old ghost with it."""
    from trackflow.math import quat_exp
    from trackflow.viewer.board import Board
    from trackflow.viewer.edges import EdgeLayout, QueryLayout, ViewLayout
    from trackflow.viewer.live_loop import LiveTabs
    from trackflow.viewer.scene import GREY

    edges = [EdgeLayout("art", "A", "T", False, 0, rate_hz=100.0, max_extrapolation_s=0.5)]
    query = QueryLayout("q", "A", "T", ("art",), now_slot=1, ahead_slot=2, rate_hz=50.0,
                        paths=(("art",),))  # fmt: skip
    board = Board.create(3)
    view = LiveTabs(ViewLayout(["A", "T"], "A", edges, [query], 3), board, port=0, rate_hz=10.0)
    q0 = quat_exp(np.array([0.1, 0.2, 0.3]))
    small, huge = np.eye(6) * 1e-6, np.eye(6) * 4.0
    try:
        sec = 1_000_000_000
        board.write_event(0, 1 * sec, 0, 1.0, 1 * sec)  # the sensor's last data: t = 1 s
        board.write_pose(0, 1 * sec, [0.1, 0.0, 0.0], q0, small)
        board.write_event(1, int(1.2 * sec), 0, 1.0, int(1.2 * sec))
        board.write_pose(1, int(1.2 * sec), [0.1, 0.0, 0.0], q0, small)  # 0.2 s ahead: drawn
        board.set_clock(int(1.2 * sec), 0)
        view.tick()
        q_index = [b.name for b in view.state.bodies].index("q")
        assert view.report()["bodies"][q_index]["grey"] is False
        # 0.4 s on: within the filter's limit, but the sensor is stale (250 ms without data)
        board.write_event(1, int(1.4 * sec), 0, 1.0, int(1.4 * sec))
        board.write_pose(1, int(1.4 * sec), [0.9, 0.0, 0.0], q0, np.eye(6) * 0.04)
        board.set_clock(int(1.4 * sec), 0)
        view.tick()
        rep = view.report()["bodies"][q_index]
        assert rep["grey"] and rep["extrapolated_s"] == pytest.approx(0.4)
        board.write_event(1, 2 * sec, 0, 1.0, 2 * sec)
        board.write_pose(1, 2 * sec, [5.0, 0.0, 0.0], q0, huge)  # 1 s ahead, ballooned
        board.set_clock(2 * sec, 0)
        view.apply(offset_s=0.1)
        board.write_pose(2, int(1.3 * sec), [0.2, 0.0, 0.0], q0, small)  # an older ghost
        view.tick()
        rep = view.report()["bodies"][q_index]
        assert rep["grey"] and rep["colour"] == list(GREY)
        assert rep["extrapolated_s"] == pytest.approx(1.0)
        drawn = view.state.anchored("A").bodies[q_index]  # what every tab draws
        np.testing.assert_allclose(drawn.position, [0.1, 0.0, 0.0])  # the held answer
        assert np.max(drawn.covariance) < 1e-3 and drawn.predicted is None
    finally:
        view.close()
        board.close()


def test_the_paths_are_kept_once_for_all_tabs_in_each_anchor_drawn_in():
    """The view's shared state extends each body's path once per tick, with no page open (a
    tab opened later draws the whole path so far), in every anchor a tab draws in: an
    anchor's path starts with its first use and is forgotten when no tab draws in it."""
    from trackflow.viewer.board import Board
    from trackflow.viewer.edges import EdgeLayout, ViewLayout
    from trackflow.viewer.live_state import LiveState

    layout = ViewLayout(["A", "T"], "A", [EdgeLayout("art", "A", "T", False, 0)], [], 1)
    board = Board.create(1)
    state = LiveState(layout, board, 10.0, axes_length=0.1, auto_scale=False)
    q0 = np.array([0.0, 0.0, 0.0, 1.0])
    try:
        for i in range(5):
            t = (i + 1) * 100_000_000
            board.write_event(0, t, 0, 1.0, t)
            board.write_pose(0, t, [0.1 * i, 0.0, 0.0], q0, np.eye(6) * 1e-6)
            board.set_clock(t, 0)
            state.tick({"A"}, now_wall=float(i))
        np.testing.assert_allclose(state.path("A", "art")[:, 0], [0.0, 0.1, 0.2, 0.3, 0.4])
        assert len(state.anchored("A").trails[0]) == 5
        state.tick({"A", "T"}, now_wall=5.0)  # a tab draws in the tool's frame: fresh there
        assert state.path("T", "art") is None
        np.testing.assert_allclose(state.anchored("T").bodies[0].position, 0.0, atol=1e-12)
        assert len(state.path("A", "art")) == 5  # the same pose again: no new point
        state.tick({"T"}, now_wall=6.0)
        assert state.path("A", "art") is None  # no tab draws in A any more
    finally:
        board.close()


class _BrokenTab:
    """A tab whose drawing raises (what a viser call failing mid-frame would do)."""

    anchor = "A"

    def __init__(self):
        self.shown: list[str] = []

    def render_frame(self) -> None:
        raise RuntimeError("the page went away mid-frame")

    def show_error(self, text: str) -> None:
        self.shown.append(text)


def test_a_tab_whose_drawing_fails_says_so_and_the_view_draws_on(capsys, monkeypatch):
    """An exception while drawing a tab is counted, written to stderr with its traceback the
    first time (the run's stderr: a view that stops drawing says why), shown on that tab's
    status line, and the other tabs and the next ticks draw on."""
    from trackflow.viewer.board import Board
    from trackflow.viewer.edges import EdgeLayout, ViewLayout
    from trackflow.viewer.live_loop import LiveTabs

    layout = ViewLayout(["A", "T"], "A", [EdgeLayout("art", "A", "T", False, 0)], [], 1)
    board = Board.create(1)
    view = LiveTabs(layout, board, port=0, rate_hz=10.0)
    broken, drawn = _BrokenTab(), []

    class _Tab(_BrokenTab):
        def render_frame(self) -> None:
            drawn.append(view.frames_sent)

    try:
        monkeypatch.setattr(view, "scenes", lambda: [broken, _Tab()])
        for _ in range(3):
            view.tick()
        err = capsys.readouterr().err
        assert view.draw_errors == 3 and view.frames_sent == 3 and drawn == [0, 1, 2]
        assert err.count("trackflow view: drawing a tab failed") == 1  # told once
        assert "RuntimeError: the page went away mid-frame" in err and "Traceback" in err
        assert broken.shown == ["RuntimeError: the page went away mid-frame"] * 3
        monkeypatch.setattr(view, "scenes", list)  # (no tab open: the default report)
        assert view.report()["draw_errors"] == 3
    finally:
        view.close()
        board.close()
