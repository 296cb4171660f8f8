"""Calibrated pinhole cameras and image features of a rigid model (points, line segments).

These are the measurement models of the quaternion-space filter (Ude 1999, sections 4-5,
``filters/manifold_gn.py``): a model feature fixed in the body frame ``b`` of a pose
``T_w_b`` (``x_w = R x_b + p``) is projected through a camera whose pose ``T_w_c`` is known.

Features
--------
* point: image position ``(u, v)`` [px].
* line segment, *reduced mid-point parameterisation* (Deriche & Faugeras 1990): the image
  mid-point ``(u_m, v_m)`` [px] of the two end-points and the direction angle
  ``phi = atan2(dv, du)`` [rad] of the segment, 3 numbers per segment. The angle residual is
  taken modulo pi, so the end-point order of a measured segment does not matter.

Pose perturbation
-----------------
All Jacobians with respect to "the pose" use the error of ``manifold_gn``: the body pose
``(p, q)`` is perturbed as ``p + dp``, ``Exp(dphi) * q`` with ``dphi`` a rotation vector in the
world frame ``w`` (radians, on the *left*). ``J_y_pose`` has columns ``(dp, dphi)``.

Each feature carries its own 2x2 (point) or 3x3 (segment) measurement covariance; the
observations store their whitening matrices ``W`` (``W^T W = Sigma^-1``) so that
``W (g(p, q) - y)`` is a vector of unit-variance residuals.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from trackflow.math import Pose, quat_to_matrix, skew

from ...errors import InputError, NumericalError

__all__ = [
    "PinholeCamera",
    "CameraObservation",
    "segment_parameters",
    "segment_covariance",
    "anisotropic_endpoint_covariance",
    "wrap_angle_pi",
]


def wrap_angle_pi(angle):
    """Map an angle difference [rad] of undirected lines into ``[-pi/2, pi/2)``."""
    return (np.asarray(angle, dtype=float) + 0.5 * np.pi) % np.pi - 0.5 * np.pi


@dataclass(frozen=True)
class PinholeCamera:
    """A calibrated pinhole camera without lens distortion.

    Parameters
    ----------
    fx, fy : float
        Focal lengths [px].
    cx, cy : float
        Principal point [px] (pixel coordinates, u to the right, v down).
    width, height : int
        Image size [px]; used by :meth:`in_image`.
    pose : Pose
        ``T_w_c``: the camera frame c in the world (reference) frame w, ``x_w = R x_c + t``.
        Camera frame: z along the optical axis, x along u, y along v.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    pose: Pose = field(default_factory=Pose.identity)

    def __post_init__(self):
        for name in ("fx", "fy"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise InputError(f"PinholeCamera.{name} must be a positive focal length, got {v}")
        if self.width <= 0 or self.height <= 0:
            raise InputError(
                f"PinholeCamera image size must be positive, got {self.width}x{self.height}"
            )
        if self.pose.shape != ():
            raise InputError(
                f"PinholeCamera.pose must be a single pose, got shape {self.pose.shape}"
            )

    @classmethod
    def from_sensor(
        cls,
        focal_length_mm: float,
        sensor_width_mm: float,
        sensor_height_mm: float,
        width_px: int,
        height_px: int,
        pose: Pose | None = None,
    ) -> PinholeCamera:
        """Camera from the focal length and the sensor size, principal point at the centre.

        ``fx = f * width_px / sensor_width``, ``fy = f * height_px / sensor_height``.
        """
        fx = focal_length_mm * width_px / sensor_width_mm
        fy = focal_length_mm * height_px / sensor_height_mm
        return cls(
            fx, fy, 0.5 * width_px, 0.5 * height_px, width_px, height_px,
            Pose.identity() if pose is None else pose,
        )  # fmt: skip

    def project(self, points_w) -> tuple[np.ndarray, np.ndarray]:
        """Project world points into the image.

        Parameters
        ----------
        points_w : array_like, shape (..., 3)
            Points in the world frame w [m].

        Returns
        -------
        uv : ndarray, shape (..., 2)
            Pixel coordinates [px].
        J_uv_x : ndarray, shape (..., 2, 3)
            Derivative of ``uv`` with respect to the world point [px/m].

        Raises
        ------
        ValueError
            If a point is not in front of the camera (depth <= 0).
        """
        x_w = np.asarray(points_w, dtype=float)
        R_wc = self.pose.rotation_matrix
        x_c = (x_w - self.pose.position) @ R_wc  # R_wc^T (x_w - t)
        z = x_c[..., 2]
        if np.any(~(z > 1e-9)):
            bad = int(np.argmax(~(z > 1e-9).reshape(-1)))
            raise InputError(
                f"point {bad} is not in front of the camera (depth {z.reshape(-1)[bad]:.3g} m)"
            )
        iz = 1.0 / z
        u = self.fx * x_c[..., 0] * iz + self.cx
        v = self.fy * x_c[..., 1] * iz + self.cy
        J_uv_xc = np.zeros(x_c.shape[:-1] + (2, 3))
        J_uv_xc[..., 0, 0] = self.fx * iz
        J_uv_xc[..., 0, 2] = -self.fx * x_c[..., 0] * iz * iz
        J_uv_xc[..., 1, 1] = self.fy * iz
        J_uv_xc[..., 1, 2] = -self.fy * x_c[..., 1] * iz * iz
        return np.stack([u, v], axis=-1), J_uv_xc @ R_wc.T

    def in_image(self, uv) -> np.ndarray:
        """Boolean mask of pixel coordinates (..., 2) inside the image rectangle."""
        uv = np.asarray(uv, dtype=float)
        return (
            (uv[..., 0] >= 0)
            & (uv[..., 0] < self.width)
            & (uv[..., 1] >= 0)
            & (uv[..., 1] < self.height)
        )


def segment_parameters(a, b) -> tuple[np.ndarray, np.ndarray]:
    """Reduced mid-point parameters of image segments from their end-points.

    Parameters
    ----------
    a, b : array_like, shape (..., 2)
        End-points [px].

    Returns
    -------
    y : ndarray, shape (..., 3)
        ``(u_m, v_m, phi)``: mid-point [px] and direction angle ``atan2(b - a)`` [rad].
    J_y_ab : ndarray, shape (..., 3, 4)
        Derivative with respect to ``(a_u, a_v, b_u, b_v)``.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    d = b - a
    l2 = np.sum(d * d, axis=-1)
    if np.any(~(l2 > 0)):
        raise InputError("segment has coincident end-points (zero length)")
    y = np.concatenate([0.5 * (a + b), np.arctan2(d[..., 1], d[..., 0])[..., None]], axis=-1)
    J = np.zeros(a.shape[:-1] + (3, 4))
    J[..., 0, 0] = J[..., 0, 2] = 0.5
    J[..., 1, 1] = J[..., 1, 3] = 0.5
    g = np.stack([-d[..., 1], d[..., 0]], axis=-1) / l2[..., None]  # d phi / d d
    J[..., 2, 0:2] = -g
    J[..., 2, 2:4] = g
    return y, J


def segment_covariance(a, b, cov_a, cov_b) -> np.ndarray:
    """First-order covariance of ``(u_m, v_m, phi)`` from independent end-point covariances.

    ``Sigma_y = J_y_ab blockdiag(cov_a, cov_b) J_y_ab^T`` (Deriche & Faugeras 1990): mid-point
    covariance ``(cov_a + cov_b) / 4``, angle variance ``n^T (cov_a + cov_b) n / L^2`` (n the unit
    normal, L the length), cross terms ``(cov_b - cov_a) n / (2 L)``.

    Parameters
    ----------
    a, b : array_like, shape (..., 2)
        End-points [px].
    cov_a, cov_b : array_like, shape (..., 2, 2)
        Their covariances [px^2].

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    _, J = segment_parameters(a, b)
    cov_a = np.asarray(cov_a, dtype=float)
    cov_b = np.asarray(cov_b, dtype=float)
    C = np.zeros(np.broadcast_shapes(cov_a.shape, cov_b.shape)[:-2] + (4, 4))
    C[..., :2, :2] = cov_a
    C[..., 2:, 2:] = cov_b
    return J @ C @ np.swapaxes(J, -1, -2)


def anisotropic_endpoint_covariance(a, b, sigma_along, sigma_across, quantization=False):
    """Covariance [px^2] of an end-point with different noise along and across its segment.

    ``Sigma = sigma_along^2 t t^T + sigma_across^2 n n^T (+ I / 12 if quantization)`` where t is
    the unit direction of ``b - a`` and n its normal; the optional term is the variance of
    rounding a coordinate to a whole pixel.

    Parameters
    ----------
    a, b : array_like, shape (..., 2)
        End-points [px] of the segment (only its direction is used).
    sigma_along, sigma_across : float
        Standard deviations [px].
    quantization : bool
        Add the rounding variance 1/12 px^2 per coordinate.

    Returns
    -------
    ndarray, shape (..., 2, 2)
    """
    d = np.asarray(b, dtype=float) - np.asarray(a, dtype=float)
    n = np.linalg.norm(d, axis=-1, keepdims=True)
    if np.any(~(n > 0)):
        raise InputError("segment has coincident end-points (zero length)")
    t = d / n
    nn = np.stack([-t[..., 1], t[..., 0]], axis=-1)
    cov = sigma_along**2 * t[..., :, None] * t[..., None, :]
    cov = cov + sigma_across**2 * nn[..., :, None] * nn[..., None, :]
    if quantization:
        cov = cov + np.eye(2) / 12.0
    return cov


def _whitening(cov: np.ndarray, name: str) -> np.ndarray:
    """``W = L^-1`` with ``cov = L L^T``; ``ValueError`` naming the feature if not SPD."""
    try:
        L = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        bad = [i for i in range(cov.shape[0]) if np.any(np.linalg.eigvalsh(cov[i]) <= 0)]
        raise NumericalError(
            f"{name} covariance of feature {bad[:1]} is not positive definite"
        ) from None
    eye = np.broadcast_to(np.eye(cov.shape[-1]), cov.shape)
    return np.linalg.solve(L, eye)


@dataclass(frozen=True)
class CameraObservation:
    """Measured features of a rigid model in one calibrated camera at one time.

    Parameters
    ----------
    camera : PinholeCamera
    point_model : array_like, shape (Np, 3)
        Model points in the body frame b [m].
    point_meas : array_like, shape (Np, 2)
        Their measured image positions [px].
    point_cov : array_like, shape (Np, 2, 2)
        Measurement covariances [px^2].
    segment_model : array_like, shape (Ns, 2, 3)
        Model segment end-points in the body frame b [m].
    segment_meas : array_like, shape (Ns, 3)
        Measured ``(u_m, v_m, phi)`` [px, px, rad] (see :func:`segment_parameters`).
    segment_cov : array_like, shape (Ns, 3, 3)
        Their covariances (see :func:`segment_covariance`).
    """

    camera: PinholeCamera
    point_model: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    point_meas: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    point_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)))
    segment_model: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))
    segment_meas: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    segment_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    point_whitening: np.ndarray = field(init=False, repr=False)
    segment_whitening: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        shapes = {
            "point_model": (3,), "point_meas": (2,), "point_cov": (2, 2),
            "segment_model": (2, 3), "segment_meas": (3,), "segment_cov": (3, 3),
        }  # fmt: skip
        for name, tail in shapes.items():
            arr = np.asarray(getattr(self, name), dtype=float)
            if arr.ndim != len(tail) + 1 or arr.shape[1:] != tail:
                raise InputError(
                    f"CameraObservation.{name} must have shape (N, {tail}), got {arr.shape}"
                )
            if not np.all(np.isfinite(arr)):
                raise InputError(f"CameraObservation.{name} contains NaN or inf")
            object.__setattr__(self, name, arr)
        for kind in ("point", "segment"):
            n = {getattr(self, f"{kind}_{s}").shape[0] for s in ("model", "meas", "cov")}
            if len(n) != 1:
                raise InputError(
                    f"CameraObservation: {kind} model, meas and cov counts differ: {n}"
                )
        object.__setattr__(self, "point_whitening", _whitening(self.point_cov, "point"))
        object.__setattr__(self, "segment_whitening", _whitening(self.segment_cov, "segment"))

    @property
    def size(self) -> int:
        """Number of scalar measurements (2 per point, 3 per segment)."""
        return 2 * self.point_meas.shape[0] + 3 * self.segment_meas.shape[0]

    def predict(self, position, quaternion) -> tuple[np.ndarray, np.ndarray]:
        """Predicted feature vector and its pose Jacobian.

        Parameters
        ----------
        position : array_like, shape (3,)
            ``p`` of ``T_w_b`` [m].
        quaternion : array_like, shape (4,)
            ``q`` of ``T_w_b`` (x, y, z, w).

        Returns
        -------
        y : ndarray, shape (size,)
            Points ``(u, v)`` then segments ``(u_m, v_m, phi)``, feature by feature.
        J_y_pose : ndarray, shape (size, 6)
            Derivative with respect to ``(dp, dphi)``: ``p + dp``, ``Exp(dphi) * q`` (world
            frame, radians, on the left).
        """
        R = quat_to_matrix(np.asarray(quaternion, dtype=float))
        p = np.asarray(position, dtype=float)
        ys, Js = [], []
        if self.point_model.shape[0]:
            rx = self.point_model @ R.T  # R x_b, shape (Np, 3)
            uv, J_uv_x = self.camera.project(rx + p)
            J = np.concatenate([J_uv_x, -J_uv_x @ skew(rx)], axis=-1)  # (Np, 2, 6)
            ys.append(uv.reshape(-1))
            Js.append(J.reshape(-1, 6))
        if self.segment_model.shape[0]:
            rx = self.segment_model @ R.T  # (Ns, 2, 3)
            uv, J_uv_x = self.camera.project(rx + p)  # (Ns, 2, 2), (Ns, 2, 2, 3)
            J_uv_pose = np.concatenate([J_uv_x, -J_uv_x @ skew(rx)], axis=-1)  # (Ns, 2, 2, 6)
            y, J_y_ab = segment_parameters(uv[:, 0], uv[:, 1])
            J = J_y_ab @ J_uv_pose.reshape(-1, 4, 6)
            ys.append(y.reshape(-1))
            Js.append(J.reshape(-1, 6))
        if not ys:
            return np.zeros(0), np.zeros((0, 6))
        return np.concatenate(ys), np.concatenate(Js, axis=0)

    def whitened_residual(self, position, quaternion) -> tuple[np.ndarray, np.ndarray]:
        """Unit-variance residuals ``h = W (g(p, q) - y)`` and ``J_h_pose`` (size, 6).

        Angle residuals are wrapped into ``[-pi/2, pi/2)`` (undirected segments).
        """
        g, J = self.predict(position, quaternion)
        npnt = 2 * self.point_meas.shape[0]
        r_p = (g[:npnt] - self.point_meas.reshape(-1)).reshape(-1, 2)
        r_s = (g[npnt:] - self.segment_meas.reshape(-1)).reshape(-1, 3)
        r_s[:, 2] = wrap_angle_pi(r_s[:, 2])
        h_p = np.einsum("nij,nj->ni", self.point_whitening, r_p).reshape(-1)
        h_s = np.einsum("nij,nj->ni", self.segment_whitening, r_s).reshape(-1)
        Jp = np.einsum("nij,njk->nik", self.point_whitening, J[:npnt].reshape(-1, 2, 6))
        Js = np.einsum("nij,njk->nik", self.segment_whitening, J[npnt:].reshape(-1, 3, 6))
        return np.concatenate([h_p, h_s]), np.concatenate([Jp.reshape(-1, 6), Js.reshape(-1, 6)])
