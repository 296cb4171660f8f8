"""The spatial relationship graph as an SVG panel, every edge coloured by its live state.

Pure functions from edge states to HTML (no viser here), so they are tested without a browser.
"""

from __future__ import annotations

import html
import math
from dataclasses import dataclass, field

__all__ = ["COLOURS", "PULL_REFUSALS", "EdgeStatus", "classify", "render_panel", "split_counts"]

#: Edge state -> stroke colour. "no path" is a query the planner found no path for.
COLOURS = {
    "live": "#1a9e3a",
    "stale": "#d62728",
    "gated": "#ff8c00",
    "static": "#1f5fbf",
    "unused": "#9e9e9e",
    "no path": "#b000b0",
}


#: Reasons a filter gives for not answering a pull (the query asked past the sensor's data);
#: the panel counts them apart from the measurements it rejected.
PULL_REFUSALS = frozenset(
    {"stale", "no data yet", "before first measurement", "before history", "no result"}
)


def split_counts(rejections: dict[str, int]) -> tuple[dict[str, int], dict[str, int]]:
    """``(rejected measurements, refused pulls)`` of an edge's counted reasons."""
    rejected = {k: v for k, v in rejections.items() if k not in PULL_REFUSALS}
    pulls = {k: v for k, v in rejections.items() if k in PULL_REFUSALS}
    return rejected, pulls


@dataclass
class EdgeStatus:
    """What the panel shows for one edge (or one unanswerable query).

    Attributes
    ----------
    name, source, target : str
        Edge name and frames (``T_source_target``).
    state : str
        A key of :data:`COLOURS`.
    rate_hz, latency_ms, offset_ms : float
        Measured update rate, median delivery latency (network clock minus sensor stamp) and
        the sensor's known timestamp offset (NaN: not applicable).
    rejections : dict
        Counted rejections by reason (source and filter), refused pulls
        (:data:`PULL_REFUSALS`) included: the panel shows the two apart.
    on_path : bool
        Part of the selected query's planned path (drawn highlighted).
    """

    name: str
    source: str
    target: str
    state: str
    rate_hz: float = math.nan
    latency_ms: float = math.nan
    offset_ms: float = math.nan
    rejections: dict = field(default_factory=dict)
    on_path: bool = False


def classify(
    *,
    static: bool,
    used: bool,
    age_s: float | None,
    rate_hz: float,
    gated_recently: bool,
    stale_periods: float = 3.0,
    stale_min_s: float = 0.25,
) -> str:
    """State of an edge: static, unused, stale (no event for ``stale_periods`` periods and at
    least ``stale_min_s``, or never), gated (the filter rejected updates lately) or live."""
    if static:
        return "static"
    if not used:
        return "unused"
    limit = max(stale_periods / rate_hz if rate_hz > 0 else math.inf, stale_min_s)
    if age_s is None or age_s > limit:
        return "stale"
    return "gated" if gated_recently else "live"


def _fmt(v: float, unit: str, digits: int = 1) -> str:
    return "-" if not math.isfinite(v) else f"{v:.{digits}f} {unit}"


def _layout(frames: list[str], w: float, h: float) -> dict[str, tuple[float, float]]:
    n = max(len(frames), 1)
    r = min(w, h) * 0.36
    return {
        f: (w / 2 + r * math.cos(2 * math.pi * i / n - math.pi / 2),
            h / 2 + r * math.sin(2 * math.pi * i / n - math.pi / 2))
        for i, f in enumerate(frames)
    }  # fmt: skip


