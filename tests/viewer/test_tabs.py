"""Each browser tab its own view (``trackflow view RECORDING``): two pages of one server, a
key pressed in one moves that page's time only, and a page's view goes with the page."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("viser", reason="the viewer extra (viser) is not installed")
pytest.importorskip("playwright", reason="the viewer extra (playwright) is not installed")

from _shots import shortcuts_ready, wait_until

from trackflow.io import PoseStream
from trackflow.math import quat_exp
from trackflow.viewer import RecordingTrack, RecordingView, ViewServer
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
