"""Many uncertain poses drawn as a handful of batched (instanced) scene nodes.

With 20 bodies a node per glyph costs hundreds of scene messages per view frame; here every
kind of glyph is one instanced node - all pose axes, all body markers, all position
ellipsoids, all orientation (axis) ellipsoids, all prediction ghosts - and a frame is a few
array updates. Poses come in the world (root) frame; the number of instances is fixed at
construction (a hidden body is drawn with zero size), so the arrays never change length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..math import ellipsoid, quat_from_matrix, quat_to_matrix, skew
from .decor import faint, path_segments
from .glyphs import stable_axes, to_wxyz
from .scene import GHOST_AXES, MARKER_RADIUS, TRAIL_PX, Style

__all__ = ["HIDDEN", "BatchDrawing", "BodyFrame", "icosphere"]

_AXIS_RGB = np.array([(220, 40, 40), (40, 180, 40), (40, 80, 230)], dtype=np.uint8)
#: Scale of a hidden instance (instanced nodes keep their length).
HIDDEN = 1e-9


def icosphere(subdivisions: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Unit sphere mesh: vertices (V, 3) float32, faces (F, 3) uint32."""
    t = (1.0 + 5**0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
         (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]  # fmt: skip
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
         (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]  # fmt: skip
    verts = [np.array(p, float) / np.linalg.norm(p) for p in v]
    for _ in range(subdivisions):
        cache: dict[tuple[int, int], int] = {}

        def mid(a: int, b: int, cache=cache) -> int:
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]

        f = [
            tri
            for a, b, c in f
            for tri in ((a, mid(a, b), mid(c, a)), (b, mid(b, c), mid(a, b)),
                        (c, mid(c, a), mid(b, c)), (mid(a, b), mid(b, c), mid(c, a)))
        ]  # fmt: skip
    return np.array(verts, np.float32), np.array(f, np.uint32)


@dataclass
class BodyFrame:
    """One body to draw this frame, everything in the world frame.

    Attributes
    ----------
    position : ndarray (3,)
    quaternion : ndarray (4,)
        ``(x, y, z, w)``.
    covariance : ndarray (6, 6)
        Over ``(dt [m, world], dtheta [rad, body])``.
    predicted : tuple (position, quaternion, covariance) or None
    """

    position: np.ndarray
    quaternion: np.ndarray
    covariance: np.ndarray
    predicted: tuple | None = None


def _ellipsoids(covs: np.ndarray, sigma: float, previous: np.ndarray | None):
    """Batched semi-axes (N, 3) and right-handed axes (N, 3, 3) following ``previous``."""
    radii, axes = ellipsoid(covs, sigma)
    return stable_axes(radii, axes, previous)


