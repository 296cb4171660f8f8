"""A ready-made scene for experiments, benchmarks and tests: four cameras on a ring and three
marker bodies (two of them nearly identical) moving along real hand-held recordings.

The recordings are ``ar_table/table_0{1,2,3}.txt`` of the shared data folder (see
:func:`shared_data_dir`), detrended by 4 s so the walking stays in the capture volume.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..io import read_stream
from .camera import CameraRig, ring_rig
from .models import MarkerModel, random_model, similar_model
from .render import Cylinder, FrameRenderer, RenderSettings, trajectory_from_stream

__all__ = ["RECORDINGS", "shared_data_dir", "three_body_scene"]

RECORDINGS = ("ar_table/table_01.txt", "ar_table/table_02.txt", "ar_table/table_03.txt")
CENTERS = ((0.45, 0.0, 1.0), (-0.22, 0.39, 1.1), (-0.22, -0.39, 0.9))


def shared_data_dir(repo_root: Path | None = None) -> Path:
    """The shared real recordings: ``$TRACKFLOW_DATA``, else ``../shared/data`` next to the
    repository, else ``/work/shared/data`` (the folder may not exist)."""
    env = os.environ.get("TRACKFLOW_DATA")
    if env:
        return Path(env)
    root = repo_root or Path(__file__).resolve().parents[3]
    for c in (root.parent / "shared" / "data", Path("/work/shared/data")):
        if (c / "README.md").is_file():
            return c
    return root.parent / "shared" / "data"


def three_body_scene(
    data: Path,
    n_markers: int = 20,
    seed: int = 0,
    settings: RenderSettings | None = None,
    occluder: bool = True,
    extent=(0.2, 0.16, 0.08),
    min_separation: float = 0.045,
) -> tuple[CameraRig, list[MarkerModel], FrameRenderer]:
    """Rig, models ``A``, ``B`` (``A`` with two markers moved by 2 cm) and ``C``, and a
    renderer of their frames (times in seconds of the recordings).

    The markers lie on an ellipsoid of semi-axes ``extent`` [m], ``min_separation`` apart (the
    defaults keep the images of 20 markers seen from 3 m mostly apart; denser layouts merge
    many blobs).

    ``settings`` default: :class:`RenderSettings` (0.1 px jitter, mirror, reflections) plus,
    with ``occluder``, a person walking around the volume.
    """
    rng = np.random.default_rng(seed)
    a = random_model("A", n_markers, rng, extent, min_separation)
    b = similar_model(a, "B", rng, n_moved=2, shift=0.02)
    models = [a, b, random_model("C", n_markers, rng, extent, min_separation)]
    trajs = {}
    for m, rec, c in zip(models, RECORDINGS, CENTERS):
        stream, _ = read_stream(Path(data) / rec)
        trajs[m.name] = trajectory_from_stream(stream, c, detrend_s=4.0)
    if settings is None:
        settings = RenderSettings()
        if occluder:
            settings.occluders = [Cylinder((0.0, 0.0), 1.4, 0.5, 0.0, 0.22, 1.8)]
    rig = ring_rig(4)
    return rig, models, FrameRenderer(rig, models, trajs, settings, seed=seed + 1)
