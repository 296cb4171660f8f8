"""Headless Chromium for snapshots and tests: Debian's ``chromium`` driven by Playwright.

No browser is downloaded: Playwright launches the system Chromium (``make browser`` installs
it) with SwiftShader WebGL (``--use-angle=swiftshader --enable-unsafe-swiftshader``), so a
machine without a GPU renders the three.js scene in software. Every wait is bounded.
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..optional import require

__all__ = ["CHROMIUM_FLAGS", "Browser", "find_chromium", "snapshot"]

CHROMIUM_FLAGS = (
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--hide-scrollbars",
    "--mute-audio",
)
# viser warns about software WebGL in a notification; snapshots hide notifications
_HIDE_NOTIFICATIONS = "[class*='Notifications-root'] { display: none !important; }"
# the floating control panel of viser (its Mantine papers)
_HIDE_PANEL = ".mantine-Paper-root { display: none !important; }"


def find_chromium() -> Path:
    """The Chromium executable: ``$TRACKFLOW_CHROMIUM``, else ``chromium`` on the PATH.

    Raises
    ------
    FileNotFoundError
        Naming how to install it (``make browser`` or ``apt-get install chromium``).
    """
    env = os.environ.get("TRACKFLOW_CHROMIUM")
    if env:
        p = Path(env)
        if not p.is_file():
            raise FileNotFoundError(f"TRACKFLOW_CHROMIUM={env} is not a file")
        return p
    for name in ("chromium", "chromium-browser"):
        found = shutil.which(name)
        if found:
            return Path(found)
    raise FileNotFoundError(
        "no Chromium found for headless snapshots: run `make browser` "
        "(apt-get install -y chromium) or set TRACKFLOW_CHROMIUM"
    )


class Browser:
    """One headless Chromium (a context manager) whose pages show viewer URLs.

    Parameters
    ----------
    width, height : int
        Viewport in CSS pixels (screenshots have this size).
    timeout_s : float
        Bound of every wait (page load, text to appear).
    executable : path, optional
        The browser to launch (default :func:`find_chromium`).
    """

    def __init__(
        self,
        width: int = 1280,
        height: int = 800,
        timeout_s: float = 60.0,
        executable: str | Path | None = None,
    ):
        self.width, self.height, self.timeout_ms = int(width), int(height), timeout_s * 1e3
        self.executable = executable
        self._pw = self._browser = None

    def __enter__(self) -> Browser:
        sync_api = require("playwright.sync_api", extra="viewer", feature="snapshots")
        sync_playwright = sync_api.sync_playwright
        exe = self.executable or find_chromium()
        self._pw = sync_playwright().start()
        try:
            self._browser = self._pw.chromium.launch(
                executable_path=str(exe), args=list(CHROMIUM_FLAGS), timeout=self.timeout_ms
            )
        except Exception:
            self._pw.stop()
            raise
        return self

    def __exit__(self, *exc) -> None:
        if self._browser is not None:
            self._browser.close()
        if self._pw is not None:
            self._pw.stop()

    def open(self, url: str, wait_text: str | None = None):
        """Open ``url`` in a new page; wait for the WebGL canvas (and ``wait_text``)."""
        page = self._browser.new_page(viewport={"width": self.width, "height": self.height})
        page.set_default_timeout(self.timeout_ms)
        page.goto(url)
        page.add_style_tag(content=_HIDE_NOTIFICATIONS)
        page.wait_for_selector("canvas")
        if wait_text:
            self.wait_text(page, wait_text)
        return page

    @staticmethod
    def hide_panel(page) -> None:
        """Hide the page's control panel: the 3D view alone (a snapshot without it)."""
        page.add_style_tag(content=_HIDE_PANEL)

    def wait_text(self, page, text: str) -> None:
        """Wait until ``text`` is shown on the page (a view's status line)."""
        page.wait_for_function("t => document.body.innerText.includes(t)", arg=text)

    def settle(self, page, ms: int = 500) -> None:
        """Give the page ``ms`` to apply scene updates that arrived with the status text (a
        screenshot then composites a fresh frame). Software WebGL is slow, so this waits a
        fixed time rather than counting animation frames (one frame can take seconds)."""
        page.wait_for_timeout(ms)

    def capture(self, page, path: str | Path | None = None, stable_s: float = 0.0) -> np.ndarray:
        """Screenshot as an RGB array (H, W, 3) of uint8; also written to ``path``.

        ``stable_s > 0``: for a still scene, take screenshots 0.25 s apart until two are
        identical (objects fade in over several frames, slower in software WebGL), for at most
        ``stable_s``; then the last one is returned. A moving (live) scene keeps the default.
        """
        from io import BytesIO

        from PIL import Image

        self.settle(page)
        png = page.screenshot()
        deadline = time.monotonic() + stable_s
        while time.monotonic() < deadline:
            page.wait_for_timeout(250)
            again = page.screenshot()
            if again == png:
                break
            png = again
        if path is not None:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            Path(path).write_bytes(png)
        return np.asarray(Image.open(BytesIO(png)).convert("RGB"))

    def capture_until(
        self, page, accept: Callable[[np.ndarray], bool], within_s: float | None = None
    ) -> np.ndarray:
        """The first screenshot for which ``accept(image)`` holds, taken about 0.5 s apart.

        For a scene update that arrived with the status text but is drawn some frames later
        (software WebGL under load can take seconds per frame). Bounded by ``within_s``
        (default: the browser's timeout); then the last screenshot is returned as it is, so
        the caller's assertion reports what was shown.
        """
        limit = self.timeout_ms / 1e3 if within_s is None else within_s
        deadline = time.monotonic() + limit
        img = self.capture(page)
        while not accept(img) and time.monotonic() < deadline:
            img = self.capture(page)  # each capture first lets the page draw for 0.5 s
        return img


def snapshot(
    url: str,
    out: str | Path,
    wait_text: str | None = None,
    width: int = 1280,
    height: int = 800,
    timeout_s: float = 90.0,
    hide_panel: bool = False,
) -> Path:
    """Render ``url`` in headless Chromium and write a PNG to ``out``; returns the path.
    ``hide_panel``: without the control panel (once ``wait_text``, which the panel shows,
    is there).

    Starts its own :class:`Browser` (Playwright's sync API: not from inside another
    ``Browser`` context of the same thread)."""
    out = Path(out)
    with Browser(width, height, timeout_s) as b:
        page = b.open(url, wait_text)
        if hide_panel:
            b.hide_panel(page)
        b.capture(page, out, stable_s=min(10.0, timeout_s))
    return out
