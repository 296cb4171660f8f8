"""Calibrated cameras: pinhole with OpenCV's radial/tangential distortion, and rigs of them.

A camera maps a world point ``X_world`` (metres) to a pixel ``(u, v)``:

    X_cam = R_cam_world X_world + t_cam_world          (OpenCV's rvec/tvec extrinsics)
    x, y  = X_cam[0] / X_cam[2], X_cam[1] / X_cam[2]
    r2    = x^2 + y^2
    a     = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3)
    x_d   = x a + 2 p1 x y + p2 (r2 + 2 x^2)
    y_d   = y a + p1 (r2 + 2 y^2) + 2 p2 x y
    u, v  = K [x_d, y_d, 1]

which is ``cv2.projectPoints`` with 4, 5 or 8 distortion coefficients
``(k1, k2, p1, p2[, k3[, k4, k5, k6]])``. Pixel centres are at integer coordinates, as in
OpenCV. In trackflow's pose convention the extrinsics are ``T_cam_world``;
:attr:`Camera.T_world_cam` is the camera's pose in the world.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..math import Pose, quat_from_matrix

__all__ = ["Camera", "CameraRig", "ring_rig"]

_N_DIST = (4, 5, 8)


def _as_matrix(value, shape, what: str) -> np.ndarray:
    a = np.asarray(value, dtype=float)
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise InputError(f"{what} must be a finite array of shape {shape}, got {a.shape}")
    return a


@dataclass(frozen=True, eq=False)
class Camera:
    """One calibrated camera.

    Parameters
    ----------
    K : array_like (3, 3)
        Camera matrix ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` [px].
    dist : array_like (4,), (5,) or (8,)
        OpenCV distortion coefficients ``(k1, k2, p1, p2[, k3[, k4, k5, k6]])``.
    size : (int, int)
        Image ``(width, height)`` [px].
    R_cam_world : array_like (3, 3)
        Rotation of the extrinsics ``x_cam = R x_world + t`` (OpenCV's ``Rodrigues(rvec)``).
    t_cam_world : array_like (3,)
        Translation of the extrinsics [m] (OpenCV's ``tvec``).
    name : str
    """

    K: np.ndarray
    dist: np.ndarray
    size: tuple[int, int]
    R_cam_world: np.ndarray
    t_cam_world: np.ndarray
    name: str = "cam"

    def __post_init__(self):
        K = _as_matrix(self.K, (3, 3), f"camera {self.name!r}: K")
        if not (K[0, 0] > 0 and K[1, 1] > 0 and K[1, 0] == 0 and K[2, 0] == 0 and K[2, 1] == 0):
            raise InputError(f"camera {self.name!r}: K must be upper triangular with fx, fy > 0")
        if not np.isclose(K[2, 2], 1.0):
            raise InputError(f"camera {self.name!r}: K[2, 2] must be 1, got {K[2, 2]}")
        d = np.asarray(self.dist, dtype=float).reshape(-1)
        if d.size not in _N_DIST or not np.all(np.isfinite(d)):
            raise InputError(
                f"camera {self.name!r}: need 4, 5 or 8 finite distortion coefficients "
                f"(k1, k2, p1, p2[, k3[, k4, k5, k6]]), got {d.size}"
            )
        R = _as_matrix(self.R_cam_world, (3, 3), f"camera {self.name!r}: R_cam_world")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise InputError(f"camera {self.name!r}: R_cam_world is not a rotation matrix")
        t = _as_matrix(np.reshape(self.t_cam_world, -1), (3,), f"camera {self.name!r}: t")
        w, h = (int(v) for v in self.size)
        if w <= 0 or h <= 0:
            raise InputError(f"camera {self.name!r}: image size must be positive, got {self.size}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", d)
        object.__setattr__(self, "_d8", np.concatenate([d, np.zeros(8 - d.size)]))
        object.__setattr__(self, "size", (w, h))
        object.__setattr__(self, "R_cam_world", R)
        object.__setattr__(self, "t_cam_world", t)

    # -- poses --------------------------------------------------------------------------------
    @classmethod
    def looking_at(
        cls, K, dist, size, position, target, up=(0.0, 0.0, 1.0), name: str = "cam"
    ) -> Camera:
        """A camera at ``position`` (world, m) whose optical axis points at ``target``; image
        ``y`` points down, so world ``up`` appears up in the image."""
        c = np.asarray(position, dtype=float)
        z = np.asarray(target, dtype=float) - c
        z /= np.linalg.norm(z)
        x = np.cross(z, np.asarray(up, dtype=float))
        if np.linalg.norm(x) < 1e-9:
            raise InputError(f"camera {name!r}: the viewing direction is parallel to up")
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])  # rows: camera axes in world coordinates
        return cls(K, dist, size, R, -R @ c, name)

    @property
    def T_world_cam(self) -> Pose:
        """Pose of the camera in the world (maps camera coordinates into world)."""
        R = self.R_cam_world.T
        return Pose(-R @ self.t_cam_world, quat_from_matrix(R))

    @property
    def center(self) -> np.ndarray:
        """Optical centre in world coordinates (3,) [m]."""
        return -self.R_cam_world.T @ self.t_cam_world

    # -- distortion ---------------------------------------------------------------------------
    def _distort(self, x, y, jacobian: bool):
        k1, k2, p1, p2, k3, k4, k5, k6 = self._d8
        r2 = x * x + y * y
        num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
        a = num / den
        xy = x * y
        xd = x * a + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x)
        yd = y * a + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy
        if not jacobian:
            return xd, yd, None
        dnum = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
        dden = k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2)
        da = (dnum * den - num * dden) / (den * den)  # d a / d r2
        J = np.empty(x.shape + (2, 2))
        J[..., 0, 0] = a + 2.0 * x * x * da + 2.0 * p1 * y + 6.0 * p2 * x
        J[..., 0, 1] = 2.0 * xy * da + 2.0 * p1 * x + 2.0 * p2 * y
        J[..., 1, 0] = 2.0 * xy * da + 2.0 * p1 * x + 2.0 * p2 * y
        J[..., 1, 1] = a + 2.0 * y * y * da + 6.0 * p1 * y + 2.0 * p2 * x
        return xd, yd, J

    def _to_pixels(self, xd, yd) -> np.ndarray:
        K = self.K
        return np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=-1)

    # -- projection ---------------------------------------------------------------------------
    def project(self, X_world, jacobian: bool = False):
        """Pixels of world points.

        Parameters
        ----------
        X_world : array_like (..., 3)
            Points in the world frame [m].
        jacobian : bool
            Also return ``J_uv_X`` (..., 2, 3), the derivative of the pixel with respect to the
            world point [px/m].

        Returns
        -------
        uv : ndarray (..., 2)
            Pixel coordinates (NaN behind the camera, ``z_cam <= 0``).
        J_uv_X : ndarray (..., 2, 3), only with ``jacobian=True``
        """
        X = np.asarray(X_world, dtype=float)
        if X.shape[-1:] != (3,):
            raise InputError(
                f"camera {self.name!r}: points must have shape (..., 3), got {X.shape}"
            )
        Xc = X @ self.R_cam_world.T + self.t_cam_world
        z = Xc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            iz = np.where(z > 0, 1.0 / z, np.nan)
        x, y = Xc[..., 0] * iz, Xc[..., 1] * iz
        xd, yd, J_d = self._distort(x, y, jacobian)
        uv = self._to_pixels(xd, yd)
        if not jacobian:
            return uv
        K2 = self.K[:2, :2]
        J_n_c = np.zeros(x.shape + (2, 3))  # d(x, y) / d X_cam
        J_n_c[..., 0, 0] = iz
        J_n_c[..., 1, 1] = iz
        J_n_c[..., 0, 2] = -x * iz
        J_n_c[..., 1, 2] = -y * iz
        J_uv_X = K2 @ J_d @ J_n_c @ self.R_cam_world
        return uv, J_uv_X

    def normalize(self, uv, iterations: int = 20, tol: float = 1e-12) -> np.ndarray:
        """Undistorted normalised coordinates ``(x, y)`` (``X_cam ~ (x, y, 1)``) of pixels.

        Inverts the distortion by Newton's method (``cv2.undistortPoints`` without ``P``).
        Pixels where it does not converge (far outside the calibrated field) are NaN.

        Parameters
        ----------
        uv : array_like (..., 2) [px]

        Returns
        -------
        ndarray (..., 2)
        """
        uv = np.asarray(uv, dtype=float)
        if uv.shape[-1:] != (2,):
            raise InputError(
                f"camera {self.name!r}: pixels must have shape (..., 2), got {uv.shape}"
            )
        K = self.K
        yd = (uv[..., 1] - K[1, 2]) / K[1, 1]
        xd = (uv[..., 0] - K[0, 2] - K[0, 1] * yd) / K[0, 0]
        x, y = xd.copy(), yd.copy()
        for _ in range(iterations):
            fx, fy, J = self._distort(x, y, True)
            rx, ry = fx - xd, fy - yd
            det = J[..., 0, 0] * J[..., 1, 1] - J[..., 0, 1] * J[..., 1, 0]
            dx = (J[..., 1, 1] * rx - J[..., 0, 1] * ry) / det
            dy = (-J[..., 1, 0] * rx + J[..., 0, 0] * ry) / det
            x, y = x - dx, y - dy
            if np.nanmax(np.abs(dx) + np.abs(dy), initial=0.0) < tol:
                break
        fx, fy, _ = self._distort(x, y, False)
        bad = np.hypot(fx - xd, fy - yd) > 1e-9
        out = np.stack([x, y], axis=-1)
        out[bad] = np.nan
        return out

    def rays(self, uv) -> np.ndarray:
        """Unit viewing directions in the world frame (..., 3) of pixels (..., 2)."""
        n = self.normalize(uv)
        d = np.concatenate([n, np.ones(n.shape[:-1] + (1,))], axis=-1) @ self.R_cam_world
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def in_image(self, uv, margin: float = 0.0) -> np.ndarray:
        """Boolean mask of pixels inside the image, ``margin`` px from the border."""
        uv = np.asarray(uv, dtype=float)
        w, h = self.size
        with np.errstate(invalid="ignore"):
            return (
                (uv[..., 0] >= -0.5 + margin)
                & (uv[..., 0] <= w - 0.5 - margin)
                & (uv[..., 1] >= -0.5 + margin)
                & (uv[..., 1] <= h - 0.5 - margin)
            )

    def projection_matrix(self) -> np.ndarray:
        """``K [R | t]`` (3, 4) of the undistorted camera (for linear triangulation)."""
        return self.K @ np.hstack([self.R_cam_world, self.t_cam_world[:, None]])


class CameraRig:
    """N calibrated cameras observing one world frame (synchronised exposures).

    Parameters
    ----------
    cameras : sequence of Camera
        Names must be unique.
    """

    def __init__(self, cameras: Sequence[Camera]):
        cams = list(cameras)
        if not cams:
            raise InputError("a camera rig needs at least one camera")
        for c in cams:
            if not isinstance(c, Camera):
                raise InputError(f"rig members must be Camera objects, got {type(c).__name__}")
        names = [c.name for c in cams]
        if len(set(names)) != len(names):
            raise InputError(f"camera names must be unique, got {names}")
        self.cameras = cams

    def __len__(self) -> int:
        return len(self.cameras)

    def __getitem__(self, i: int) -> Camera:
        return self.cameras[i]

    def __iter__(self):
        return iter(self.cameras)

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.cameras]

    def project(self, X_world, jacobian: bool = False):
        """Project points (..., 3) into every camera.

        Returns
        -------
        uv : ndarray (C, ..., 2)
        J_uv_X : ndarray (C, ..., 2, 3), only with ``jacobian=True``
        """
        out = [c.project(X_world, jacobian) for c in self.cameras]
        if not jacobian:
            return np.stack(out)
        return np.stack([o[0] for o in out]), np.stack([o[1] for o in out])

    def visible(self, X_world, margin: float = 0.0) -> np.ndarray:
        """(C, ...) mask: in front of the camera and inside the image."""
        uv = self.project(X_world)
        return np.stack([c.in_image(uv[i], margin) for i, c in enumerate(self.cameras)])


def ring_rig(
    n: int = 4,
    radius: float = 3.0,
    height: float = 2.2,
    target=(0.0, 0.0, 1.0),
    size: tuple[int, int] = (1280, 1024),
    focal_px: float = 1200.0,
    dist=(-0.12, 0.08, 0.0005, -0.0003, -0.01),
) -> CameraRig:
    """``n`` identical cameras evenly on a circle (z up), all looking at ``target`` - the usual
    outside-in motion-capture layout (about 56 degrees horizontal field of view by default).

    Parameters
    ----------
    radius, height : float
        Circle radius and camera height [m]. ``target`` (3,) [m].
    size : (width, height) [px]; focal_px : float [px]; dist : OpenCV coefficients.
    """
    w, h = size
    K = np.array([[focal_px, 0.0, (w - 1) / 2.0], [0.0, focal_px, (h - 1) / 2.0], [0, 0, 1.0]])
    cams = []
    for i in range(n):
        a = 2.0 * np.pi * i / n + np.pi / 4
        pos = (radius * np.cos(a), radius * np.sin(a), height)
        cams.append(Camera.looking_at(K, dist, size, pos, target, name=f"cam{i}"))
    return CameraRig(cams)
