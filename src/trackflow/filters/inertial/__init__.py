"""IMU-aided pose filtering (thesis 10.3.3): an error-state Kalman filter driven by an IMU.

* :mod:`.model`: ``InertialModel`` (mode, ``ImuNoise``, ``ImuExtrinsics`` ``T_b_s``, gravity).
* :mod:`.kernel`: the strapdown step, the pose and gravity updates and their Jacobians.
* :mod:`.driver`: ``InertialFilter`` (streaming) and ``run_inertial`` (whole recordings).
* :mod:`.orientation`: orientation from the IMU alone (gyro and accelerometer, optionally
  magnetometer): ``run_imu_orientation`` (recordings) and ``ImuOrientationFilter`` (live);
  kernels in :mod:`.orientation_kernel`.
* :mod:`.calibration`: noise from a static segment (Allan deviation), clock offset, IMU-to-body
  rotation and gravity from data.

See ``docs/inertial.md``.
"""

from .calibration import (
    allan_deviation,
    angular_velocity_from_poses,
    estimate_gravity,
    estimate_imu_rotation,
    imu_clock_offset,
    noise_from_static,
    world_acceleration,
)
from .driver import (
    InertialFilter,
    InertialResult,
    InertialState,
    run_inertial,
)
from .extrapolation import GyroExtrapolation, fit_gyro_extrapolation
from .model import GRAVITY, MODES, ImuExtrinsics, ImuNoise, InertialModel
from .orientation import (
    ImuOrientationFilter,
    ImuOrientationModel,
    ImuOrientationResult,
    heading_inclination_errors,
    initial_orientation,
    run_imu_orientation,
)

__all__ = [
    "GRAVITY",
    "GyroExtrapolation",
    "fit_gyro_extrapolation",
    "MODES",
    "ImuExtrinsics",
    "ImuNoise",
    "ImuOrientationFilter",
    "ImuOrientationModel",
    "ImuOrientationResult",
    "InertialFilter",
    "InertialModel",
    "InertialResult",
    "InertialState",
    "allan_deviation",
    "angular_velocity_from_poses",
    "imu_clock_offset",
    "estimate_gravity",
    "estimate_imu_rotation",
    "heading_inclination_errors",
    "initial_orientation",
    "noise_from_static",
    "run_imu_orientation",
    "run_inertial",
    "world_acceleration",
]
