"""The views rendered by real headless Chromium (SwiftShader WebGL), asserted on pixels.

Needs Debian's ``chromium`` (``make browser``) and the ``viewer`` extra (viser, playwright);
skips with the reason when either is missing. One browser serves the whole module
(``tests/conftest.py``), and one viser server with one page serves the tests drawn in this
process (a new page costs software WebGL its shaders again); every wait is bounded by the
browser's timeout.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser", reason="the viewer extra (viser) is not installed")
pytest.importorskip("playwright", reason="the viewer extra (playwright) is not installed")

from _shots import capture_panel_until

from trackflow.dataflow import Network, SimulatedSensor, parse_setup
from trackflow.io import PoseStream
from trackflow.math import Pose, UncertainPose, quat_exp
from trackflow.viewer import (
    COLOURS,
    PoseDrawing,
    RecordingTrack,
    RecordingView,
    Style,
    attach_view,
    edge_motion,
)

pytestmark = pytest.mark.slow

W, H = 900, 600


def _mask(img: np.ndarray, rgb, tol: int = 40) -> np.ndarray:
    """Pixels within ``tol`` of ``rgb`` in every channel."""
    return np.all(np.abs(img.astype(int) - np.asarray(rgb)) <= tol, axis=-1)


def _magenta(img: np.ndarray) -> np.ndarray:
    """Shaded magenta (red and blue well above green, about equal): the body colour."""
    r, g, b = (img[..., i].astype(int) for i in range(3))
    return (r > g + 70) & (b > g + 70) & (np.abs(r - b) < 70)


def _scene_part(img: np.ndarray) -> np.ndarray:
    """The 3D canvas left of the control panel (viser docks it on the right)."""
    return img[:, : int(W * 0.6)]


SETUP = {
    "frames": ["A", "T", "C", "M"],
    "sensors": [
        {"name": "art", "source": "A", "target": "T", "rate_hz": 60, "latency_ms": 20,
         "sigma_pos_mm": 2.0, "sigma_ori_deg": 1.0},
        {"name": "cam", "source": "C", "target": "M", "rate_hz": 30, "latency_ms": 30,
         "sigma_pos_mm": 3.0, "sigma_ori_deg": 1.0},
    ],
    "statics": [{"name": "mount", "source": "T", "target": "C", "position": [0.0, 0.0, 0.1]}],
    "queries": [{"name": "view", "source": "A", "target": "M", "mode": "push", "rate_hz": 30}],
}  # fmt: skip


def _sensor(name, rate, end_s, k, rng, sigma):
    return SimulatedSensor(
        name, edge_motion(k), rate_hz=rate, latency_s=0.02, sigma_pos=sigma,
        sigma_ori=0.02, rng=rng, start_s=0.0, end_s=end_s,
    )  # fmt: skip


def _in_panel(img: np.ndarray, box) -> np.ndarray:
    """The control panel's part of the page (the graph panel is in it). The readable scene
    (issue 29) frames and follows the body, so parts of the 3D scene (red and green axes, the
    grid) show on the right of the page below the panel: only the panel's box is measured."""
    x0, y0, x1, y1 = box
    return img[max(y0, 0) : y1, max(x0, 0) : x1]


def _red(img: np.ndarray, box) -> int:
    """Pixels of the stale colour in the panel."""
    return int(_mask(_in_panel(img, box), (214, 39, 40)).sum())


def _green(img: np.ndarray, box) -> int:
    """Pixels of the live colour in the panel."""
    return int(_mask(_in_panel(img, box), (26, 158, 58)).sum())


def _green_shown(img: np.ndarray, box) -> bool:
    return _green(img, box) > 150


def _red_shown(img: np.ndarray, box) -> bool:
    return _red(img, box) > 150


