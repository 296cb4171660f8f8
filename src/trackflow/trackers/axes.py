"""Boundary conversions of live poses: wire units and Y-up frames (``docs/conventions.md``).

A Y-up tracker (Motive's default, Unity, OpenGL: x right, y up, z towards the viewer) is
turned into a Z-up one (x right, y forward, z up) by the rotation ``M`` of +90 degrees about
x: ``(x, y, z) -> (x, -z, y)``. Both the tracker's frame and the body's frame are converted,
``T' = M T M^T``: ``t' = M t``, ``R' = M R M^T``; covariance ``(dt, dtheta)`` maps with
``blockdiag(M, M)`` (``R' Exp(M dtheta) = M R Exp(dtheta) M^T``).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..math import quat_multiply

__all__ = ["Y_UP_TO_Z_UP", "BoundaryConversion"]

#: ``M``: a Y-up vector expressed in the Z-up frame.
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
_QM = np.array([np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)])  # quaternion of M (x, y, z, w)
_QM_INV = np.array([-np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)])


class BoundaryConversion:
    """Scale positions to metres and optionally convert Y-up to Z-up.

    Parameters
    ----------
    unit_scale : float
        Metres per wire unit.
    up : str
        ``"z"`` (as sent) or ``"y"``.
    """

    def __init__(self, unit_scale: float = 1.0, up: str = "z"):
        if up not in ("y", "z"):
            raise InputError(f"up must be 'y' or 'z', got {up!r}")
        self.scale = float(unit_scale)
        self.up = up

    def pose(self, position, quaternion) -> tuple[np.ndarray, np.ndarray]:
        """``(t [m] (..., 3), q (x, y, z, w) (..., 4))`` in trackflow frames (batches too)."""
        p = np.asarray(position, dtype=float) * self.scale
        q = np.asarray(quaternion, dtype=float)
        if self.up == "y":
            p = p @ Y_UP_TO_Z_UP.T
            q = quat_multiply(quat_multiply(_QM, q), _QM_INV)
        return p, q

    def covariance(self, covariance: np.ndarray) -> np.ndarray:
        """A 6x6 ``(dt [m], dtheta [rad])`` covariance (already in metres) in the new frames."""
        if self.up == "z":
            return covariance
        J = np.zeros((6, 6))
        J[:3, :3] = J[3:, 3:] = Y_UP_TO_Z_UP
        return J @ covariance @ J.T