def render_panel(frames: list[str], edges: list[EdgeStatus], width: int = 300) -> str:
    """HTML of the graph (SVG: frames on a circle, edges as coloured arrows, the selected
    query's path drawn thick) followed by a table of each edge's figures."""
    w, h = float(width), float(width) * 0.8
    pos = _layout(frames, w, h)
    out = [
        f'<svg width="{w:.0f}" height="{h:.0f}" viewBox="0 0 {w:.0f} {h:.0f}" '
        'xmlns="http://www.w3.org/2000/svg" style="background:#fff">',
        '<defs><marker id="tfa" viewBox="0 0 10 10" refX="9" refY="5" markerWidth="12" '
        'markerHeight="12" markerUnits="userSpaceOnUse" orient="auto">'
        '<path d="M0,0 L10,5 L0,10 z" fill="#444"/></marker></defs>',
    ]
    pair_count: dict[tuple[str, str], int] = {}
    for e in edges:
        if e.source not in pos or e.target not in pos:
            continue
        (x1, y1), (x2, y2) = pos[e.source], pos[e.target]
        key = tuple(sorted((e.source, e.target)))
        k = pair_count.get(key, 0)
        pair_count[key] = k + 1
        # parallel edges bend apart
        mx, my = (x1 + x2) / 2, (y1 + y2) / 2
        dx, dy = x2 - x1, y2 - y1
        norm = math.hypot(dx, dy) or 1.0
        bend = (k - 0.0) * 22.0 * (1 if k % 2 else -1) if k else 0.0
        cx, cy = mx - dy / norm * bend, my + dx / norm * bend
        # stop the arrow at the node circle
        ex, ey = x2 - dx / norm * 14, y2 - dy / norm * 14
        colour = COLOURS.get(e.state, "#000")
        dash = ' stroke-dasharray="6,4"' if e.state in ("unused", "no path") else ""
        if e.on_path:
            out.append(
                f'<path d="M{x1:.1f},{y1:.1f} Q{cx:.1f},{cy:.1f} {ex:.1f},{ey:.1f}" '
                'stroke="#ffe14d" stroke-width="14" fill="none" stroke-linecap="round"/>'
            )
        out.append(
            f'<path d="M{x1:.1f},{y1:.1f} Q{cx:.1f},{cy:.1f} {ex:.1f},{ey:.1f}" '
            f'stroke="{colour}" stroke-width="6" fill="none"{dash} marker-end="url(#tfa)">'
            f"<title>{html.escape(e.name)}: {e.state}</title></path>"
        )
        out.append(
            f'<text x="{cx:.1f}" y="{cy - 6:.1f}" font-size="11" text-anchor="middle" '
            f'fill="#222">{html.escape(e.name)}</text>'
        )
    for f, (x, y) in pos.items():
        out.append(
            f'<circle cx="{x:.1f}" cy="{y:.1f}" r="13" fill="#f4f4f4" stroke="#333"/>'
            f'<text x="{x:.1f}" y="{y + 4:.1f}" font-size="12" text-anchor="middle">'
            f"{html.escape(f)}</text>"
        )
    out.append("</svg>")
    rows = [
        '<table style="font-size:11px;border-collapse:collapse;width:100%">'
        "<tr><th align=left>edge</th><th>state</th><th>rate</th><th>latency</th>"
        "<th>offset</th><th>rejected</th><th>stale pulls</th></tr>"
    ]
    for e in edges:
        rejected, pulls = split_counts(e.rejections)
        why = html.escape(", ".join(f"{k}: {v}" for k, v in sorted(rejected.items())))
        pull_why = html.escape(", ".join(f"{k}: {v}" for k, v in sorted(pulls.items())))
        rows.append(
            f"<tr><td>{'&#9654; ' if e.on_path else ''}{html.escape(e.name)}</td>"
            f'<td style="color:{COLOURS.get(e.state, "#000")}">{e.state}</td>'
            f"<td>{_fmt(e.rate_hz, 'Hz', 0)}</td><td>{_fmt(e.latency_ms, 'ms')}</td>"
            f'<td>{_fmt(e.offset_ms, "ms")}</td><td title="{why}">{sum(rejected.values())}</td>'
            f'<td title="{pull_why}">{sum(pulls.values())}</td></tr>'
        )
    rows.append("</table>")
    legend = " ".join(f'<span style="color:{c}">&#9632; {s}</span>' for s, c in COLOURS.items())
    return "".join(out) + f'<div style="font-size:11px">{legend}</div>' + "".join(rows)
