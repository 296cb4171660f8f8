"""The thesis's pose Kalman filter on derivative motion models (Pustka, chapters 5.3, 6.2, 6.3).

``model`` (:class:`MotionModel`: state layout and process noise), ``kernels`` (the compiled
prediction, update and offline loop), ``streaming`` (:class:`PoseKalmanFilter`: predict,
interpolate, fuse, estimate static poses), ``bank`` (:class:`PoseFilterBank`: the filters of
one packet in one compiled call) and ``offline`` (:func:`run_filter` and the smoother
:func:`smooth_filter` over whole recordings). See ``docs/filters.md``.
"""

from .bank import Layouts, PoseFilterBank, PredictedPoses
from .model import FORMULATIONS, MotionModel
from .offline import FilterResult, run_filter, smooth_filter
from .streaming import FilterSnapshot, KernelSettings, PoseKalmanFilter

__all__ = [
    "FORMULATIONS",
    "FilterResult",
    "FilterSnapshot",
    "KernelSettings",
    "Layouts",
    "MotionModel",
    "PoseFilterBank",
    "PoseKalmanFilter",
    "PredictedPoses",
    "run_filter",
    "smooth_filter",
]
