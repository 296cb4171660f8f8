"""Poses with a 6x6 error covariance, and first-order propagation through pose operations.

Error model (``docs/conventions.md``): for an uncertain pose ``T_a_b`` with covariance ``C``,
``t_true = t + dt`` and ``R_true = R Exp(dtheta)`` with ``(dt, dtheta) ~ N(0, C)``; ``dt`` in
frame a (metres), ``dtheta`` on the right (radians).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from . import _kernels
from ._checks import check_covariance, check_position
from ._jacobians import (
    jacobian_inverse,
    jacobians_between,
    jacobians_interpolate,
    jacobians_transform_point,
    propagate_covariance,
)
from ._pose import Pose
from ._quaternion import (
    quat_exp,
    quat_make_continuous,
    quat_multiply,
    quat_normalize,
    quat_rminus,
    quat_to_matrix,
    skew,
)

__all__ = ["UncertainPose", "evaluate_covariance", "ellipsoid"]


def _as_uncertain(other, operation: str) -> UncertainPose:
    """``other`` as an UncertainPose: a plain ``Pose`` is exact, anything else an error."""
    if isinstance(other, UncertainPose):
        return other
    if isinstance(other, Pose):
        return UncertainPose.exact(other)
    raise InputError(f"cannot {operation} with {type(other).__name__}; need UncertainPose or Pose")


def _as_cross(cross, shape) -> np.ndarray | None:
    if cross is None:
        return None
    c = np.asarray(cross, dtype=float)
    if c.shape[-2:] != (6, 6) or not np.all(np.isfinite(c)):
        raise InputError(f"cross_covariance must be finite with shape (..., 6, 6), got {c.shape}")
    return c


class UncertainPose:
    """A pose ``T_a_b`` with the 6x6 covariance of its error, single or batched.

    Parameters
    ----------
    pose : Pose
        The mean transformation (shape ``S``, possibly empty for one pose).
    covariance : array_like, shape S + (6, 6)
        Covariance of ``e = (dt, dtheta)``: ``t_true = t + dt`` (frame a, metres),
        ``R_true = R Exp(dtheta)`` (radians, on the right). Must be symmetric positive
        semi-definite; see ``docs/conventions.md``.

    Examples
    --------
    >>> import numpy as np
    >>> a = UncertainPose(Pose([0, 0, 0], [0, 0, 0, 1]), np.diag([1e-6] * 3 + [3e-4] * 3))
    >>> b = UncertainPose(Pose([1, 0, 0], [0, 0, 0, 1]), np.zeros((6, 6)))
    >>> c, J_c_a, J_c_b = a.compose(b, jacobians=True)
    >>> bool(c.covariance[1, 1] > a.covariance[1, 1])  # rotation error moves the lever arm
    True
    """

    __slots__ = ("_pose", "_cov")
    __array_priority__ = 1000

    def __init__(self, pose: Pose, covariance):
        if not isinstance(pose, Pose):
            raise InputError(f"pose must be a trackflow Pose, got {type(pose).__name__}")
        c = check_covariance(covariance)
        if c is covariance:  # never alias the caller's array
            c = c.copy()
        if c.shape[:-2] != pose.shape:
            try:
                c = np.broadcast_to(c, pose.shape + (6, 6)).copy()
            except ValueError as exc:
                raise InputError(
                    f"covariance batch shape {c.shape[:-2]} does not match pose shape {pose.shape}"
                ) from exc
        self._pose = pose
        self._cov = c

    @classmethod
    def _trusted(cls, position, quaternion, covariance) -> UncertainPose:
        obj = cls.__new__(cls)
        obj._pose = Pose._trusted(position, quaternion)
        obj._cov = covariance
        return obj

    @classmethod
    def exact(cls, pose: Pose) -> UncertainPose:
        """An uncertain pose with zero covariance."""
        return cls._trusted(pose.position, pose.quaternion, np.zeros(pose.shape + (6, 6)))

    # -- attributes ---------------------------------------------------------------------------
    @property
    def pose(self) -> Pose:
        """The mean pose."""
        return self._pose

    @property
    def position(self) -> np.ndarray:
        """Mean translation ``t_a_b``, shape (..., 3), metres."""
        return self._pose.position

    @property
    def quaternion(self) -> np.ndarray:
        """Mean rotation ``R_a_b`` as ``(x, y, z, w)``, shape (..., 4)."""
        return self._pose.quaternion

    @property
    def covariance(self) -> np.ndarray:
        """Error covariance, shape (..., 6, 6), over ``(dt [m], dtheta [rad])``."""
        return self._cov

    @property
    def shape(self) -> tuple[int, ...]:
        """Batch shape (``()`` for a single pose)."""
        return self._pose.shape

    def __len__(self) -> int:
        return len(self._pose)

    def __getitem__(self, index) -> UncertainPose:
        p = self._pose[index]
        return UncertainPose._trusted(p.position, p.quaternion, self._cov[index])

    def __repr__(self) -> str:
        if self.shape:
            return f"UncertainPose(batch of shape {self.shape})"
        sd = np.sqrt(np.maximum(np.diag(self._cov), 0.0))
        return (
            f"UncertainPose(position={np.array2string(self.position, precision=6)}, "
            f"quaternion={np.array2string(self.quaternion, precision=6)}, "
            f"sigma_mm={np.array2string(sd[:3] * 1e3, precision=3)}, "
            f"sigma_deg={np.array2string(np.degrees(sd[3:]), precision=3)})"
        )

    # -- operations ---------------------------------------------------------------------------
    def compose(self, other, jacobians: bool = False, cross_covariance=None):
        """Chain ``T_a_c = T_a_b @ T_b_c`` and propagate the covariance.

        Parameters
        ----------
        other : UncertainPose or Pose
            ``T_b_c``; a plain ``Pose`` counts as exact.
        jacobians : bool
            Also return ``J_c_a`` and ``J_c_b`` (shape (..., 6, 6)).
        cross_covariance : array_like, shape (..., 6, 6), optional
            ``E[e_self e_other^T]`` for correlated inputs; omitted means independent.

        Returns
        -------
        UncertainPose, or (UncertainPose, J_c_a, J_c_b)
            ``C_c = J_c_a C_a J_c_a^T + J_c_b C_b J_c_b^T (+ cross terms)`` with
            ``J_c_a = [[I, -R_a [t_b]x], [0, R_b^T]]``, ``J_c_b = [[R_a, 0], [0, I]]``.
        """
        if not isinstance(other, UncertainPose):
            if not isinstance(other, Pose):
                raise InputError(f"cannot compose with {type(other).__name__}")
            other = UncertainPose.exact(other)
        pa, pb = self._pose, other._pose
        t, q, c, J_c_a, J_c_b = _kernels.compose(
            pa._p,
            pa._q,
            self._cov,
            pb._p,
            pb._q,
            other._cov,
            None if cross_covariance is None else _as_cross(cross_covariance, self.shape),
        )
        out = UncertainPose._trusted(t, q, c)
        return (out, J_c_a, J_c_b) if jacobians else out

    def __matmul__(self, other):
        if isinstance(other, (UncertainPose, Pose)):
            return self.compose(other)
        return NotImplemented

    def __rmatmul__(self, other):
        if isinstance(other, Pose):
            return UncertainPose.exact(other).compose(self)
        return NotImplemented

    def inverse(self, jacobians: bool = False):
        """``T_b_a`` with covariance ``J C J^T``, ``J = [[-R^T, [t_i]x], [0, -R]]``.

        Returns
        -------
        UncertainPose, or (UncertainPose, J_i_a)
        """
        J = jacobian_inverse(self.position, self.quaternion)
        inv = self._pose.inverse()
        out = UncertainPose._trusted(
            inv.position, inv.quaternion, propagate_covariance(J, self._cov)
        )
        return (out, J) if jacobians else out

    def between(self, other, jacobians: bool = False, cross_covariance=None):
        """The relative pose ``T_b_c = T_a_b^-1 @ T_a_c`` done in one step.

        Uses the chain rule through the inversion (``J_c_a = [[-R_a^T, [t_c]x], [0, -R_c^T]]``,
        ``J_c_b = [[R_a^T, 0], [0, I]]``), so correlated inputs (``cross_covariance =
        E[e_self e_other^T]``) are handled exactly; with independent inputs it equals
        ``self.inverse() @ other``.

        Returns
        -------
        UncertainPose, or (UncertainPose, J_c_a, J_c_b)
        """
        other = _as_uncertain(other, "take the relative pose")
        cross = _as_cross(cross_covariance, self.shape)
        J_c_a, J_c_b = jacobians_between(
            self.position, self.quaternion, other.position, other.quaternion
        )
        mean = self._pose.inverse() @ other._pose
        c = propagate_covariance(J_c_a, self._cov, J_c_b, other._cov, cross)
        out = UncertainPose._trusted(mean.position, mean.quaternion, c)
        return (out, J_c_a, J_c_b) if jacobians else out

    def transform_point(self, point, point_covariance=None, jacobians: bool = False):
        """Map an uncertain point of frame b into frame a: ``x_a = R x_b + t``.

        Parameters
        ----------
        point : array_like, shape (..., 3)
            ``x_b`` in metres.
        point_covariance : array_like, shape (..., 3, 3), optional
            Covariance of ``x_b`` (independent of the pose error); zero if omitted.
        jacobians : bool
            Also return ``J_x_pose`` (..., 3, 6) and ``J_x_point`` (..., 3, 3).

        Returns
        -------
        x_a : ndarray (..., 3)
        C_x : ndarray (..., 3, 3)
            ``J_x_pose C J_x_pose^T + R C_point R^T`` with ``J_x_pose = [I, -R [x_b]x]``.
        """
        x = check_position(point, "point")
        J_x_pose, J_x_point = jacobians_transform_point(self.quaternion, x)
        c = J_x_pose @ self._cov @ np.swapaxes(J_x_pose, -1, -2)
        if point_covariance is not None:
            cp = check_covariance(point_covariance, "point_covariance", size=3)
            c = c + J_x_point @ cp @ np.swapaxes(J_x_point, -1, -2)
        c = 0.5 * (c + np.swapaxes(c, -1, -2))
        x_a = self._pose.transform_points(x)
        return (x_a, c, J_x_pose, J_x_point) if jacobians else (x_a, c)

    def interpolate(self, other, s, jacobians: bool = False, cross_covariance=None):
        """Interpolate towards ``other`` (lerp of position, slerp of rotation), ``s`` in [0, 1].

        ``other`` is an ``UncertainPose`` or a plain ``Pose`` (exact). The rotation follows the
        shortest path, so end points with opposite orientations (relative angle exactly pi) have
        no well-defined interpolation and no Jacobian; near pi the Jacobian stays bounded.

        The covariance is ``J_s_a C_a J_s_a^T + J_s_b C_b J_s_b^T`` (plus cross terms if
        ``cross_covariance`` is given): for independent end points it is smallest between them.

        Returns
        -------
        UncertainPose, or (UncertainPose, J_s_a, J_s_b)
        """
        other = _as_uncertain(other, "interpolate")
        s = np.asarray(s, dtype=float)
        J_s_a, J_s_b = jacobians_interpolate(self.quaternion, other.quaternion, s)
        mean = self._pose.interpolate(other._pose, s)
        cross = _as_cross(cross_covariance, self.shape)
        c = propagate_covariance(J_s_a, self._cov, J_s_b, other._cov, cross)
        out = UncertainPose._trusted(mean.position, mean.quaternion, c)
        return (out, J_s_a, J_s_b) if jacobians else out

    # -- evaluation and visualisation ---------------------------------------------------------
    def evaluate(self, weights=None) -> np.ndarray:
        """Scalar accuracy ``sqrt(trace(A C A^T))`` (thesis eq. 6.26); see
        :func:`evaluate_covariance`."""
        return evaluate_covariance(self._cov, weights)

    def position_ellipsoid(self, sigma: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Semi-axes of the position error ellipsoid in frame a.

        Returns
        -------
        radii : ndarray (..., 3)
            ``sigma * sqrt(eigenvalues)`` of the 3x3 position covariance, ascending, metres.
        axes : ndarray (..., 3, 3)
            Unit axis directions as columns, in frame a.
        """
        return ellipsoid(self._cov[..., :3, :3], sigma)

    def axis_ellipsoids(
        self, length: float = 1.0, sigma: float = 1.0
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Orientation error shown as the displacement of the tips of the body axes.

        For each axis ``k`` of frame b, the tip ``length * e_k`` is displaced in frame a by
        ``-R [length e_k]x dtheta`` (the point-transform propagation with the position error
        set to zero, thesis section 8.2.2.1). The ellipsoid is flat along the axis itself.

        Returns
        -------
        covariances : ndarray (..., 3, 3, 3)
            ``[..., k]`` is the 3x3 displacement covariance of axis ``k`` in frame a.
        radii : ndarray (..., 3, 3)
        axes : ndarray (..., 3, 3, 3)
        """
        c_rot = self._cov[..., 3:, 3:]
        r = quat_to_matrix(self.quaternion)
        covs = []
        for k in range(3):
            e = np.zeros(3)
            e[k] = length
            J = -r @ skew(e)
            covs.append(J @ c_rot @ np.swapaxes(J, -1, -2))
        covs = np.stack(covs, axis=-3)
        radii, axes = ellipsoid(covs, sigma)
        return covs, radii, axes

    # -- construction from data ---------------------------------------------------------------
    @classmethod
    def from_samples(cls, poses: Pose, max_iterations: int = 50) -> UncertainPose:
        """Mean and covariance of repeated measurements of one static pose (thesis 6.1.5).

        The mean rotation is the Karcher (geodesic) mean, found by Gauss-Newton iteration
        ``R <- R Exp(mean_i Log(R^T R_i))``; the covariance is the sample covariance (``N - 1``
        normalisation) of the residuals ``(t_i - t_mean, Log(R_mean^T R_i))``, which is exactly
        this library's error convention.

        Parameters
        ----------
        poses : Pose with batch shape (N,), N >= 2
        """
        if len(poses.shape) != 1 or poses.shape[0] < 2:
            raise InputError(f"from_samples needs a batch of N >= 2 poses, got {poses.shape}")
        t = poses.position
        q = quat_make_continuous(poses.quaternion)
        q_mean = quat_normalize(np.sum(q, axis=0))  # chordal mean as the starting point
        for _ in range(max_iterations):
            step = np.mean(quat_rminus(q, q_mean), axis=0)
            q_mean = quat_normalize(quat_multiply(q_mean, quat_exp(step)))
            if np.linalg.norm(step) < 1e-13:
                break
        t_mean = np.mean(t, axis=0)
        res = np.concatenate([t - t_mean, quat_rminus(q, q_mean)], axis=1)
        cov = res.T @ res / (len(res) - 1)
        return cls._trusted(t_mean, q_mean, 0.5 * (cov + cov.T))


def evaluate_covariance(covariance, weights=None) -> np.ndarray:
    """Scalar accuracy ``sqrt(trace(A C A^T))`` of a covariance (thesis eq. 6.26).

    Parameters
    ----------
    covariance : array_like (..., n, n)
    weights : array_like (k, n), optional
        The application's weighting matrix ``A`` (for example only the position rows, or
        directions perpendicular to the viewing ray). Identity if omitted.

    Returns
    -------
    ndarray (...)
        With ``A = I`` this is the length of the diagonal of the box around the 1-sigma
        ellipsoid (in mixed units of metres and radians unless ``A`` selects or scales them).
    """
    c = np.asarray(covariance, dtype=float)
    if weights is None:
        return np.sqrt(np.maximum(np.trace(c, axis1=-2, axis2=-1), 0.0))
    a = np.asarray(weights, dtype=float)
    if a.shape[-1] != c.shape[-1]:
        raise InputError(f"weights must have {c.shape[-1]} columns, got shape {a.shape}")
    m = a @ c @ np.swapaxes(a, -1, -2)
    return np.sqrt(np.maximum(np.trace(m, axis1=-2, axis2=-1), 0.0))


def ellipsoid(covariance, sigma: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Semi-axis lengths (ascending) and directions (columns) of a covariance ellipsoid."""
    w, v = np.linalg.eigh(np.asarray(covariance, dtype=float))
    return sigma * np.sqrt(np.maximum(w, 0.0)), v