class BatchDrawing:
    """Instanced glyphs of ``n`` bodies under scene path ``path`` (see module docstring).

    Parameters
    ----------
    scene : viser.SceneApi
    path : str
    colors : array_like (n, 3)
        RGB 0-255 per body.
    style : Style
        Shared options, read on every :meth:`update`.
    """

    def __init__(self, scene, path: str, colors, style: Style):
        self.scene, self.path, self.style = scene, path, style
        self.colors = np.asarray(colors, np.uint8).reshape(-1, 3)
        n = self.n = len(self.colors)
        verts, faces = icosphere(2)
        zeros3, ident = np.zeros((n, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
        tiny = np.full((n, 3), HIDDEN)
        L = style.axes_length
        self.axes = scene.add_batched_axes(
            f"{path}/axes", ident, zeros3, np.full(n, HIDDEN),
            axes_length=L, axes_radius=L * 0.03,
        )  # fmt: skip
        v0, f0 = icosphere(0)  # a wire icosahedron: it hides no ellipsoid inside it
        self.markers = scene.add_batched_meshes_simple(
            f"{path}/markers", v0, f0, ident, zeros3,
            batched_scales=tiny, batched_colors=self.colors, lod="off", wireframe=True,
        )  # fmt: skip
        self.pos_err = scene.add_batched_meshes_simple(
            f"{path}/position_error", verts, faces, ident, zeros3, batched_scales=tiny,
            batched_colors=self.colors, opacity=style.opacity, lod="off",
        )  # fmt: skip
        self.ori_err = scene.add_batched_meshes_simple(
            f"{path}/orientation_error", verts, faces, np.tile(ident, (3, 1)),
            np.zeros((3 * n, 3)), batched_scales=np.full((3 * n, 3), HIDDEN),
            batched_colors=np.tile(_AXIS_RGB, (n, 1)), opacity=style.opacity, lod="off",
        )  # fmt: skip
        self.ghost_axes = scene.add_batched_axes(
            f"{path}/predicted_axes", ident, zeros3, np.full(n, HIDDEN),
            axes_length=L * GHOST_AXES, axes_radius=L * 0.02,
        )  # fmt: skip
        self.ghost_err = scene.add_batched_meshes_simple(
            f"{path}/predicted_error", verts, faces, ident, zeros3, batched_scales=tiny,
            batched_colors=self.colors, opacity=0.25, wireframe=True, lod="off",
        )  # fmt: skip
        self.trails = None
        self.paths = None
        self.shown_colors = self.colors.copy()  # the colours drawn (grey: no data)
        self._fades: dict[tuple, np.ndarray] = {}
        self._prev_pos: np.ndarray | None = None
        self._prev_tip: np.ndarray | None = None

    def set_colors(self, colors) -> None:
        """Draw the bodies in ``colors`` (n, 3) from now on (grey for a body without data)."""
        c = np.asarray(colors, np.uint8).reshape(-1, 3)
        if np.array_equal(c, self.shown_colors):
            return
        self.shown_colors = c
        self.markers.batched_colors = c
        self.pos_err.batched_colors = c
        self.ghost_err.batched_colors = c

    def update(self, bodies: list[BodyFrame | None], trails: list[np.ndarray | None]) -> None:
        """Draw ``bodies`` (``None``: hidden) and their trails (world positions, oldest first)."""
        st, n = self.style, self.n
        shown = np.array([b is not None for b in bodies], bool)
        pos = np.zeros((n, 3))
        quat = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
        cov = np.tile(np.eye(6) * 1e-12, (n, 1, 1))
        for i, b in enumerate(bodies):
            if b is not None:
                pos[i], quat[i], cov[i] = b.position, b.quaternion, b.covariance
        wxyz = to_wxyz(quat)
        L = st.axes_length
        self.axes.batched_positions, self.axes.batched_wxyzs = pos, wxyz
        self.axes.batched_scales = np.where(shown, 1.0, HIDDEN)
        self.markers.batched_positions, self.markers.batched_wxyzs = pos, wxyz
        self.markers.batched_scales = np.where(shown[:, None], L * MARKER_RADIUS, HIDDEN) * np.ones(
            3
        )
        radii, axes = _ellipsoids(cov[:, :3, :3], st.sigma, self._prev_pos)
        self._prev_pos = axes
        self.pos_err.batched_positions = pos
        self.pos_err.batched_wxyzs = to_wxyz(quat_from_matrix(axes))
        self.pos_err.batched_scales = self._scales(radii, shown)
        if st.show_orientation:
            r = quat_to_matrix(quat)  # (n, 3, 3)
            c_rot = cov[:, 3:, 3:]
            tips, tip_cov = [], []
            for k in range(3):
                lever = np.zeros(3)
                lever[k] = L
                J = -r @ skew(lever)  # the tip displacement per rotation error (8.2.2.1)
                tip_cov.append(J @ c_rot @ np.swapaxes(J, -1, -2))
                tips.append(pos + L * r[:, :, k])
            tcov = np.stack(tip_cov, axis=1).reshape(3 * n, 3, 3)
            tr, ta = _ellipsoids(tcov, st.sigma, self._prev_tip)
            self._prev_tip = ta
            self.ori_err.batched_positions = np.stack(tips, axis=1).reshape(3 * n, 3)
            self.ori_err.batched_wxyzs = to_wxyz(quat_from_matrix(ta))
            self.ori_err.batched_scales = self._scales(tr, np.repeat(shown, 3))
        else:
            self.ori_err.batched_scales = np.full((3 * n, 3), HIDDEN)
        self._update_ghosts(bodies)
        self._update_trails(trails)

    def _scales(self, radii: np.ndarray, shown: np.ndarray, magnify: float | None = None):
        m = self.style.magnify if magnify is None else magnify
        s = np.maximum(radii * m, 1e-5)
        return np.where(shown[:, None], s, HIDDEN)

    def _update_ghosts(self, bodies) -> None:
        n = self.n
        has = np.array([b is not None and b.predicted is not None for b in bodies], bool)
        pos = np.zeros((n, 3))
        quat = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
        cov = np.tile(np.eye(3) * 1e-12, (n, 1, 1))
        for i, b in enumerate(bodies):
            if has[i]:
                p, q, c = b.predicted
                pos[i], quat[i], cov[i] = p, q, np.asarray(c)[:3, :3]
        self.ghost_axes.batched_positions = pos
        self.ghost_axes.batched_wxyzs = to_wxyz(quat)
        self.ghost_axes.batched_scales = np.where(has, 1.0, HIDDEN)
        radii, axes = _ellipsoids(cov, self.style.sigma, None)
        self.ghost_err.batched_positions = pos
        self.ghost_err.batched_wxyzs = to_wxyz(quat_from_matrix(axes))
        self.ghost_err.batched_scales = self._scales(radii, has, self.style.ghost_magnify)

    def _fade(self, i: int, n: int) -> np.ndarray:
        """Segment colours (n - 1, 2, 3) of body ``i``'s trail of ``n`` points: from the
        background (white) at the oldest end to the body colour (cached per length)."""
        colour = self.shown_colors[i]
        key = (i, n, *colour.tolist())
        if key not in self._fades:
            if len(self._fades) > 4 * self.n + 64:
                self._fades.clear()
            a = np.linspace(0.0, 1.0, n)
            rgb = 255.0 + a[:, None] * (colour.astype(float) - 255.0)
            self._fades[key] = np.stack([rgb[:-1], rgb[1:]], axis=1).astype(np.uint8)
        return self._fades[key]

    def update_paths(self, paths: list[np.ndarray | None]) -> None:
        """Draw every body's whole path (world positions (N, 3)) as a faint line."""
        segs, cols = [], []
        for i, pts in enumerate(paths):
            if pts is None or len(pts) < 2:
                continue
            seg = path_segments(pts)
            segs.append(seg)
            cols.append(np.broadcast_to(np.array(faint(self.shown_colors[i], 0.7)), seg.shape))
        if not segs:
            return
        seg = np.concatenate(segs).astype(np.float32)
        col = np.concatenate(cols).astype(np.uint8)
        if self.paths is None:
            self.paths = self.scene.add_line_segments(
                f"{self.path}/paths", seg, col, thickness=1.5, thickness_units="screen",
                visible=self.style.show_path,
            )  # fmt: skip
        else:
            self.paths.points, self.paths.colors = seg, col
            self.paths.visible = self.style.show_path

    def _update_trails(self, trails) -> None:
        if self.trails is not None:
            self.trails.visible = self.style.show_trail
        segs, cols = [], []
        for i, pts in enumerate(trails):
            if pts is None or len(pts) < 2:
                continue
            pts = np.asarray(pts, float)
            segs.append(np.stack([pts[:-1], pts[1:]], axis=1))
            cols.append(self._fade(i, len(pts)))
        if not segs:
            return
        seg = np.concatenate(segs).astype(np.float32)
        col = np.concatenate(cols)
        if self.trails is None:
            self.trails = self.scene.add_line_segments(
                f"{self.path}/trails", seg, col, thickness=TRAIL_PX, thickness_units="screen"
            )
        else:
            self.trails.points, self.trails.colors = seg, col
