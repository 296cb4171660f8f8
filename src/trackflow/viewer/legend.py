"""The legend of the glyphs (markdown for a viser GUI panel), with the current sigma level,
each error's size at that level and the magnification it is drawn with."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..math import UncertainPose
from .decor import GridSpec
from .scene import Style

__all__ = ["BodyLine", "live_legend", "recording_legend", "sigma_sizes"]


def sigma_sizes(covariance: np.ndarray, sigma: float) -> tuple[float, float]:
    """Largest position semi-axis [mm] and orientation semi-axis [deg] at ``sigma``."""
    c = np.asarray(covariance, float)
    pos = math.sqrt(max(float(np.linalg.eigvalsh(c[:3, :3])[-1]), 0.0)) * 1e3 * sigma
    ori = math.degrees(math.sqrt(max(float(np.linalg.eigvalsh(c[3:, 3:])[-1]), 0.0))) * sigma
    return pos, ori


def _mm(v: float) -> str:
    return f"{v:.3g} mm" if v < 1000 else f"{v / 1e3:.3g} m"


def _common(style: Style, grid: GridSpec | None) -> list[str]:
    ori = ", orientation error (discs at the axis tips) likewise" if style.show_orientation else ""
    mag = f"**x{style.magnify:g}**"
    out = [f"- ellipsoids at **{style.sigma:g} sigma**: position error drawn {mag}{ori}"]
    if style.show_trail:
        out.append(f"- fading line: the last {style.trail_s:g} s")
    if style.show_path:
        out.append("- faint line: the whole path")
    if grid is not None:
        out.append(f"- floor: {grid.text} (z = {grid.center[2]:g} m)")
    out.append("- labels: `frame X` names a frame's axes; a plain name, a body")
    return out


def recording_legend(
    target: str,
    pose: UncertainPose,
    style: Style,
    predicted: UncertainPose | None,
    offset_s: float,
    grid: GridSpec | None,
) -> str:
    """The recording view's legend at the shown time."""
    pos, ori = sigma_sizes(pose.covariance, style.sigma)
    lines = [
        f"**{target}** (magenta): axes at the filtered pose, a small wire marker on its origin",
        f"- position error {_mm(pos)}, orientation error {ori:.3g} deg "
        f"({style.sigma:g} sigma, largest semi-axes)",
    ]
    if predicted is not None:
        gp, _ = sigma_sizes(predicted.covariance, style.sigma)
        lines.append(
            f"- wireframe and short axes: predicted +{offset_s * 1e3:.0f} ms, position error "
            f"{_mm(gp)}, drawn **x{style.ghost_magnify:g}** (its own scale); black dot: "
            "recorded then"
        )
    lines.append("- grey dot: the measurement")
    return "\n".join(lines + _common(style, grid))


@dataclass
class BodyLine:
    """One body of the live legend."""

    name: str
    kind: str  # "sensor" or "query"
    colour: tuple[int, int, int]
    covariance: np.ndarray | None
    stale_s: float | None = None  # time without data (None: live)
    grey_after_s: float | None = None  # how long without data it was when first drawn grey


def live_legend(
    bodies: list[BodyLine],
    style: Style,
    grid: GridSpec | None,
    anchor: str,
    offset_s: float,
) -> str:
    """The live view's legend: every body with its state and current errors."""
    lines = [f"drawn in frame **{anchor}**"]
    for b in bodies:
        hexc = "#{:02x}{:02x}{:02x}".format(*b.colour)
        head = f'- <span style="color:{hexc}">&#9679;</span> **{b.name}** ({b.kind})'
        if b.stale_s is not None:
            grey = "" if b.grey_after_s is None else f", grey after {b.grey_after_s:.2f} s"
            lines.append(f"{head}: grey, no data for {b.stale_s:.1f} s{grey}")
        elif b.covariance is None:
            lines.append(f"{head}: no data yet")
        else:
            pos, ori = sigma_sizes(b.covariance, style.sigma)
            lines.append(f"{head}: {_mm(pos)}, {ori:.3g} deg")
    if offset_s > 0:
        lines.append(
            f"- wireframe and short axes: queries predicted +{offset_s * 1e3:.0f} ms, drawn "
            f"**x{style.ghost_magnify:g}**"
        )
    return "\n".join(lines + _common(style, grid))
