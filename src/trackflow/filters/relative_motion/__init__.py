"""Dorfmueller-Ulhaas's EKF on relative rigid-body motion (seed 000, section 3).

``ekf`` (:class:`RelativeMotionEKF`, the paper's filter and its motion matrices) and
``streaming`` (:class:`RelativeMotionPoseFilter`, the filter behind the streaming pose-filter
contract). See ``docs/seed_filter_relative_motion.md``.
"""

from .ekf import RelativeMotionEKF, RelativeMotionState
from .streaming import RelativeMotionPoseFilter

__all__ = ["RelativeMotionEKF", "RelativeMotionPoseFilter", "RelativeMotionState"]
