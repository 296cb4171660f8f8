"""``trackflow view RECORDING --snapshot`` end to end: the command starts its own headless
Chromium (its own module: Playwright's sync API runs one instance per thread at a time)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("viser", reason="the viewer extra (viser) is not installed")
pytest.importorskip("playwright", reason="the viewer extra (playwright) is not installed")

from PIL import Image

from trackflow.cli.main import main
from trackflow.io import PoseStream, write_stream
from trackflow.math import quat_exp
from trackflow.viewer import find_chromium

pytestmark = pytest.mark.slow


def test_cli_snapshot_of_a_recording(tmp_path):
    try:
        find_chromium()
    except FileNotFoundError as exc:
        pytest.skip(str(exc))
    t = np.arange(0.0, 4.0, 0.01)
    ang = 2 * np.pi * t / 4.0
    pos = np.stack([0.4 * np.cos(ang), 0.4 * np.sin(ang), 0.1 + 0 * t], axis=1)
    pos += np.random.default_rng(1).normal(0, 1e-3, pos.shape)
    q = quat_exp(np.stack([0 * t, 0 * t, ang], axis=1))
    rec = tmp_path / "circle.tum"
    write_stream(rec, PoseStream("world", "body", np.round(t * 1e9).astype(np.int64), pos, q))
    out = tmp_path / "shot.png"
    args = ["view", str(rec), "--snapshot", str(out), "--at", "1.5", "--sigma", "2"]
    assert main([*args, "--width", "800", "--height", "500"]) == 0
    img = np.asarray(Image.open(out).convert("RGB")).astype(int)
    assert img.shape == (500, 800, 3)
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    body = (r > g + 70) & (b > g + 70) & (np.abs(r - b) < 70)  # the magenta body
    assert body[:, :480].sum() > 10
