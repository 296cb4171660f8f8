"""Pixel measures of the browser views shared by the scene tests, and the pictures of
``docs/viewer.md``: with ``TRACKFLOW_DOC_SHOTS=1`` the tests write the screenshots they
assert on into ``docs/viewer/`` (``make doc-shots``); otherwise nothing is written."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

DOCS = Path(__file__).resolve().parents[2] / "docs" / "viewer"

# the floating control panel of viser (a Mantine paper), as a box in CSS pixels
_PANEL_JS = """() => {
  let best = null;
  for (const el of document.querySelectorAll('.mantine-Paper-root')) {
    const r = el.getBoundingClientRect();
    const box = [r.x, r.y, r.width, r.height];
    if (best === null || r.width * r.height > best[2] * best[3]) best = box;
  }
  return best;
}"""


def panel_box(page) -> tuple[int, int, int, int]:
    """The control panel's box ``(x0, y0, x1, y1)`` on the page [px] (empty if none)."""
    r = page.evaluate(_PANEL_JS)
    if r is None:
        return (0, 0, 0, 0)
    x, y, w, h = r
    return int(x), int(y), int(np.ceil(x + w)), int(np.ceil(y + h))


def capture_panel_until(browser, page, accept) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """The first screenshot for which ``accept(image, box)`` holds, and the panel's box then.

    The box is read again with every screenshot: the panel grows as its content arrives,
    and under load a box read before the first drawing misses what is drawn later. Bounded
    like :meth:`Browser.capture_until`; then the last screenshot and its box are returned.
    """
    box = panel_box(page)

    def ok(img: np.ndarray) -> bool:
        nonlocal box
        box = panel_box(page)
        return accept(img, box)

    img = browser.capture_until(page, ok)
    return img, box


def outside(shape, box) -> np.ndarray:
    """Mask (H, W) of the pixels outside ``box`` (the 3D scene the panel does not cover)."""
    m = np.ones(shape[:2], bool)
    x0, y0, x1, y1 = box
    m[max(y0, 0) : max(y1, 0), max(x0, 0) : max(x1, 0)] = False
    return m


def changed(a: np.ndarray, b: np.ndarray, tol: int = 30) -> np.ndarray:
    """Pixels that differ by more than ``tol`` in some channel."""
    return np.any(np.abs(a.astype(int) - b.astype(int)) > tol, axis=-1)


def bbox(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    """Bounding box ``(x0, y0, x1, y1)`` of the set pixels (None if there are none)."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return None
    return int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1


def bbox_fraction(mask: np.ndarray) -> float:
    """Area of the bounding box of the set pixels over the whole image's area."""
    b = bbox(mask)
    if b is None:
        return 0.0
    return (b[2] - b[0]) * (b[3] - b[1]) / float(mask.shape[0] * mask.shape[1])


def doc_shot(img: np.ndarray, name: str) -> None:
    """Write ``img`` to ``docs/viewer/NAME.png`` when ``TRACKFLOW_DOC_SHOTS`` is set."""
    if not os.environ.get("TRACKFLOW_DOC_SHOTS"):
        return
    from PIL import Image

    DOCS.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(DOCS / f"{name}.png")


def wait_until(cond, what, within_s: float) -> None:
    """Wait (bounded by ``within_s``) until ``cond()``; on the timeout fail with ``what()``."""
    end = time.monotonic() + within_s
    while not cond():
        assert time.monotonic() < end, what()
        time.sleep(0.05)


def shortcuts_ready(page, within_s: float) -> None:
    """Wait until the page's shortcut script runs (``viewer/shortcuts.py``): it is installed
    by an image's error event, which may come after the panel's text is shown."""
    page.wait_for_function(
        "() => window.__tf && Object.keys(window.__tf.keys).length > 0",
        timeout=within_s * 1000,
    )
