"""Scene labels that do not overlap: screen boxes from the camera, a greedy layout, and the
viser label nodes that show it.

viser draws a screen-sized label (``font_size_mode="screen"``) with a 12 px em (times its
``font_screen_scale``) on a white box padded by a fifth of the line height, whatever the
canvas size. The layout estimates each box from the text (a generous average advance per
character), projects each label's anchor with the camera the browser reported and moves
labels that would overlap an already placed one up or down, in label heights, until they do
not. Frame labels (``frame W``, smaller) and body labels (the sensor's or query's name) read
differently; the legend says which is which.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .camera import Camera

__all__ = ["EM_PX", "LabelLayer", "LabelSpec", "box_size", "layout_labels", "overlaps"]

#: viser's em of a screen-sized label at ``font_screen_scale=1`` [CSS px].
EM_PX = 12.0
#: Average advance of a character [em], generous (wide sans fonts stay inside it).
CHAR_EM = 0.66
#: Line height [em] and the box's padding (a fifth of the line height, both sides together).
LINE_EM = 1.2
PAD = 0.2
#: Scale of frame labels (smaller than body labels).
FRAME_SCALE = 0.85
#: Gap kept between two boxes [px].
GAP_PX = 2.0


@dataclass
class LabelSpec:
    """One label to place.

    Attributes
    ----------
    key : str
        Stable identity (the node's name).
    text : str
    anchor : ndarray (3,)
        The world point it labels.
    kind : str
        ``"body"`` (above its point), ``"frame"`` (below it, smaller) or ``"note"``.
    visible : bool
    """

    key: str
    text: str
    anchor: np.ndarray
    kind: str = "body"
    visible: bool = True

    @property
    def scale(self) -> float:
        return FRAME_SCALE if self.kind == "frame" else 1.0


def box_size(text: str, scale: float = 1.0) -> tuple[float, float]:
    """Estimated width and height [px] of a label's box (text plus padding)."""
    em = EM_PX * scale
    lines = text.split("\n")
    width = max(len(line) for line in lines) * CHAR_EM * em
    height = len(lines) * LINE_EM * em
    pad = PAD * LINE_EM * em
    return width + pad, height + pad


def overlaps(a, b, gap: float = 0.0) -> bool:
    """Whether two boxes ``(x0, y0, x1, y1)`` overlap (closer than ``gap``)."""
    return a[0] < b[2] + gap and b[0] < a[2] + gap and a[1] < b[3] + gap and b[1] < a[3] + gap


@dataclass
class Placement:
    """Where a label went: its box on screen ``(x0, y0, x1, y1)`` [px] and world position."""

    box: tuple[float, float, float, float]
    position: np.ndarray


def layout_labels(specs: list[LabelSpec], camera: Camera) -> dict[str, Placement]:
    """Place the visible labels of ``specs`` (in order of priority) without overlaps.

    A body label sits just above its point, a frame label just below; a label whose box
    would overlap one already placed is moved by whole box heights (down, up, further down,
    ...) until it is free (after 12 tries it keeps its best try). Labels behind the camera are
    left out.

    Returns
    -------
    dict key -> Placement
    """
    placed: dict[str, Placement] = {}
    boxes: list[tuple[float, float, float, float]] = []
    for s in specs:
        if not s.visible:
            continue
        uv, depth = camera.project(s.anchor)
        if depth[0] <= 1e-6:
            continue
        w, h = box_size(s.text, s.scale)
        u, v = uv[0]
        lift = 0.6 * h + 4.0
        base = v + lift if s.kind == "frame" else v - lift
        step = h + GAP_PX
        best = None
        for k in range(13):
            off = 0.0 if k == 0 else step * ((k + 1) // 2) * (1 if k % 2 else -1)
            if s.kind == "frame":
                off = -off  # a frame label tries upwards first
            cy = base + off
            box = (u - w / 2, cy - h / 2, u + w / 2, cy + h / 2)
            hits = sum(overlaps(box, b, GAP_PX) for b in boxes)
            if best is None or hits < best[0]:
                best = (hits, box, cy)
            if hits == 0:
                break
        _, box, cy = best
        boxes.append(box)
        pos = np.asarray(s.anchor, float) + camera.world_offset(depth[0], 0.0, cy - v)
        placed[s.key] = Placement(box, pos)
    return placed


@dataclass
class LabelLayer:
    """viser label nodes under ``path``, one per key, placed by :func:`layout_labels`.

    Attributes
    ----------
    placed : dict key -> Placement
        The last layout (what :meth:`report` returns with the texts).
    """

    scene: object
    path: str
    handles: dict = field(default_factory=dict)
    texts: dict = field(default_factory=dict)
    placed: dict = field(default_factory=dict)
    camera: Camera | None = None
    shown: bool = True

    def update(self, specs: list[LabelSpec], camera: Camera) -> None:
        """Lay out ``specs`` for ``camera`` and move the nodes there."""
        self.camera = camera
        self.placed = layout_labels(specs, camera) if self.shown else {}
        for s in specs:
            h = self.handles.get(s.key)
            if h is None:
                h = self.scene.add_label(
                    f"{self.path}/{s.key}", s.text, font_screen_scale=s.scale,
                    anchor="center-center", visible=False,
                )  # fmt: skip
                self.handles[s.key] = h
                self.texts[s.key] = s.text
            elif self.texts[s.key] != s.text:
                h.text = s.text
                self.texts[s.key] = s.text
            p = self.placed.get(s.key)
            if p is not None:
                h.position = p.position
            if h.visible != (p is not None):
                h.visible = p is not None

    def report(self) -> dict:
        """The shown labels and the camera they were placed for (plain data, picklable):
        ``{"labels": [{key, text, scale, position}], "camera": {...}}``."""
        cam = self.camera
        return {
            "labels": [
                {
                    "key": k,
                    "text": self.texts[k],
                    "position": p.position.tolist(),
                    "scale": float(self.handles[k].font_screen_scale),
                }  # fmt: skip
                for k, p in self.placed.items()
            ],
            "camera": None
            if cam is None
            else {
                "position": cam.position.tolist(),
                "rotation": cam.rotation.tolist(),
                "fov": cam.fov,
                "width": cam.width,
                "height": cam.height,
            },  # fmt: skip
        }
