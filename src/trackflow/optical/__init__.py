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

from .absolute_orientation import PoseFit, fit_pose
from .blobs import Blobs, detect_blobs
from .calibration import CalibrationFileError, read_opencv_calibration, write_opencv_calibration
from .camera import Camera, CameraRig, ring_rig
from .correspondence import PointCandidates, match_epipolar
from .live import OpticalFeed, optical_feed
from .matching import BodyMatch, identify, pose_nis
from .models import MarkerModel, model_separation, random_model, similar_model
from .pipeline import BodyResult, FrameResult, OpticalTracker, TrackerConfig
from .render import Cylinder, Frame, FrameRenderer, RenderSettings, trajectory_from_stream
from .source import (
    OpticalBodySensor,
    OpticalRun,
    OpticalSetup,
    RenderedFrames,
    load_optical_setup,
)
from .triangulation import Triangulation, triangulate, triangulate_linear

__all__ = [
    "OpticalFeed",
    "optical_feed",
    "Blobs",
    "BodyMatch",
    "BodyResult",
    "CalibrationFileError",
    "Camera",
    "CameraRig",
    "Cylinder",
    "Frame",
    "FrameRenderer",
    "FrameResult",
    "MarkerModel",
    "OpticalBodySensor",
    "OpticalRun",
    "OpticalSetup",
    "OpticalTracker",
    "PointCandidates",
    "PoseFit",
    "RenderSettings",
    "RenderedFrames",
    "TrackerConfig",
    "Triangulation",
    "detect_blobs",
    "fit_pose",
    "identify",
    "load_optical_setup",
    "match_epipolar",
    "model_separation",
    "pose_nis",
    "random_model",
    "read_opencv_calibration",
    "ring_rig",
    "similar_model",
    "trajectory_from_stream",
    "triangulate",
    "triangulate_linear",
    "write_opencv_calibration",
]
