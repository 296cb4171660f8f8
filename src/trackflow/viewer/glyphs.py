"""Error glyphs of an uncertain pose (thesis 8.2.2.1): pure geometry, no drawing.

* The position error ellipsoid: the eigen decomposition of the 3x3 position block of the 6x6
  covariance, scaled by the sigma level, centred on the pose's position.
* The orientation error as the thesis's axis ellipsoids: for each body axis ``k`` the tip
  ``length * e_k`` is displaced by the rotation error alone (:meth:`UncertainPose.axis_ellipsoids`);
  its ellipsoid is flat along the axis.

Eigenvectors come sorted by eigenvalue, so an ellipsoid whose two axes swap order between two
updates would spin on screen; :func:`stable_axes` re-sorts them to match the previous update
(thesis 8.2.3). Everything is in the pose's frame ``a`` (``T_a_b``); rotations are returned as
viser's ``(w, x, y, z)`` at this boundary only (trackflow itself uses ``(x, y, z, w)``).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import permutations

import numpy as np

from ..math import UncertainPose, ellipsoid, quat_from_matrix, quat_to_matrix

__all__ = ["Ellipsoid", "orientation_glyphs", "position_glyph", "stable_axes", "to_wxyz"]

#: Smallest drawn semi-axis [m]: a flat axis ellipsoid is drawn as a thin disc.
MIN_RADIUS = 1e-5


@dataclass(frozen=True)
class Ellipsoid:
    """An ellipsoid to draw: a unit sphere scaled by ``radii`` along the columns of ``axes``.

    Attributes
    ----------
    center : ndarray (3,)
        Centre in frame a [m].
    radii : ndarray (3,)
        Semi-axis lengths [m] at the chosen sigma level.
    axes : ndarray (3, 3)
        Right-handed orthonormal axis directions as columns, in frame a.
    """

    center: np.ndarray
    radii: np.ndarray
    axes: np.ndarray

    @property
    def wxyz(self) -> np.ndarray:
        """Rotation of the axes as a ``(w, x, y, z)`` quaternion (viser's order)."""
        return to_wxyz(quat_from_matrix(self.axes))

    @property
    def scale(self) -> tuple[float, float, float]:
        """Radii with the drawing floor :data:`MIN_RADIUS` applied."""
        r = np.maximum(self.radii, MIN_RADIUS)
        return float(r[0]), float(r[1]), float(r[2])


def to_wxyz(q_xyzw: np.ndarray) -> np.ndarray:
    """``(x, y, z, w)`` -> ``(w, x, y, z)`` (viser's order), shape (..., 4)."""
    q = np.asarray(q_xyzw, dtype=float)
    return np.concatenate([q[..., 3:], q[..., :3]], axis=-1)


_PERMS = np.array(list(permutations(range(3))))  # (6, 3)


def stable_axes(
    radii: np.ndarray, axes: np.ndarray, previous: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """Reorder and re-sign eigenvectors to follow ``previous`` (thesis 8.2.3).

    Parameters
    ----------
    radii : ndarray (..., 3)
        Semi-axes in eigenvalue order.
    axes : ndarray (..., 3, 3)
        Matching unit directions as columns.
    previous : ndarray (..., 3, 3) or None
        The axes drawn last time (columns).

    Returns
    -------
    radii, axes
        Permuted so that column ``k`` is the one closest to ``previous[..., :, k]`` (the
        permutation with the largest summed overlap), each column's sign chosen to point the
        same way, and the frame made right-handed by flipping the smallest axis if needed.
    """
    radii = np.array(radii, dtype=float)
    axes = np.array(axes, dtype=float)
    shape = radii.shape
    r, a = radii.reshape(-1, 3), axes.reshape(-1, 3, 3)
    if previous is not None:
        prev = np.asarray(previous, float).reshape(-1, 3, 3)
        overlap = np.abs(np.einsum("nik,nij->nkj", prev, a))  # [n, k, j] = |prev_k . new_j|
        score = overlap[:, np.arange(3), _PERMS].sum(axis=-1)  # (n, 6)
        best = _PERMS[np.argmax(score, axis=1)]  # (n, 3)
        r = np.take_along_axis(r, best, axis=1)
        a = np.take_along_axis(a, best[:, None, :], axis=2)
        signs = np.sign(np.einsum("nij,nij->nj", prev, a))
        a = a * np.where(signs == 0, 1.0, signs)[:, None, :]
    left = np.linalg.det(a) < 0
    if left.any():
        # flip the smallest axis (a flat ellipsoid's normal: a flip is invisible there)
        k = np.argmin(r, axis=1)
        idx = np.flatnonzero(left)
        a[idx, :, k[idx]] *= -1.0
    return r.reshape(shape), a.reshape(*shape, 3)


def position_glyph(
    pose: UncertainPose, sigma: float = 1.0, previous: Ellipsoid | None = None
) -> Ellipsoid:
    """The position error ellipsoid of one pose ``T_a_b`` in frame a at ``sigma``."""
    radii, axes = pose.position_ellipsoid(sigma)
    radii, axes = stable_axes(radii, axes, None if previous is None else previous.axes)
    return Ellipsoid(np.asarray(pose.position, float), radii, axes)


def orientation_glyphs(
    pose: UncertainPose,
    sigma: float = 1.0,
    length: float = 0.1,
    previous: tuple[Ellipsoid, ...] | None = None,
) -> tuple[Ellipsoid, Ellipsoid, Ellipsoid]:
    """The three axis ellipsoids: where the tips of the body axes (length ``length`` [m])
    may lie because of the rotation error alone, at ``sigma``, in frame a."""
    covs, _, _ = pose.axis_ellipsoids(length, 1.0)
    r_ab = quat_to_matrix(pose.quaternion)
    out = []
    for k in range(3):
        radii, axes = ellipsoid(covs[k], sigma)
        prev = None if previous is None else previous[k].axes
        radii, axes = stable_axes(radii, axes, prev)
        tip = np.asarray(pose.position, float) + length * r_ab[:, k]
        out.append(Ellipsoid(tip, radii, axes))
    return tuple(out)
