"""A small shared scene for the optical tests: a 4-camera rig, three bodies (two of them
similar) moving along detrended real recordings from ../shared/data."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trackflow.io import read_stream
from trackflow.optical import ring_rig
from trackflow.optical.models import random_model, similar_model
from trackflow.optical.render import FrameRenderer, RenderSettings, trajectory_from_stream

RECORDINGS = ["ar_table/table_01.txt", "ar_table/table_02.txt", "ar_table/table_03.txt"]
CENTERS = [(0.45, 0.0, 1.0), (-0.22, 0.39, 1.1), (-0.22, -0.39, 0.9)]


def models(n_markers: int = 10, seed: int = 0):
    rng = np.random.default_rng(seed)
    a = random_model("A", n_markers, rng)
    return [a, similar_model(a, "B", rng), random_model("C", n_markers, rng)]


def trajectories(names, data: Path):
    """Trajectories of ``names`` from the shared recordings in ``data`` (the ``shared_data``
    fixture of tests/conftest.py)."""
    out = {}
    for name, rec, c in zip(names, RECORDINGS, CENTERS):
        stream, _ = read_stream(data / rec)
        out[name] = trajectory_from_stream(stream, c, detrend_s=4.0)
    return out


def renderer(data: Path, settings: RenderSettings | None = None, n_markers: int = 10, seed=1):
    ms = models(n_markers)
    settings = settings or RenderSettings(visibility_deg=100.0)
    return FrameRenderer(ring_rig(4), ms, trajectories([m.name for m in ms], data), settings, seed)
