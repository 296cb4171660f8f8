"""Rigid transformations ``T_a_b`` held as position + unit quaternion, single or batched.

See ``docs/conventions.md``: ``T_a_b`` maps points of frame b into frame a,
``x_a = R x_b + t``, and chains as ``T_a_c = T_a_b @ T_b_c``.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ._checks import check_position, check_quaternion
from ._quaternion import (
    quat_angle,
    quat_conjugate,
    quat_from_matrix,
    quat_identity,
    quat_multiply,
    quat_rotate,
    quat_slerp,
    quat_to_matrix,
)

__all__ = ["Pose"]


class Pose:
    """A rigid transformation ``T_a_b`` (or a batch of them) without uncertainty.

    Parameters
    ----------
    position : array_like, shape (..., 3)
        Translation ``t_a_b``: the origin of frame b expressed in frame a, metres.
    quaternion : array_like, shape (..., 4)
        Rotation ``R_a_b`` as a unit quaternion ``(x, y, z, w)``.
    normalize : bool, default False
        Accept a non-unit quaternion and scale it. Without it, a norm off by more than
        ``1e-6`` raises ``ValueError``.

    Notes
    -----
    Leading dimensions of ``position`` and ``quaternion`` broadcast; the pose then represents a
    batch and every operation works element-wise. Conventions: ``docs/conventions.md``.

    Examples
    --------
    >>> T_a_b = Pose([1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])
    >>> T_a_b.transform_points([0.0, 1.0, 0.0])
    array([1., 1., 0.])
    """

    __slots__ = ("_p", "_q")
    __array_priority__ = 1000  # make ndarray @ Pose defer to Pose

    def __init__(self, position, quaternion, normalize: bool = False):
        p = check_position(position)
        q = check_quaternion(quaternion, normalize=normalize)
        if p is position:  # never alias the caller's array: a Pose does not change under it
            p = p.copy()
        if p.ndim == 1 and q.ndim == 1:
            self._p, self._q = p, q
            return
        try:
            shape = np.broadcast_shapes(p.shape[:-1], q.shape[:-1])
        except ValueError as exc:
            raise InputError(
                f"position batch shape {p.shape[:-1]} and quaternion batch shape "
                f"{q.shape[:-1]} do not broadcast"
            ) from exc
        self._p = np.broadcast_to(p, shape + (3,)).copy() if p.shape[:-1] != shape else p
        self._q = np.broadcast_to(q, shape + (4,)).copy() if q.shape[:-1] != shape else q

    @classmethod
    def _trusted(cls, position: np.ndarray, quaternion: np.ndarray) -> Pose:
        """Build from arrays already known to be valid (internal fast path)."""
        obj = cls.__new__(cls)
        obj._p = position
        obj._q = quaternion
        return obj

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def identity(cls, shape: tuple[int, ...] = ()) -> Pose:
        """The identity transformation (a batch of them for non-empty ``shape``)."""
        return cls._trusted(np.zeros(tuple(shape) + (3,)), quat_identity(shape))

    @classmethod
    def from_matrix(cls, matrix) -> Pose:
        """From homogeneous matrices (..., 4, 4) whose rotation part is orthonormal to 1e-6."""
        m = np.asarray(matrix, dtype=float)
        if m.shape[-2:] != (4, 4):
            raise InputError(f"matrix must have shape (..., 4, 4), got {m.shape}")
        if not np.all(np.isfinite(m)):
            raise InputError("matrix contains NaN or inf")
        r = m[..., :3, :3]
        err = np.max(np.abs(r @ np.swapaxes(r, -1, -2) - np.eye(3)))
        if err > 1e-6:
            raise InputError(f"matrix rotation part is not a rotation (|R R^T - I| = {err:.3g})")
        if np.any(np.linalg.det(r) < 0):
            raise InputError(
                "matrix rotation part is not a rotation: a reflection (determinant -1)"
            )
        if np.any(np.abs(m[..., 3, :] - [0.0, 0.0, 0.0, 1.0]) > 1e-12):
            raise InputError("matrix last row must be [0, 0, 0, 1]")
        return cls._trusted(m[..., :3, 3].copy(), quat_from_matrix(r))

    # -- attributes ---------------------------------------------------------------------------
    @property
    def position(self) -> np.ndarray:
        """Translation ``t_a_b``, shape (..., 3), metres."""
        return self._p

    @property
    def quaternion(self) -> np.ndarray:
        """Rotation ``R_a_b`` as unit quaternion ``(x, y, z, w)``, shape (..., 4)."""
        return self._q

    @property
    def shape(self) -> tuple[int, ...]:
        """Batch shape (``()`` for a single pose)."""
        return self._p.shape[:-1]

    @property
    def rotation_matrix(self) -> np.ndarray:
        """Rotation matrix ``R_a_b``, shape (..., 3, 3)."""
        return quat_to_matrix(self._q)

    def as_matrix(self) -> np.ndarray:
        """Homogeneous matrix (..., 4, 4)."""
        m = np.zeros(self.shape + (4, 4))
        m[..., :3, :3] = quat_to_matrix(self._q)
        m[..., :3, 3] = self._p
        m[..., 3, 3] = 1.0
        return m

    def __len__(self) -> int:
        if not self.shape:
            raise TypeError("a single Pose has no length")
        return self.shape[0]

    def __getitem__(self, index) -> Pose:
        if not self.shape:
            raise TypeError("a single Pose cannot be indexed")
        return Pose._trusted(self._p[index], self._q[index])

    def __repr__(self) -> str:
        if self.shape:
            return f"Pose(batch of shape {self.shape})"
        p = np.array2string(self._p, precision=6)
        q = np.array2string(self._q, precision=6)
        return f"Pose(position={p}, quaternion={q})"

    # -- operations ---------------------------------------------------------------------------
    def __matmul__(self, other):
        if isinstance(other, Pose):
            return Pose._trusted(
                self._p + quat_rotate(self._q, other._p), quat_multiply(self._q, other._q)
            )
        return NotImplemented

    def compose(self, other: Pose) -> Pose:
        """``T_a_c = T_a_b @ T_b_c``; the same as ``self @ other``."""
        return self @ other

    def inverse(self) -> Pose:
        """``T_b_a``: ``R^T``, ``-R^T t``."""
        qi = quat_conjugate(self._q)
        return Pose._trusted(-quat_rotate(qi, self._p), qi)

    def transform_points(self, points) -> np.ndarray:
        """Map points (..., 3) given in frame b into frame a: ``R x + t``."""
        x = np.asarray(points, dtype=float)
        return quat_rotate(self._q, x) + self._p

    def interpolate(self, other: Pose, s) -> Pose:
        """Linear interpolation of position and slerp of rotation, ``s`` in [0, 1].

        ``s = 0`` gives ``self``, ``s = 1`` gives ``other``; the rotation follows the shortest
        path. ``s`` broadcasts against the batch shape.
        """
        s = np.asarray(s, dtype=float)
        p = (1.0 - s)[..., None] * self._p + s[..., None] * other._p
        return Pose._trusted(p, quat_slerp(self._q, other._q, s))

    def __eq__(self, other) -> bool:
        """Exact equality of batch shape, positions and rotations (``q`` and ``-q`` are equal,
        element by element)."""
        if not isinstance(other, Pose):
            return NotImplemented
        if self.shape != other.shape:
            return False
        same_q = np.all(self._q == other._q, axis=-1) | np.all(self._q == -other._q, axis=-1)
        return bool(np.all(self._p == other._p) and np.all(same_q))

    __hash__ = None

    def allclose(self, other: Pose, atol: float = 1e-9) -> bool:
        """Positions within ``atol`` metres and rotations within ``atol`` radians."""
        dp = np.max(np.abs(self._p - other._p), initial=0.0)
        da = np.max(quat_angle(self._q, other._q), initial=0.0)
        return bool(dp <= atol and da <= atol)
