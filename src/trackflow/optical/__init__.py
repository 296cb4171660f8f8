"""The optical tracker of Dorfmueller-Ulhaas (section 2): infrared marker images to poses.

Calibrated cameras (:mod:`.camera`, OpenCV files in :mod:`.calibration`), blob detection
(:mod:`.blobs`), epipolar correspondence (:mod:`.correspondence`), triangulation with a 3x3
covariance per point (:mod:`.triangulation`), rigid marker models and their identification
among unlabelled points (:mod:`.models`, :mod:`.matching`), the pose by absolute orientation
with its 6x6 covariance (:mod:`.absolute_orientation`), a renderer of realistic infrared
frames (:mod:`.render`) and the whole pipeline guided by the pose Kalman filter
(:mod:`.pipeline`), which plugs into the dataflow as a sensor (:mod:`.source`).
Conventions: ``docs/conventions.md``; the tracker: ``docs/optical.md``.
"""

from .absolute_orientation import PoseFit, fit_pose, umeyama
from .calibration import CalibrationFileError, read_opencv_calibration, write_opencv_calibration
from .camera import Camera, CameraRig, ring_rig
from .triangulation import Triangulation, triangulate, triangulate_linear

__all__ = [
    "CalibrationFileError",
    "Camera",
    "CameraRig",
    "PoseFit",
    "Triangulation",
    "fit_pose",
    "read_opencv_calibration",
    "ring_rig",
    "triangulate",
    "triangulate_linear",
    "umeyama",
    "write_opencv_calibration",
]
