"""Ude's filter in the unit-quaternion space, adjusted by Gauss-Newton on the manifold (seed 003).

``gauss_newton`` (:class:`QuaternionSpaceFilter`), ``camera_features`` (the image features it
adjusts to: :class:`PinholeCamera`, :class:`CameraObservation`) and ``streaming``
(:class:`QuaternionSpacePoseFilter`, the filter behind the streaming pose-filter contract). See
``docs/seed_filter_quaternion_space.md``.
"""

from .camera_features import CameraObservation, PinholeCamera
from .gauss_newton import QuaternionSpaceFilter, QuaternionSpaceState, estimate_pose
from .streaming import QuaternionSpacePoseFilter

__all__ = [
    "CameraObservation",
    "PinholeCamera",
    "QuaternionSpaceFilter",
    "QuaternionSpacePoseFilter",
    "QuaternionSpaceState",
    "estimate_pose",
]
