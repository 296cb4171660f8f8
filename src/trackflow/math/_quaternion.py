"""Unit quaternions and rotation vectors, batched over leading dimensions.

Quaternions are ``(x, y, z, w)``, Hamilton product, unit length; rotation vectors are axis times
angle in radians. See ``docs/conventions.md``. Every function accepts arrays of shape
``(..., 4)`` / ``(..., 3)`` and broadcasts over the leading dimensions. These functions do not
validate their input: validation happens once, at the boundary (``trackflow.math.checks``).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ._lie import SMALL_ANGLE as _SMALL_ANGLE

__all__ = [
    "quat_identity",
    "quat_multiply",
    "quat_conjugate",
    "quat_normalize",
    "quat_rotate",
    "quat_exp",
    "quat_log",
    "quat_slerp",
    "quat_between",
    "quat_rplus",
    "quat_rminus",
    "quat_align_sign",
    "quat_make_continuous",
    "quat_angle",
    "quat_to_matrix",
    "quat_from_matrix",
    "skew",
    "so3_right_jacobian",
    "so3_right_jacobian_inverse",
]

# Below _SMALL_ANGLE (radians, the policy of trackflow.math._lie) the series expansions are
# used; their truncation error there is far below double precision.


def quat_identity(shape: tuple[int, ...] = ()) -> np.ndarray:
    """Identity quaternion(s) of shape ``shape + (4,)``."""
    q = np.zeros(tuple(shape) + (4,))
    q[..., 3] = 1.0
    return q


def quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p * q``; ``R(p * q) = R(p) R(q)``.

    Parameters
    ----------
    p, q : array_like, shape (..., 4)
        Quaternions ``(x, y, z, w)``.

    Returns
    -------
    ndarray, shape (..., 4)
    """
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    px, py, pz, pw = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qx, qy, qz, qw = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
            pw * qw - px * qx - py * qy - pz * qz,
        ],
        axis=-1,
    )


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """Conjugate ``(-x, -y, -z, w)``: the inverse rotation of a unit quaternion."""
    q = np.asarray(q, dtype=float)
    return q * np.array([-1.0, -1.0, -1.0, 1.0])


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Scale quaternion(s) to unit length. Raises ``ValueError`` for a zero quaternion."""
    q = np.asarray(q, dtype=float)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n == 0.0) or not np.all(np.isfinite(n)):
        raise InputError("cannot normalize a zero or non-finite quaternion")
    return q / n


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vector(s) ``v`` (shape (..., 3)) by unit quaternion(s) ``q``: ``R(q) v``."""
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    u = q[..., :3]
    w = q[..., 3:4]
    # v' = v + 2 w (u x v) + 2 u x (u x v), valid for unit q.
    uv = np.cross(u, v)
    return v + 2.0 * (w * uv + np.cross(u, uv))


def quat_exp(rotvec: np.ndarray) -> np.ndarray:
    """Exponential map: rotation vector (radians, shape (..., 3)) to unit quaternion (..., 4).

    ``Exp(theta * axis) = (sin(theta/2) axis, cos(theta/2))``; uses a Taylor series below
    ``1e-4`` rad so that tiny rotations keep full relative precision.
    """
    v = np.asarray(rotvec, dtype=float)
    theta2 = np.sum(v * v, axis=-1, keepdims=True)
    theta = np.sqrt(theta2)
    small = theta < _SMALL_ANGLE
    safe = np.where(small, 1.0, theta)
    # sin(theta/2)/theta and cos(theta/2), series for small angles.
    k = np.where(small, 0.5 - theta2 / 48.0, np.sin(0.5 * safe) / safe)
    w = np.where(small, 1.0 - theta2 / 8.0 + theta2 * theta2 / 384.0, np.cos(0.5 * safe))
    return np.concatenate([k * v, w], axis=-1)


def quat_log(q: np.ndarray) -> np.ndarray:
    """Logarithm map: unit quaternion (..., 4) to rotation vector (..., 3), angle in [0, pi].

    ``q`` and ``-q`` give the same result (the shortest rotation). ``atan2`` keeps the result
    accurate both at tiny angles and near pi (``w ~ 0``).
    """
    q = np.asarray(q, dtype=float)
    sign = np.where(q[..., 3:4] < 0.0, -1.0, 1.0)
    v = q[..., :3] * sign
    w = q[..., 3:4] * sign
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    small = n < _SMALL_ANGLE * 0.5
    safe_n = np.where(small, 1.0, n)
    # angle / sin(angle/2) = 2 atan2(n, w) / n; series 2/w (1 - n^2 / (3 w^2)) for tiny n.
    safe_w = np.where(small, w, 1.0)
    k = np.where(
        small,
        2.0 / safe_w * (1.0 - n * n / (3.0 * safe_w * safe_w)),
        2.0 * np.arctan2(n, w) / safe_n,
    )
    return k * v


