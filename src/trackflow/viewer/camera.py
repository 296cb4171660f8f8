"""The browser camera as a pinhole: projection, framing of a body, screen-to-world offsets.

Pure geometry (no viser here). Cameras follow viser's convention for the pose a client reports:
``T_world_camera`` with OpenCV axes (x right, y down, z along the view direction), a vertical
field of view and the canvas size in pixels. The view's world is Z-up
(``docs/conventions.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..math import quat_to_matrix

__all__ = [
    "DEFAULT_FOV",
    "FRAMING_FOV",
    "VIEW_DIRECTION",
    "Camera",
    "body_glyph_points",
    "frame_points",
]

#: three.js's default vertical field of view (viser's initial camera) [rad].
DEFAULT_FOV = np.radians(75.0)
#: The views' initial vertical field of view [rad]: a longer lens, little distortion close up.
FRAMING_FOV = np.radians(45.0)
#: Direction from the framed point back to the camera (seen from above, front right).
VIEW_DIRECTION = np.array([1.0, -1.2, 0.8]) / np.linalg.norm([1.0, -1.2, 0.8])
#: Canvas size assumed before a browser has reported its own (the snapshot's default).
DEFAULT_CANVAS = (1280, 800)


@dataclass(frozen=True)
class Camera:
    """A pinhole camera of the page.

    Attributes
    ----------
    position : ndarray (3,)
        Camera centre in the world [m].
    rotation : ndarray (3, 3)
        ``R_world_camera``, OpenCV axes as columns (x right, y down, z forward).
    fov : float
        Vertical field of view [rad].
    width, height : int
        Canvas size [CSS px].
    """

    position: np.ndarray
    rotation: np.ndarray
    fov: float = float(DEFAULT_FOV)
    width: int = DEFAULT_CANVAS[0]
    height: int = DEFAULT_CANVAS[1]

    @classmethod
    def looking_at(
        cls, position, target, up=(0.0, 0.0, 1.0), fov=DEFAULT_FOV, width=None, height=None
    ) -> Camera:
        """The camera at ``position`` looking at ``target`` with ``up`` above it.

        Raises
        ------
        InputError
            If ``target`` equals ``position`` or the view direction is parallel to ``up``.
        """
        p, t = np.asarray(position, float), np.asarray(target, float)
        z = t - p
        n = np.linalg.norm(z)
        if not n > 0:
            raise InputError("a camera cannot look at its own position")
        z /= n
        x = np.cross(z, np.asarray(up, float))
        if not np.linalg.norm(x) > 1e-9:
            raise InputError("the camera's view direction is parallel to its up direction")
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        return cls(
            p, np.stack([x, y, z], axis=1), float(fov),
            int(width or DEFAULT_CANVAS[0]), int(height or DEFAULT_CANVAS[1]),
        )  # fmt: skip

    @classmethod
    def from_client(cls, camera) -> Camera:
        """The camera a browser reported (a viser ``CameraHandle``: ``wxyz``, ``position``,
        ``fov``, ``image_width``, ``image_height``)."""
        w, x, y, z = (float(v) for v in camera.wxyz)
        rot = quat_to_matrix(np.array([x, y, z, w]))
        return cls(
            np.asarray(camera.position, float), rot, float(camera.fov),
            int(camera.image_width), int(camera.image_height),
        )  # fmt: skip

    @property
    def focal(self) -> float:
        """Focal length [px]."""
        return 0.5 * self.height / np.tan(0.5 * self.fov)

    def project(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (N, 2) (origin top left, y down) and depths (N,) [m] of world
        points (N, 3); points behind the camera have depth <= 0."""
        p = np.atleast_2d(np.asarray(points, float))
        c = (p - self.position) @ self.rotation  # camera coordinates
        z = c[:, 2]
        safe = np.where(np.abs(z) > 1e-12, z, 1e-12)
        f = self.focal
        uv = np.stack([f * c[:, 0] / safe + 0.5 * self.width,
                       f * c[:, 1] / safe + 0.5 * self.height], axis=1)  # fmt: skip
        return uv, z

    def on_plane(self, u: float, v: float, z: float) -> np.ndarray | None:
        """Where the ray through pixel ``(u, v)`` meets the horizontal plane at height ``z``
        (3,), or None if it does not (it points up, or the plane is behind)."""
        d = self.rotation @ np.array([(u - 0.5 * self.width) / self.focal,
                                      (v - 0.5 * self.height) / self.focal, 1.0])  # fmt: skip
        if d[2] > -1e-9:
            return None
        t = (z - self.position[2]) / d[2]
        return self.position + t * d if t > 0 else None

    def world_offset(self, depth: float, dx_px: float, dy_px: float) -> np.ndarray:
        """The world displacement (3,) that moves a point at ``depth`` by ``(dx, dy)``
        pixels on screen (x right, y down)."""
        s = float(depth) / self.focal
        return s * (dx_px * self.rotation[:, 0] + dy_px * self.rotation[:, 1])