def test_a_sensor_that_stops_turns_its_edge_from_live_to_stale(browser):
    setup = parse_setup(SETUP)
    rng = np.random.default_rng(0)
    # the art tracker stops after 1 s; the camera keeps the clock going until 4 s
    sources = {
        "art": _sensor("art", 60, 1.0, 0, rng, 0.002),
        "cam": _sensor("cam", 30, 4.0, 1, rng, 0.003),
    }
    net = Network()
    plan = setup.plan("view")
    plan.build(sources, network=net, prefix="view:")
    live = attach_view(net, setup, {"view": (plan, "view:")}, port=0, rate_hz=20)
    try:
        shots = []
        page = None
        for until_s in (0.9, 3.0):
            net.run(until_ns=int(until_s * 1e9))
            text = f"network t = {until_s:.2f} s"
            if page is None:
                page = browser.open(live.url, text)
            else:
                browser.wait_text(page, text)
            browser.settle(page, 700)  # the panel redraws at 5 Hz
            states = {s.name: s.state for s in live.edge_statuses()}
            # the panel's drawing may lag under load: wait (bounded) for its green arrows
            # first, then for the red one
            img, box = capture_panel_until(
                browser, page, _green_shown if until_s < 1.0 else _red_shown
            )
            shots.append((img, states, box))
        (img0, st0, box0), (img1, st1, box1) = shots
        assert st0["art"] == "live" and st1["art"] == "stale" and st1["cam"] == "live"
        green0, red0 = _green(img0, box0), _red(img0, box0)
        green1, red1 = _green(img1, box1), _red(img1, box1)
        assert COLOURS["stale"] == "#d62728" and COLOURS["live"] == "#1a9e3a"
        assert red0 < 0.2 * red1, (red0, red1)  # the red arrow appeared
        assert red1 > 150, (red1, box1)
        assert green1 < green0 - 100, (green0, green1)  # and replaced a green one
        # the "Save" buttons: the selected edge's updates as CSV, the 3D view as PNG
        page.get_by_text("Save", exact=True).click()
        with page.expect_download() as got:
            page.get_by_role("button", name="save CSV").click()
        lines = Path(got.value.path()).read_text().splitlines()
        assert got.value.suggested_filename == "art.csv" and lines[0] == "t_s,latency_ms,nis"
        rows = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
        # the art tracker's 60 Hz updates of its first second, in order
        assert 50 <= len(rows) <= 61 and np.all(np.diff(rows[:, 0]) > 0), rows[:3]
        assert rows[-1, 0] <= 1.0 + 1e-9 and np.isfinite(rows[1:, 2]).all(), rows[-3:]
        with page.expect_download() as got:
            page.get_by_role("button", name="save PNG").click()
        assert got.value.suggested_filename == "trackflow_view.png"
        assert Path(got.value.path()).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    finally:
        live.close()


def test_four_times_the_covariance_covers_four_times_the_area(browser, page, server):
    view = server
    view.clear()
    try:
        view.look_at((0.0, 0.0, 0.0), 0.4)
        view.reset_cameras()
        style = Style(axes_length=0.005, opacity=None, show_orientation=False)
        body = PoseDrawing(view.scene, "/world/body", (230, 0, 230), style)
        sigma = 0.03
        areas = []
        for k, factor in enumerate((1.0, 4.0)):
            cov = np.diag([sigma**2 * factor] * 3 + [1e-6] * 3)
            body.update(UncertainPose(Pose.identity(), cov))
            view.set_status(f"covariance step {k}")
            browser.wait_text(page, f"covariance step {k}")
            # wait until the new ellipsoid is drawn (software WebGL under load lags the
            # status text), then until two screenshots agree
            least = 500 if k == 0 else 1.5 * areas[0]
            browser.capture_until(page, lambda im, n=least: _magenta(_scene_part(im)).sum() > n)
            img = browser.capture(page, stable_s=10.0)
            areas.append(int(_magenta(_scene_part(img)).sum()))
        assert areas[0] > 500, f"the ellipsoid is hardly visible ({areas[0]} px)"
        # radii double -> the projected area is four times as large (perspective: about)
        assert 3.3 < areas[1] / areas[0] < 4.7, areas
    finally:
        view.clear()


