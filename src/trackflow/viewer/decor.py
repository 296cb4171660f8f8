"""What makes a scene readable besides the poses: the floor grid with its metric scale, the
faint full path of a body, and the legend of the glyphs (pure functions and small helpers;
the drawing calls take a viser scene)."""

from __future__ import annotations

import html
import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "GridSpec",
    "add_floor_grid",
    "faint",
    "format_length",
    "grid_spec",
    "nice_step",
    "path_segments",
]

#: Line colours of the floor grid: cells and the heavier section lines (RGB 0-255).
GRID_CELL_RGB = (205, 205, 205)
GRID_SECTION_RGB = (150, 150, 150)


def nice_step(x: float) -> float:
    """The smallest of 1, 2, 5 times a power of ten that is at least ``x`` (> 0)."""
    x = max(float(x), 1e-9)
    p = 10.0 ** math.floor(math.log10(x))
    for m in (1.0, 2.0, 5.0, 10.0):
        if m * p >= x * (1 - 1e-9):
            return m * p
    return 10.0 * p


def format_length(m: float) -> str:
    """A length for a label: ``5 mm``, ``20 cm``, ``1 m``, ``1.5 m``."""
    if m >= 1.0:
        return f"{m:g} m"
    if m >= 0.01:
        return f"{m * 100:g} cm"
    return f"{m * 1000:g} mm"


@dataclass(frozen=True)
class GridSpec:
    """A floor grid in the xy plane of the world (Z up).

    Attributes
    ----------
    center : ndarray (3,)
        Centre of the grid; its z is the floor's height [m].
    width, height : float
        Size along x and y [m] (whole multiples of ``section``).
    cell, section : float
        Spacing of the thin and of the heavier lines [m].
    """

    center: np.ndarray
    width: float
    height: float
    cell: float
    section: float

    @property
    def text(self) -> str:
        """The scale as a label says it."""
        return f"grid {format_length(self.cell)} cells, {format_length(self.section)} lines"

    def mark(self, near) -> np.ndarray:
        """The grid's line crossing closest to the point ``near`` (3,), on the grid (where
        the scale label goes)."""
        p = np.asarray(near, float)
        half = np.array([self.width, self.height]) / 2
        xy = np.clip(p[:2], self.center[:2] - half, self.center[:2] + half)
        xy = np.round(xy / self.cell) * self.cell
        return np.array([xy[0], xy[1], self.center[2]])


def grid_spec(lo, hi, cells: int = 20) -> GridSpec:
    """A grid covering the box ``lo``-``hi`` (3,) of the data with a wide margin, with about
    ``cells`` cells along its longer side, on the floor: ``z = 0`` when the data are up to
    3 m above it (a motion capture room's origin is on the floor), else under the data."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    span = float(max(np.max(hi[:2] - lo[:2]), 0.05))
    cell = nice_step(span / cells)
    mantissa = round(cell / 10.0 ** math.floor(math.log10(cell)))
    section = cell * (5.0 if mantissa == 2 else 10.0)
    centre = np.round(0.5 * (lo[:2] + hi[:2]) / section) * section
    # the data's box and as much again around it (a floor, not a tile under the path)
    half = np.maximum(np.abs(hi[:2] - centre), np.abs(lo[:2] - centre)) + max(2 * cell, span / 2)
    size = 2 * np.ceil(half / section) * section
    floor = 0.0 if 0.0 <= lo[2] <= 3.0 else float(lo[2])
    return GridSpec(np.array([centre[0], centre[1], floor]), float(size[0]), float(size[1]),
                    cell, section)  # fmt: skip


def add_floor_grid(scene, path: str, spec: GridSpec, visible: bool = True):
    """The grid of ``spec`` as a viser grid node at ``path``; returns its handle."""
    return scene.add_grid(
        path, width=spec.width, height=spec.height, plane="xy",
        cell_color=GRID_CELL_RGB, cell_size=spec.cell, cell_thickness=1.0,
        section_color=GRID_SECTION_RGB, section_size=spec.section, section_thickness=1.4,
        position=tuple(spec.center), shadow_opacity=0.0, visible=visible,
        fade_distance=max(spec.width, spec.height) * 4, fade_strength=0.5,
    )  # fmt: skip


def faint(rgb, amount: float = 0.75) -> tuple[int, int, int]:
    """``rgb`` blended ``amount`` of the way to white (the full path, drawn behind)."""
    c = np.asarray(rgb, float)
    return tuple(int(v) for v in np.round(c + amount * (255.0 - c)))


def path_segments(points, max_points: int = 4000) -> np.ndarray:
    """Line segments (M, 2, 3) through ``points`` (N, 3), every k-th point so that at most
    ``max_points`` are used; NaN rows (gaps) break the line."""
    p = np.asarray(points, float)
    step = max(1, int(math.ceil(len(p) / max_points)))
    p = p[::step]
    if len(p) < 2:
        return np.zeros((0, 2, 3))
    seg = np.stack([p[:-1], p[1:]], axis=1)
    return seg[np.all(np.isfinite(seg), axis=(1, 2))]


def legend_rows(rows: list[tuple[str, str]]) -> str:
    """Markdown of a two-column legend: (glyph, what it shows)."""
    out = ["| glyph | shows |", "|---|---|"]
    out += [f"| {html.escape(g)} | {html.escape(s)} |" for g, s in rows]
    return "\n".join(out)
