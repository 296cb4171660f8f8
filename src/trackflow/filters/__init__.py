"""Pose filters, one folder per family, all behind one contract.

* ``contract``: :class:`PoseFilter` (the streaming protocol the dataflow relies on),
  :class:`FilterStatus` (one status code set) and :class:`MeasurementFunction` (user-defined
  measurements with their Jacobian, thesis 7.3.2).
* ``gating``: one gate and reset policy (:class:`GatePolicy`) for every family and both
  drivers (streaming and offline).
* ``derivative``: the thesis's pose Kalman filter built from motion models (chapters 5.3, 6.2,
  6.3): :class:`PoseKalmanFilter`, :class:`MotionModel`, :func:`run_filter`.
* ``twist_ar``: a Kalman filter on learned dynamics (:class:`TwistARModel`, a vector
  autoregression of body-frame pose increments fitted to a recording; :func:`run_twist_ar`).
* ``relative_motion``: Dorfmueller-Ulhaas's EKF on relative rigid-body motion
  (:class:`RelativeMotionEKF`, :class:`RelativeMotionPoseFilter`).
* ``quaternion_space``: Ude's filter in the unit-quaternion space, adjusted by Gauss-Newton on
  the manifold (:class:`QuaternionSpaceFilter`, :class:`QuaternionSpacePoseFilter`, with
  :class:`PinholeCamera` / :class:`CameraObservation` features).
* ``factory``: the filter the dataflow builds for a relationship (:func:`make_filter`, and the
  seed filters' factories).

* ``inertial``: IMU-aided tracking (thesis 10.3.3): :class:`InertialFilter` /
  :func:`run_inertial`, an error-state filter driven by gyro and accelerometer (or the gyro
  alone) and corrected by tracker poses, with biases, gravity and the IMU-to-body pose
  (``docs/inertial.md``).

All of them deliver ``trackflow.UncertainPose`` in the conventions of ``docs/conventions.md``;
``docs/architecture.md`` maps the package.
"""

from .contract import STATS_KEYS, FilterStatus, MeasurementFunction, PoseFilter
from .derivative import (
    FORMULATIONS,
    FilterResult,
    FilterSnapshot,
    Layouts,
    MotionModel,
    PoseFilterBank,
    PoseKalmanFilter,
    PredictedPoses,
    run_filter,
    smooth_filter,
)
from .factory import (
    constant_velocity_densities,
    filter_noise,
    make_filter,
    quaternion_space_factory,
    relative_motion_factory,
)
from .gating import GatePolicy, chi2_gate
from .inertial import (
    ImuExtrinsics,
    ImuNoise,
    ImuOrientationFilter,
    ImuOrientationModel,
    InertialFilter,
    InertialModel,
    estimate_imu_rotation,
    heading_inclination_errors,
    noise_from_static,
    run_imu_orientation,
    run_inertial,
)
from .measurements import numerical_jacobian
from .quaternion_space import (
    CameraObservation,
    PinholeCamera,
    QuaternionSpaceFilter,
    QuaternionSpacePoseFilter,
    QuaternionSpaceState,
    estimate_pose,
)
from .relative_motion import RelativeMotionEKF, RelativeMotionPoseFilter, RelativeMotionState
from .twist_ar import (
    TwistARModel,
    TwistARResult,
    body_increments,
    excitation_ratios,
    run_twist_ar,
)

__all__ = [
    "FORMULATIONS",
    "STATS_KEYS",
    "CameraObservation",
    "FilterResult",
    "FilterSnapshot",
    "FilterStatus",
    "GatePolicy",
    "MeasurementFunction",
    "ImuExtrinsics",
    "ImuNoise",
    "ImuOrientationFilter",
    "ImuOrientationModel",
    "InertialFilter",
    "InertialModel",
    "Layouts",
    "MotionModel",
    "PinholeCamera",
    "PoseFilter",
    "PoseFilterBank",
    "PoseKalmanFilter",
    "PredictedPoses",
    "QuaternionSpaceFilter",
    "QuaternionSpacePoseFilter",
    "QuaternionSpaceState",
    "RelativeMotionEKF",
    "RelativeMotionPoseFilter",
    "RelativeMotionState",
    "TwistARModel",
    "TwistARResult",
    "body_increments",
    "chi2_gate",
    "constant_velocity_densities",
    "estimate_pose",
    "excitation_ratios",
    "filter_noise",
    "make_filter",
    "numerical_jacobian",
    "estimate_imu_rotation",
    "heading_inclination_errors",
    "noise_from_static",
    "run_imu_orientation",
    "run_inertial",
    "quaternion_space_factory",
    "relative_motion_factory",
    "run_filter",
    "smooth_filter",
    "run_twist_ar",
]
