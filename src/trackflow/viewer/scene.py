"""Drawing uncertain poses into a viser scene: axes, error ellipsoids, trail and prediction.

A :class:`PoseDrawing` owns the scene nodes of one relationship ``T_a_b`` drawn under the node
of frame a: the pose as axes with a small wireframe body marker (it never hides the position
error ellipsoid inside it), its position error ellipsoid, the three axis ellipsoids of its
orientation error (thesis 8.2.2.1), a trail fading into the background, the whole path as a
faint line and, when a prediction offset is set, a second (ghost) pose with its own ellipsoid
at the predicted time, magnified on its own scale (:attr:`Style.ghost_magnify`). Positions
are metres in frame a; rotations are handed to viser as ``(w, x, y, z)`` (the conversion
lives in :mod:`trackflow.viewer.glyphs`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..math import UncertainPose
from .decor import faint, path_segments
from .glyphs import Ellipsoid, orientation_glyphs, position_glyph, to_wxyz

__all__ = ["GREY", "PALETTE", "PoseDrawing", "Style", "frame_node"]

#: Body colours (RGB 0-255), chosen away from the pure red/green/blue of axes.
PALETTE = (
    (230, 0, 230),  # magenta
    (255, 140, 0),  # orange
    (0, 170, 200),  # teal
    (140, 80, 220),  # violet
    (200, 160, 0),  # ochre
    (0, 120, 90),  # dark green-teal
    (220, 60, 110),  # raspberry
    (90, 90, 90),  # grey
)
_AXIS_COLOURS = ((220, 40, 40), (40, 180, 40), (40, 80, 230))
#: Colour of a body whose data stopped (a stale or down sensor, an unanswered query).
GREY = (150, 150, 150)
#: Radius of the wireframe body marker and length of the ghost's axes [axes lengths].
MARKER_RADIUS = 0.1
GHOST_AXES = 0.6
#: Width of the fading trail on screen [px].
TRAIL_PX = 3.0


@dataclass
class Style:
    """How poses are drawn (changed live by the controls).

    Attributes
    ----------
    sigma : float
        Sigma level of every ellipsoid (1, 2 or 3).
    magnify : float
        Ellipsoid semi-axes are drawn ``magnify`` times their size (sub-millimetre errors are
        invisible at room scale); 1 draws them true to scale. The page says which.
    ghost_magnify : float
        The same for the prediction ghost's ellipsoid, on its own scale: a prediction's error
        is centimetres where the filter's is a fraction of a millimetre.
    axes_length : float
        Length of a pose's axes and of the axis-ellipsoid lever [m].
    opacity : float or None
        Opacity of the error ellipsoids (None: opaque).
    show_orientation : bool
        Draw the axis ellipsoids.
    trail_s : float
        Length of the fading trail [s].
    show_trail, show_path : bool
        Draw the fading trail; the whole path as a faint line.
    """

    sigma: float = 1.0
    magnify: float = 1.0
    ghost_magnify: float = 1.0
    axes_length: float = 0.1
    opacity: float | None = 0.45
    show_orientation: bool = True
    trail_s: float = 2.0
    show_trail: bool = True
    show_path: bool = True


def frame_node(scene, path: str, axes_length: float = 0.15):
    """A frame of the SRG as axes at scene path ``path`` (its label is laid out with the
    others: :mod:`trackflow.viewer.labels`)."""
    return scene.add_frame(path, axes_length=axes_length, axes_radius=axes_length * 0.04)


def _scaled(e: Ellipsoid, magnify: float) -> tuple[float, float, float]:
    s = np.maximum(np.asarray(e.scale) * magnify, 1e-5)
    return float(s[0]), float(s[1]), float(s[2])


class PoseDrawing:
    """The scene nodes of one uncertain pose ``T_a_b`` under the node of frame a.

    Parameters
    ----------
    scene : viser.SceneApi
    path : str
        Scene path of the drawing (under the parent frame's path, e.g. ``/world/P/q_view``).
    color : tuple of int
        RGB 0-255 of the body marker, ellipsoid and trail.
    style : Style
        Shared drawing options (read on every :meth:`update`).
    """

    def __init__(self, scene, path: str, color, style: Style):
        self.scene, self.path, self.color, self.style = scene, path, tuple(color), style
        L = style.axes_length
        self.axes = scene.add_frame(
            f"{path}/pose", axes_length=L, axes_radius=L * 0.03, origin_radius=L * 0.005
        )
        self.marker = scene.add_icosphere(
            f"{path}/pose/marker", radius=L * MARKER_RADIUS, color=self.color,
            subdivisions=0, wireframe=True,
        )  # fmt: skip
        self.ellipsoid = scene.add_icosphere(
            f"{path}/position_error", radius=1.0, color=self.color, opacity=style.opacity,
            subdivisions=3, visible=False,
        )  # fmt: skip
        self.tips = [
            scene.add_icosphere(
                f"{path}/orientation_error_{k}",
                radius=1.0,
                color=c,
                opacity=style.opacity,
                subdivisions=2,
                visible=False,
            )  # fmt: skip
            for k, c in enumerate(_AXIS_COLOURS)
        ]
        self.ghost = scene.add_frame(
            f"{path}/predicted", axes_length=L * GHOST_AXES, axes_radius=L * 0.02,
            origin_radius=L * 0.005, visible=False,
        )  # fmt: skip
        self.ghost_ellipsoid = scene.add_icosphere(
            f"{path}/predicted_error", radius=1.0, color=self.color, opacity=0.2,
            wireframe=True, subdivisions=2, visible=False,
        )  # fmt: skip
        self.trail = None
        self.path_line = None
        self._pos: Ellipsoid | None = None
        self._tips: tuple[Ellipsoid, ...] | None = None

    def set_visible(self, visible: bool) -> None:
        """Show or hide the whole drawing."""
        for h in (self.axes, self.ellipsoid, *self.tips, self.ghost, self.ghost_ellipsoid):
            h.visible = visible
        if self.trail is not None:
            self.trail.visible = visible and self.style.show_trail
        if self.path_line is not None:
            self.path_line.visible = visible and self.style.show_path

    def set_path(self, points: np.ndarray) -> None:
        """Draw the whole path (positions in frame a, (N, 3), NaN rows break it) as a faint
        line in the body's colour."""
        seg = path_segments(points).astype(np.float32)
        if len(seg) == 0:
            return
        if self.path_line is not None:
            self.path_line.remove()
        self.path_line = self.scene.add_line_segments(
            f"{self.path}/path", seg, faint(self.color, 0.7), thickness=1.5,
            thickness_units="screen", visible=self.style.show_path,
        )  # fmt: skip

    def update(
        self,
        pose: UncertainPose,
        predicted: UncertainPose | None = None,
        trail: np.ndarray | None = None,
    ) -> None:
        """Draw ``pose`` (``T_a_b``), the optional ``predicted`` pose and the ``trail``
        (positions in frame a, oldest first, shape (N, 3))."""
        st = self.style
        self.axes.position = np.asarray(pose.position, float)
        self.axes.wxyz = to_wxyz(pose.quaternion)
        self._pos = position_glyph(pose, st.sigma, self._pos)
        e = self._pos
        self.ellipsoid.position, self.ellipsoid.wxyz = e.center, e.wxyz
        self.ellipsoid.scale = _scaled(e, st.magnify)
        self.ellipsoid.visible = True
        if st.show_orientation:
            self._tips = orientation_glyphs(pose, st.sigma, st.axes_length, self._tips)
            for h, t in zip(self.tips, self._tips):
                h.position, h.wxyz, h.scale = t.center, t.wxyz, _scaled(t, st.magnify)
                h.visible = True
        else:
            for h in self.tips:
                h.visible = False
        if predicted is not None:
            self.ghost.position = np.asarray(predicted.position, float)
            self.ghost.wxyz = to_wxyz(predicted.quaternion)
            g = position_glyph(predicted, st.sigma)
            self.ghost_ellipsoid.position, self.ghost_ellipsoid.wxyz = g.center, g.wxyz
            self.ghost_ellipsoid.scale = _scaled(g, st.ghost_magnify)
        self.ghost.visible = self.ghost_ellipsoid.visible = predicted is not None
        if trail is not None and len(trail) >= 2:
            self._draw_trail(np.asarray(trail, float))
        if self.trail is not None:
            self.trail.visible = st.show_trail
        if self.path_line is not None:
            self.path_line.visible = st.show_path

    def _draw_trail(self, pts: np.ndarray) -> None:
        seg = np.stack([pts[:-1], pts[1:]], axis=1)  # (N-1, 2, 3)
        # fade from the background (white) at the oldest end to the body colour
        a = np.linspace(0.0, 1.0, len(pts))
        rgb = 255.0 + a[:, None] * (np.asarray(self.color, float) - 255.0)
        cols = np.stack([rgb[:-1], rgb[1:]], axis=1).astype(np.uint8)
        if self.trail is None:
            self.trail = self.scene.add_line_segments(
                f"{self.path}/trail", seg, cols, thickness=TRAIL_PX, thickness_units="screen"
            )
        else:
            self.trail.points, self.trail.colors = seg, cols