def _circle_stream(duration_s=6.0, rate=100.0) -> PoseStream:
    t = np.arange(0.0, duration_s, 1.0 / rate)
    ang = 2 * np.pi * t / duration_s
    pos = np.stack([0.4 * np.cos(ang), 0.4 * np.sin(ang), 0.1 + 0 * t], axis=1)
    rng = np.random.default_rng(5)
    pos = pos + rng.normal(0, 0.001, pos.shape)
    q = quat_exp(np.stack([0 * t, 0 * t, ang], axis=1))
    return PoseStream("world", "body", np.round(t * 1e9).astype(np.int64), pos, q)


def _centroid(mask: np.ndarray) -> np.ndarray:
    ys, xs = np.nonzero(mask)
    return np.array([xs.mean(), ys.mean()])


def _shows_body_apart(img: np.ndarray, earlier: list, px: float = 40.0) -> bool:
    """The body is drawn, and more than ``px`` from every centroid in ``earlier``."""
    m = _magenta(_scene_part(img))
    if m.sum() <= 30:
        return False
    c = _centroid(m)
    return all(np.linalg.norm(c - e) > px for e in earlier)


def test_scrubbing_a_recording_moves_the_body(browser, page, server):
    track = RecordingTrack.from_stream(_circle_stream())
    # a big body so the centroid is well defined: the readable scene marks the origin with a
    # small wire icosahedron (a solid marker hid the ellipsoid), so the magenta that shows is
    # the position ellipsoid, magnified x100 (a few centimetres)
    view = RecordingView(track, style=Style(axes_length=0.12, magnify=100.0), server=server)
    # The readable scene (issue 29) draws the whole path as a faint line and the 2 s trail in
    # the body's colour, and labels: on the whole circle they would hold the magenta pixels'
    # centroid near the circle's centre whatever the time, so they are hidden and the body's
    # own pixels are measured. The camera is held on the whole circle (by default it frames
    # and follows the body, which would keep the body where it is on the page).
    view.set_scene(follow=False, path=False, trail=False, labels=False)
    server.look_at((0.0, 0.0, 0.1), 0.9)
    server.reset_cameras()
    try:
        centroids = []
        for t in (0.5, 2.0):  # a quarter turn apart
            view.show(t)
            browser.wait_text(page, f"t = {t:.3f} s")
            # the body is drawn some frames after the status text (software WebGL under load)
            img = browser.capture_until(page, lambda im: _shows_body_apart(im, centroids))
            m = _magenta(_scene_part(img))
            assert m.sum() > 30, "the body is not visible"
            centroids.append(_centroid(m))
        moved = float(np.linalg.norm(centroids[1] - centroids[0]))
        assert moved > 40.0, f"the body moved only {moved:.1f} px"
    finally:
        view.close()


def test_a_page_that_took_part_of_the_initial_camera_starts_at_the_home_camera(browser, server):
    # A page takes the initial camera once, at the first of its messages: on a loaded machine
    # it took the position without the point to look at, and looked at the origin, away from
    # the scene, for good. Here a URL parameter makes a page look at the origin the same way;
    # its first report moves it to the home camera, which looks at the magenta ball.
    server.clear()
    home = np.array([2.5, 2.0, 0.4])
    server.place_camera(home + [1.5, -1.5, 1.0], home)
    server.scene.add_icosphere("/ball", radius=0.15, color=(230, 0, 230), position=tuple(home))
    server.set_status("ball placed")
    page = browser.open(server.url + "?initialCameraLookAt=0,0,0", "ball placed")
    try:
        browser.hide_panel(page)
        # the ball at the middle of the page (where the camera looks), bounded wait
        img = browser.capture_until(page, lambda im: _magenta(im).sum() > 300)
        c = _centroid(_magenta(img))
        # the page's last reported camera says whether it looked away or drew nothing
        assert np.linalg.norm(c - [W / 2, H / 2]) < 60, (c, int(_magenta(img).sum()),
                                                          server.camera())  # fmt: skip
    finally:
        page.close()
        server.clear()
