"""``trackflow view --realm NAME`` with real processes: two agents on loopback (a sensor's host
and an application with a push query), the realm's view as a third process, headless
Chromium on its page. The page lists both agents, the sensor's edge and the query running on
it, draws the query's answer, and after a kill -9 of the sensor's host shows the agent gone
and the application's re-plan, each with its time."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (pip install .[distributed])")

from _agents import SRC, AgentProcess, free_port, sensor_and_app

from trackers._lines import read_lines, wait_line  # tests/trackers
from viewer._shots import doc_shot, outside, panel_box  # tests/viewer

pytestmark = pytest.mark.slow

W, H = 1100, 700
BROWSER_TIMEOUT_S = 120


def _magenta(img: np.ndarray) -> np.ndarray:
    """The first answer's colour (the palette's magenta), shaded."""
    r, g, b = (img[..., i].astype(int) for i in range(3))
    return (r > g + 70) & (b > g + 70) & (np.abs(r - b) < 70)


def test_the_realm_view_shows_agents_edges_answers_and_a_replan(tmp_path, browser):
    realm = f"view{free_port()}"
    sensor, app, endpoints = sensor_and_app(tmp_path, realm, duration_s=90)
    agents = [AgentProcess(f, "--duration", "120", log_dir=tmp_path) for f in (sensor, app)]
    env = dict(os.environ, PYTHONPATH=str(SRC))
    view = subprocess.Popen(
        [sys.executable, "-m", "trackflow.cli.main", "view", "--realm", realm, "--port", "0",
         "--connect", endpoints[0], "--connect", endpoints[1]],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    try:
        for a in agents:
            a.wait_ready()
        url = wait_line(read_lines(view.stderr), "view: ", 120).split(" ", 1)[1]
        page = browser.open(url, f"realm {realm}")
        t0 = time.monotonic()
        # both agents, the sensor's edge advertised live and the query running on it
        for text in ("host_c", "host_s", "advertises s1", "query q: running, path W-&gt;X[s1]"
                     .replace("&gt;", ">")):  # fmt: skip
            browser.wait_text(page, text)
        print(f"realm shown {time.monotonic() - t0:.2f} s after the page opened")
        # the query's answer drawn: its colour in the scene, outside the panel
        img = browser.capture_until(
            page, lambda im: (_magenta(im) & outside(im.shape, panel_box(page))).sum() > 30
        )
        assert (_magenta(img) & outside(img.shape, panel_box(page))).sum() > 30
        doc_shot(img, "realm_view")
        agents[0].kill9()
        t_kill = time.monotonic()
        browser.wait_text(page, "agent host_s left")
        browser.wait_text(page, "host_c: query q re-planned")
        print(f"re-plan shown {time.monotonic() - t_kill:.2f} s after the kill")
        text = page.inner_text("body")
        # each event with its time of day, newest first; the gone agent no longer alive
        events = re.findall(r"(\d\d:\d\d:\d\d\.\d{3}) (agent host_s left|host_c: query q re-pl)",
                            text)  # fmt: skip
        assert {e[1] for e in events} == {"agent host_s left", "host_c: query q re-pl"}, text
        assert "1 agent(s) alive" in text, text
    finally:
        view.terminate()
        try:
            view.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            view.kill()
            view.communicate()
        for a in agents:
            a.stop()
    assert view.returncode == 143, view.returncode  # SIGTERM, handled by the command line
