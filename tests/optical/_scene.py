"""The optical tests' scene: :func:`trackflow.optical.scene.three_body_scene` with 10 markers
per body, visible up to 100 degrees off their normal, no person walking through."""

from __future__ import annotations

from pathlib import Path

from trackflow.optical.render import RenderSettings
from trackflow.optical.scene import three_body_scene


def renderer(data: Path, settings: RenderSettings | None = None, n_markers: int = 10, seed=1):
    settings = settings or RenderSettings(visibility_deg=100.0)
    return three_body_scene(data, n_markers, seed=seed, settings=settings)[2]
