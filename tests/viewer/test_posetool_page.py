"""The PoseTool in headless Chromium on a real recording (AR table 01): each tab its own
settings and computation, the error plot in view without scrolling, the residual plot in
millimetres consistent with the error plot, and the documentation's picture."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("viser", reason="the viewer extra (viser) is not installed")
pytest.importorskip("playwright", reason="the viewer extra (playwright) is not installed")

from _shots import doc_shot, wait_until

from trackflow.io import read_stream
from trackflow.viewer import ViewServer
from trackflow.viewer.posetool import PoseTool, PoseToolPage
from trackflow.viewer.tabs import PerTab

pytestmark = pytest.mark.slow

W, H = 1400, 1000  # the documentation's picture
BROWSER_TIMEOUT_S = 180

# the bottom of the uPlot chart whose title is ``title`` (page pixels), or None
_PLOT_BOTTOM = """(title) => {
  const t = [...document.querySelectorAll('.u-title')].find(e => e.textContent === title);
  if (!t) return null;
  const r = t.closest('.uplot').getBoundingClientRect();
  return r.bottom;
}"""


@pytest.fixture
def table01(shared_data):
    path = shared_data / "ar_table" / "table_01.txt"
    if not path.exists():
        pytest.skip(f"{path} not present")
    stream, _ = read_stream(path)
    return stream


def test_posetool_tabs_have_their_own_settings_and_the_error_plot_is_in_view(browser, table01):
    tool = PoseTool(table01, tune_fraction=0.5)
    tabs = PerTab(ViewServer(port=0, title=tool.title), lambda page: PoseToolPage(tool, page),
                  note="each tab has its own settings")  # fmt: skip
    try:
        a = browser.open(tabs.url, "revision")
        b = browser.open(tabs.url, "revision")
        wait_until(lambda: len(tabs.views) == 2, lambda: f"{len(tabs.views)} views for 2 pages",
                   BROWSER_TIMEOUT_S)  # fmt: skip
        views = list(tabs.views.values())
        for v in views:
            v.wait_tuned(timeout_s=600)
        va, vb = views
        before, b_controls = dict(vb.last_rows), vb.controls()
        # one tab's slider: that tab recomputes, the other keeps its settings and table
        va.log_pos.value = -1.0
        va.wait_settled(timeout_s=300)
        assert va.last_rows["Kalman (hand)"] != before["Kalman (hand)"]
        assert vb.controls() == b_controls and float(vb.log_pos.value) != -1.0
        assert vb.last_rows == before
        # the residual plot: one axis of (prediction - recording) [mm], never larger than the
        # error plot's norm at the same times; another axis gives other residuals
        t_err, hand_err = (np.asarray(c) for c in va.errors.data[:2])
        t_res, hand_res = (np.asarray(c) for c in (va.residuals.data[0], va.residuals.data[2]))
        np.testing.assert_array_equal(t_err, t_res)
        ok = np.isfinite(hand_res)
        assert ok.sum() > 100 and np.all(np.abs(hand_res[ok]) <= hand_err[ok] + 1e-9)
        assert 0.1 < float(np.sqrt(np.mean(hand_res[ok] ** 2))) < 100.0  # millimetres
        va.axis.value = "z"
        va.wait_settled(timeout_s=300)
        assert not np.array_equal(np.asarray(va.residuals.data[2]), hand_res)
        # the error plot is in view on the page, without scrolling
        for page in (a, b):
            browser.wait_text(page, "position prediction error")
            bottom = page.evaluate(_PLOT_BOTTOM, "position prediction error")
            assert bottom is not None and bottom <= H, bottom
        browser.wait_text(b, "each tab has its own settings")
        text = b.inner_text("body")
        assert "automatic tuning" in text and "(running)" not in text, text[:400]
        browser.wait_text(a, "residual: z position minus the recording's")
        # the documentation's picture: the other tab, on the default settings
        browser.wait_text(b, f"revision {vb.revision} ")
        doc_shot(browser.capture(b, stable_s=10.0), "posetool_ar_table")
    finally:
        tabs.close()
