"""Shared test fixtures.

Real recordings live outside the repository: ``$TRACKFLOW_DATA``, else ``../shared/data``
relative to the repository root, else the workplace's ``/work/shared/data``. Tests that need
them take the ``shared_data`` fixture, which skips with the reason when none is present.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    """Folder with the shared real recordings (may not exist)."""
    env = os.environ.get("TRACKFLOW_DATA")
    if env:
        return Path(env)
    for candidate in (REPO_ROOT.parent / "shared" / "data", Path("/work/shared/data")):
        if (candidate / "README.md").is_file():
            return candidate
    return REPO_ROOT.parent / "shared" / "data"


@pytest.fixture
def shared_data() -> Path:
    d = shared_data_dir()
    if not (d / "README.md").is_file():
        pytest.skip(f"shared recordings not found at {d} (set TRACKFLOW_DATA to their folder)")
    return d


@pytest.fixture
def room1(shared_data) -> Path:
    """TUM-VI room1's motion-capture recording (the simulated trackers' usual source)."""
    path = shared_data / "tumvi" / "dataset-room1_512_16.txt"
    if not path.exists():
        pytest.skip(f"{path} not present")
    return path


@pytest.fixture
def rng() -> np.random.Generator:
    """A fresh, seeded generator per test: no shared hidden RNG state between tests."""
    return np.random.default_rng(20261121)


@pytest.fixture
def router():
    """A Zenoh router on loopback standing in for ``rmw_zenohd`` (the ROS 2 tests,
    ``tests/ros2/_ros2live.py``; here because a second ``conftest`` module would shadow this
    one for ``from conftest import ...``)."""
    pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed")
    pytest.importorskip("rosbags", reason="rosbags is not installed")
    from _ros2live import Router

    r = Router()
    yield r
    r.close()


@pytest.fixture(scope="module")
def browser(request):
    """One headless Chromium per test module (starting one costs seconds of a loaded machine;
    a page costs software WebGL its shaders: modules keep one page where they can). Its
    viewport is the module's ``W`` x ``H``, its waits bounded by ``BROWSER_TIMEOUT_S``
    (default 90 s). Skips with the reason when Chromium or the viewer extra is missing."""
    pytest.importorskip("playwright", reason="the viewer extra (playwright) is not installed")
    from trackflow.viewer import Browser, find_chromium

    try:
        find_chromium()
    except FileNotFoundError as exc:
        pytest.skip(str(exc))
    mod = request.module
    size = (getattr(mod, "W", 1024), getattr(mod, "H", 640))
    with Browser(*size, timeout_s=getattr(mod, "BROWSER_TIMEOUT_S", 90)) as b:
        yield b


@pytest.fixture(scope="module")
def server():
    """The module's viser server for the views its tests draw in this process (one page
    keeps its WebGL context across views: ``ViewServer.clear``)."""
    from trackflow.viewer import ViewServer

    view = ViewServer(port=0)
    yield view
    view.close()


@pytest.fixture(scope="module")
def page(browser, server):
    """The module's one page on ``server``, once it reported its camera (tests move it);
    bounded by the module's ``BROWSER_TIMEOUT_S`` (default 90 s)."""
    import time

    server.look_at((1.0, 0.0, 0.5), 1.0)
    server.set_status("page ready")
    p = browser.open(server.url, "page ready")
    end = time.monotonic() + browser.timeout_ms / 1e3
    while not server.has_browser_camera:
        assert time.monotonic() < end, "the page did not report its camera"
        time.sleep(0.1)
    yield p
    p.close()
