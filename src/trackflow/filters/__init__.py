"""Pose filters.

* The thesis's pose Kalman filter built from motion models (Pustka, chapters 5.3, 6.2, 6.3):
  ``PoseKalmanFilter`` (streaming: predict, interpolate, fuse, estimate static poses),
  ``MotionModel`` (state layout and process noise) and ``run_filter`` (whole recordings).
  See ``docs/filters.md``.
* Dorfmueller-Ulhaas's EKF on relative rigid-body motion: ``RelativeMotionEKF``
  (module ``relative_motion``; ``docs/seed_filter_relative_motion.md``).
* Ude's filter in the unit-quaternion space, adjusted by Gauss-Newton on the manifold:
  ``QuaternionSpaceFilter`` with ``PinholeCamera`` / ``CameraObservation`` features
  (modules ``manifold_gn`` and ``camera_features``; ``docs/seed_filter_quaternion_space.md``).

``RelativeMotionPoseFilter`` and ``QuaternionSpacePoseFilter`` give the two seed filters the
streaming protocol of ``PoseKalmanFilter`` (``update_pose``/``predict``), so the dataflow can use
them through ``filter_factory`` (``relative_motion_factory``, ``quaternion_space_factory``).
* A Kalman filter on learned dynamics: ``TwistARModel`` (a vector autoregression of
  body-frame pose increments, fitted to a recording) and ``run_twist_ar`` (module
  ``twist_ar``; ``docs/filters.md``), which the evaluation's tuning uses where it predicts
  better than the derivative models.

All of them deliver ``trackflow.UncertainPose`` in the conventions of ``docs/conventions.md``.
"""

from ._kalman import PoseKalmanFilter, chi2_gate
from ._model import FORMULATIONS, MotionModel
from ._offline import FilterResult, run_filter
from .camera_features import CameraObservation, PinholeCamera
from .manifold_gn import QuaternionSpaceFilter, QuaternionSpaceState, estimate_pose
from .relative_motion import RelativeMotionEKF, RelativeMotionState
from .seed_adapters import (
    QuaternionSpacePoseFilter,
    RelativeMotionPoseFilter,
    quaternion_space_factory,
    relative_motion_factory,
)
from .twist_ar import (
    TwistARModel,
    TwistARResult,
    body_increments,
    excitation_ratios,
    run_twist_ar,
)

__all__ = [
    "FORMULATIONS",
    "CameraObservation",
    "FilterResult",
    "MotionModel",
    "PinholeCamera",
    "PoseKalmanFilter",
    "QuaternionSpaceFilter",
    "QuaternionSpacePoseFilter",
    "QuaternionSpaceState",
    "RelativeMotionEKF",
    "RelativeMotionPoseFilter",
    "RelativeMotionState",
    "TwistARModel",
    "TwistARResult",
    "body_increments",
    "excitation_ratios",
    "chi2_gate",
    "estimate_pose",
    "quaternion_space_factory",
    "relative_motion_factory",
    "run_filter",
    "run_twist_ar",
]