def quat_between(q_a: np.ndarray, q_b: np.ndarray) -> np.ndarray:
    """``q_a^* q_b`` (..., 4): ``R_a_b`` of the orientations ``q_a = R_w_a`` and ``q_b = R_w_b``."""
    return quat_multiply(quat_conjugate(q_a), q_b)


def quat_rplus(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``q (+) v = q Exp(v)`` (..., 4): ``q`` moved by the right error ``v`` (..., 3) [rad]."""
    return quat_multiply(q, quat_exp(v))


def quat_rminus(q_b: np.ndarray, q_a: np.ndarray) -> np.ndarray:
    """``q_b (-) q_a = Log(q_a^* q_b)`` (..., 3) [rad]: the right error taking ``q_a`` to ``q_b``.

    The inverse of :func:`quat_rplus`: ``quat_rplus(q_a, quat_rminus(q_b, q_a))`` is ``q_b`` up
    to sign. The scalar kernels of the same maps are in :mod:`trackflow.math._lie`.
    """
    return quat_log(quat_between(q_a, q_b))


def quat_align_sign(q: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Return ``q`` or ``-q``, whichever is closer to ``reference`` (non-negative dot product)."""
    q = np.asarray(q, dtype=float)
    d = np.sum(q * np.asarray(reference, dtype=float), axis=-1, keepdims=True)
    return np.where(d < 0.0, -q, q)


def quat_make_continuous(q: np.ndarray) -> np.ndarray:
    """Flip signs along a sequence (axis 0) so consecutive quaternions have dot product >= 0.

    Recordings often contain sign flips (``q`` -> ``-q``) that break averaging and additive
    filters; this removes them without changing any rotation. The first quaternion keeps its
    sign.

    Parameters
    ----------
    q : array_like, shape (N, ..., 4)
        ``N`` quaternions in time order; further leading dimensions are independent sequences.
        A single quaternion (shape (4,)) is returned unchanged.

    Returns
    -------
    ndarray, same shape as ``q`` (a new array)
    """
    q = np.array(q, dtype=float, copy=True)
    if q.ndim < 2 or q.shape[0] < 2:
        return q
    d = np.sum(q[1:] * q[:-1], axis=-1)  # (N - 1, ...)
    flips = np.concatenate([np.zeros((1,) + d.shape[1:], dtype=bool), d < 0.0], axis=0)
    sign = np.where(np.cumsum(flips, axis=0) % 2 == 1, -1.0, 1.0)
    return q * sign[..., None]


def quat_angle(q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Angle (radians, in [0, pi]) of the rotation between orientations ``q0`` and ``q1``."""
    d = quat_between(q0, q1)
    n = np.linalg.norm(d[..., :3], axis=-1)
    return 2.0 * np.arctan2(n, np.abs(d[..., 3]))


def quat_slerp(q0: np.ndarray, q1: np.ndarray, s: np.ndarray | float) -> np.ndarray:
    """Spherical linear interpolation along the shortest path.

    ``slerp(q0, q1, s) = q0 * Exp(s Log(q0^* q1))``; ``s = 0`` gives ``q0``, ``s = 1`` gives
    ``q1`` (or ``-q1``). ``s`` broadcasts against the leading dimensions.
    """
    q0 = np.asarray(q0, dtype=float)
    s = np.asarray(s, dtype=float)[..., None]
    return quat_rplus(q0, s * quat_rminus(q1, q0))


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix/matrices (..., 3, 3) of unit quaternion(s) (..., 4)."""
    q = np.asarray(q, dtype=float)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    m = np.empty(q.shape[:-1] + (3, 3))
    m[..., 0, 0] = 1.0 - 2.0 * (yy + zz)
    m[..., 0, 1] = 2.0 * (xy - wz)
    m[..., 0, 2] = 2.0 * (xz + wy)
    m[..., 1, 0] = 2.0 * (xy + wz)
    m[..., 1, 1] = 1.0 - 2.0 * (xx + zz)
    m[..., 1, 2] = 2.0 * (yz - wx)
    m[..., 2, 0] = 2.0 * (xz - wy)
    m[..., 2, 1] = 2.0 * (yz + wx)
    m[..., 2, 2] = 1.0 - 2.0 * (xx + yy)
    return m


def quat_from_matrix(m: np.ndarray) -> np.ndarray:
    """Unit quaternion(s) (..., 4) with ``w >= 0`` from rotation matrices (..., 3, 3).

    Uses the numerically best of the four Shepperd branches per matrix.
    """
    m = np.asarray(m, dtype=float)
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    cand = np.stack(
        [
            1.0 + 2.0 * m[..., 0, 0] - tr,
            1.0 + 2.0 * m[..., 1, 1] - tr,
            1.0 + 2.0 * m[..., 2, 2] - tr,
            1.0 + tr,
        ],
        axis=-1,
    )
    i = np.argmax(cand, axis=-1)
    r = np.sqrt(np.maximum(np.take_along_axis(cand, i[..., None], axis=-1)[..., 0], 0.0))
    h = 0.5 / r
    d21 = m[..., 2, 1] - m[..., 1, 2]
    d02 = m[..., 0, 2] - m[..., 2, 0]
    d10 = m[..., 1, 0] - m[..., 0, 1]
    s01 = m[..., 0, 1] + m[..., 1, 0]
    s02 = m[..., 0, 2] + m[..., 2, 0]
    s12 = m[..., 1, 2] + m[..., 2, 1]
    branches = [
        np.stack([0.5 * r, s01 * h, s02 * h, d21 * h], axis=-1),
        np.stack([s01 * h, 0.5 * r, s12 * h, d02 * h], axis=-1),
        np.stack([s02 * h, s12 * h, 0.5 * r, d10 * h], axis=-1),
        np.stack([d21 * h, d02 * h, d10 * h, 0.5 * r], axis=-1),
    ]
    q = np.choose(i[..., None], branches)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0.0, -q, q)


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix ``[v]x`` (..., 3, 3) with ``[v]x u = v x u``."""
    v = np.asarray(v, dtype=float)
    m = np.zeros(v.shape[:-1] + (3, 3))
    m[..., 0, 1] = -v[..., 2]
    m[..., 0, 2] = v[..., 1]
    m[..., 1, 0] = v[..., 2]
    m[..., 1, 2] = -v[..., 0]
    m[..., 2, 0] = -v[..., 1]
    m[..., 2, 1] = v[..., 0]
    return m


def _jacobian_coefficients(theta2: np.ndarray):
    """``(1 - cos t)/t^2`` and ``(t - sin t)/t^3`` with series for small ``t``."""
    theta = np.sqrt(theta2)
    small = theta < _SMALL_ANGLE
    t = np.where(small, 1.0, theta)
    # (1 - cos t)/t^2 written as 2 sin^2(t/2)/t^2: no cancellation just above the switch.
    half_sinc = np.sin(0.5 * t) / t
    a = np.where(small, 0.5 - theta2 / 24.0 + theta2 * theta2 / 720.0, 2.0 * half_sinc**2)
    b = np.where(
        small, 1.0 / 6.0 - theta2 / 120.0 + theta2 * theta2 / 5040.0, (t - np.sin(t)) / t**3
    )
    return a, b


def so3_right_jacobian(phi: np.ndarray) -> np.ndarray:
    """Right Jacobian ``J_r(phi)`` of SO(3): ``Exp(phi + d) ~ Exp(phi) Exp(J_r(phi) d)``.

    ``J_r(phi) = I - a [phi]x + b [phi]x^2`` with ``a = (1 - cos t)/t^2``, ``b = (t - sin t)/t^3``.
    """
    phi = np.asarray(phi, dtype=float)
    a, b = _jacobian_coefficients(np.sum(phi * phi, axis=-1))
    k = skew(phi)
    return np.eye(3) - a[..., None, None] * k + b[..., None, None] * (k @ k)


def so3_right_jacobian_inverse(phi: np.ndarray) -> np.ndarray:
    """Inverse right Jacobian: ``Log(Exp(phi) Exp(d)) ~ phi + J_r^{-1}(phi) d``.

    ``J_r^{-1}(phi) = I + [phi]x / 2 + c [phi]x^2`` with
    ``c = 1/t^2 - (1 + cos t) / (2 t sin t)``; valid for angles below pi.
    """
    phi = np.asarray(phi, dtype=float)
    theta2 = np.sum(phi * phi, axis=-1)
    theta = np.sqrt(theta2)
    small = theta < _SMALL_ANGLE
    t = np.where(small, 1.0, theta)
    c = np.where(
        small,
        1.0 / 12.0 + theta2 / 720.0 + theta2 * theta2 / 30240.0,
        1.0 / t**2 - np.cos(0.5 * t) / (2.0 * t * np.sin(0.5 * t)),
    )
    k = skew(phi)
    return np.eye(3) + 0.5 * k + c[..., None, None] * (k @ k)
