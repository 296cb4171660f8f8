"""Closed-form building blocks shared by the estimators (internal)."""

from __future__ import annotations

import numpy as np

from ..math import quat_from_matrix, quat_to_matrix

__all__ = ["mean_rotation", "rotation_axis_spread"]


def mean_rotation(q: np.ndarray) -> np.ndarray:
    """Chordal mean of unit quaternions ``q`` (M, 4): the top eigenvector of ``sum q q^T``."""
    q = np.asarray(q, float)
    _, vecs = np.linalg.eigh(q.T @ q)
    m = vecs[:, -1]
    return m if m[3] >= 0 else -m


def rotation_axis_spread(rotvecs: np.ndarray) -> float:
    """Ratio of the second to the first singular value of stacked rotation vectors (M, 3).

    0 when every rotation is about one axis (hand-eye translation along it is unobservable),
    up to 1 for rotations about well spread axes.
    """
    s = np.linalg.svd(np.asarray(rotvecs, float), compute_uv=False)
    return float(s[1] / s[0]) if s[0] > 0 else 0.0


def matrix_quaternion(R: np.ndarray) -> np.ndarray:
    """``quat_from_matrix`` with the sign fixed to ``w >= 0``."""
    q = quat_from_matrix(R)
    return q if q[3] >= 0 else -q


def rotation(q: np.ndarray) -> np.ndarray:
    return quat_to_matrix(np.asarray(q, float))
