"""Pose Kalman filters built from motion models (Pustka's thesis, chapters 5.3, 6.2, 6.3).

``PoseKalmanFilter`` (streaming: predict, interpolate, fuse, estimate static poses),
``MotionModel`` (state layout and process noise) and ``run_filter`` (whole recordings).
See ``docs/filters.md``.
"""

from ._kalman import PoseKalmanFilter, chi2_gate
from ._model import FORMULATIONS, MotionModel
from ._offline import FilterResult, run_filter

__all__ = [
    "FORMULATIONS",
    "FilterResult",
    "MotionModel",
    "PoseKalmanFilter",
    "chi2_gate",
    "run_filter",
]
