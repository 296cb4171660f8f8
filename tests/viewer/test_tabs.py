"""Each browser tab its own view: two pages of one server. A recording (``trackflow view
RECORDING``): a key pressed in one moves that page's time only, and a page's view goes with the
page. A live network (``attach_view``): a control moved in one page changes that page only,
while the Python API's settings and the prediction offset (the dataflow process's) reach
both."""

from __future__ import annotations

import re

import numpy as np
import pytest

pytest.importorskip("viser", reason="the viewer extra (viser) is not installed")
pytest.importorskip("playwright", reason="the viewer extra (playwright) is not installed")

from _shots import shortcuts_ready, wait_until

from trackflow.dataflow import Network, SimulatedSensor, parse_setup
from trackflow.io import PoseStream
from trackflow.math import quat_exp
from trackflow.viewer import (
    RecordingTrack,
    RecordingView,
    ViewServer,
    attach_view,
    edge_motion,
)
from trackflow.viewer.tabs import PerTab

pytestmark = pytest.mark.slow

W, H = 900, 560
BROWSER_TIMEOUT_S = 120


def _circle(duration_s=4.0, rate=50.0) -> PoseStream:
    t = np.arange(0.0, duration_s, 1.0 / rate)
    ang = 2 * np.pi * t / duration_s
    pos = np.stack([0.4 * np.cos(ang), 0.4 * np.sin(ang), 1.0 + 0 * t], axis=1)
    q = quat_exp(np.stack([0 * t, 0 * t, ang], axis=1))
    return PoseStream("world", "body", np.round(t * 1e9).astype(np.int64), pos, q)


def _until(cond, what) -> None:
    wait_until(cond, what, BROWSER_TIMEOUT_S)


def test_each_tab_keeps_its_own_time_and_its_view_goes_with_it(browser):
    track = RecordingTrack.from_stream(_circle())

    def make(page) -> RecordingView:
        view = RecordingView(track, server=page)
        view.show(1.0)
        return view

    tabs = PerTab(ViewServer(port=0), make)
    try:
        a = browser.open(tabs.url, "t = 1.000 s /")
        b = browser.open(tabs.url, "t = 1.000 s /")
        _until(lambda: len(tabs.views) == 2, lambda: f"{len(tabs.views)} views for 2 pages")
        k = track.index(1.0)
        shortcuts_ready(a, BROWSER_TIMEOUT_S)
        a.keyboard.press("ArrowRight")
        browser.wait_text(a, f"sample {k + 1} ")
        # the other page's view did not move: its own time, shown on its own status line
        times = sorted(round(v.t_s, 3) for v in tabs.views.values())
        assert times == [1.0, round(float(track.t[k + 1]), 3)], times
        text = b.inner_text("body")
        assert f"sample {k} " in text and f"sample {k + 1} " not in text, text[:300]
        assert "each tab has its own view" in text
        a.close()
        _until(lambda: len(tabs.views) == 1, lambda: f"{len(tabs.views)} views for 1 page")
        (left,) = tabs.views.values()
        assert round(left.t_s, 3) == 1.0
    finally:
        tabs.close()


LIVE_SETUP = {
    "frames": ["room", "tool"],
    "sensors": [{"name": "art", "source": "room", "target": "tool", "rate_hz": 50,
                 "latency_ms": 10, "sigma_pos_mm": 2.0, "sigma_ori_deg": 1.0}],
    "queries": [{"name": "q", "source": "room", "target": "tool", "mode": "push",
                 "rate_hz": 25}],
}  # fmt: skip


def _status(page) -> str:
    """The page's own status line (``**live** - network t = ...``)."""
    text = page.inner_text("body")
    line = next((x for x in text.splitlines() if "network t =" in x), None)
    assert line is not None, text[:400]
    return line


def _fill(page, label: str, value: str) -> None:
    """Type ``value`` into the panel's field labelled exactly ``label`` (and leave it)."""
    name = re.compile(f"^{re.escape(label)}$")
    row = page.locator(".mantine-Flex-root", has=page.locator("label", has_text=name)).last
    field = row.locator("input")
    field.fill(value)
    field.press("Enter")
    field.blur()


def test_each_tab_has_its_own_live_view_and_shares_the_prediction(browser):
    sensor = SimulatedSensor(
        "art", edge_motion(0), rate_hz=50, latency_s=0.01, sigma_pos=0.002, sigma_ori=0.02,
        rng=np.random.default_rng(3), start_s=0.0, end_s=3.0,
    )  # fmt: skip
    setup = parse_setup(LIVE_SETUP)
    net = Network()
    plan = setup.plan("q")
    plan.build({"art": sensor}, network=net, prefix="view:")
    live = attach_view(net, setup, {"q": (plan, "view:")}, port=0, rate_hz=10)
    try:
        net.run(until_ns=int(2e9))
        a = browser.open(live.url, "network t = 2.00 s")
        b = browser.open(live.url, "network t = 2.00 s")
        assert "each tab has its own live view" in b.inner_text("body")
        # a control moved in one page changes that page's view
        _fill(a, "magnify", "5")
        browser.wait_text(a, "ellipsoids x5")
        # a setting of the Python API reaches every page; the other kept its magnification
        live.set_sigma(2)
        for page in (a, b):
            browser.wait_text(page, "2 sigma")
        assert "2 sigma, ellipsoids x5" in _status(a), _status(a)
        assert "ellipsoids" not in _status(b), _status(b)
        # the prediction is the dataflow's: a slider moved in one page moves it for both
        a.get_by_role("slider").first.focus()
        a.keyboard.press("ArrowRight")
        for page in (a, b):
            browser.wait_text(page, "predicted +5 ms")
        _until(lambda: abs(live.offset_s - 0.005) < 1e-9, lambda: f"offset {live.offset_s}")
        rep = live.scene_report()  # the first page's
        assert rep["anchor"] == "room" and [x["name"] for x in rep["bodies"]] == ["art", "q"]
        # a page opened later starts from the Python API's settings
        c = browser.open(live.url, "2 sigma")
        assert "ellipsoids" not in _status(c) and "predicted +5 ms" in _status(c), _status(c)
        for page in (a, b, c):
            page.close()
        _until(lambda: live.clients == 0, lambda: f"{live.clients} pages still counted")
        assert live.scene_report()["browser_camera"] is False  # no page: the defaults
    finally:
        live.close()