def body_glyph_points(position, quaternion, length: float) -> np.ndarray:
    """Points bounding a body's drawn glyph (4, 3): its position and its three axis tips."""
    r = quat_to_matrix(np.asarray(quaternion, float))
    p = np.asarray(position, float)
    return np.vstack([p, p + length * r.T])


def frame_points(
    points,
    coverage: float = 0.14,
    direction=VIEW_DIRECTION,
    fov: float = float(FRAMING_FOV),
    canvas: tuple[int, int] = DEFAULT_CANVAS,
    shift: float = 0.3,
    centre=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Camera ``(position, look_at)`` viewing ``points`` from ``direction`` so that their
    screen bounding box covers ``coverage`` of the canvas.

    Parameters
    ----------
    points : array_like (N, 3)
        What is framed (e.g. :func:`body_glyph_points`).
    coverage : float
        Fraction of the canvas area their bounding box covers (less if they would not fit
        into the canvas around ``centre`` otherwise).
    direction : array_like (3,)
        From the points back to the camera.
    fov, canvas
        The camera's vertical field of view [rad] and canvas size [px] assumed.
    shift : float
        ``centre`` is drawn this fraction of the half-width left of the canvas's centre (the
        control panel covers the right of the page).
    centre : array_like (3,), optional
        The point the camera aims at (default: the centre of the points' bounding box).

    Returns
    -------
    position, look_at : ndarray (3,)
    """
    pts = np.atleast_2d(np.asarray(points, float))
    if centre is None:
        centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    centre = np.asarray(centre, float)
    back = np.asarray(direction, float) / np.linalg.norm(direction)
    w, h = canvas
    half = 0.5 * np.array([w, h], float)

    def aimed(dist: float) -> tuple[np.ndarray, np.ndarray]:
        # aim right of the centre: ``centre`` appears ``shift`` of the half-width left of it
        cam = Camera.looking_at(centre + dist * back, centre, fov=fov, width=w, height=h)
        offset = cam.world_offset(dist, shift * half[0], 0.0)
        return centre + dist * back + offset, centre + offset

    dist = max(float(np.max(np.linalg.norm(pts - centre, axis=1))), 1e-3) * 3.0
    for _ in range(6):  # the box's area goes with about 1 / distance^2: a few refinements
        cam = Camera.looking_at(*aimed(dist), fov=fov, width=w, height=h)
        uv, depth = cam.project(pts)
        if np.any(depth <= 0.05 * dist):
            dist *= 2.0
            continue
        span = np.maximum(uv.max(axis=0) - uv.min(axis=0), 1.0)
        scale = np.sqrt(float(span[0] * span[1]) / (w * h) / coverage)  # > 1: move back
        # every point inside the canvas, at least 7.5 % of its size from the edges
        reach = np.max(np.abs(uv - half) / (0.85 * half))
        dist *= max(scale, float(reach)) if reach > 1 else scale
    return aimed(dist)
