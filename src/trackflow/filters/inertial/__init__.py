"""IMU-aided pose filtering (thesis 10.3.3): an error-state Kalman filter driven by an IMU.

* :mod:`.model`: ``InertialModel`` (mode, ``ImuNoise``, ``ImuExtrinsics`` ``T_b_s``, gravity).
* :mod:`.kernel`: the strapdown step, the pose and gravity updates and their Jacobians.
* :mod:`.driver`: ``InertialFilter`` (streaming), ``run_inertial`` (whole recordings) and
  ``run_imu_orientation`` (IMU alone).
* :mod:`.calibration`: noise from a static segment (Allan deviation), clock offset, IMU-to-body
  rotation and gravity from data.

See ``docs/inertial.md``.
"""

from .calibration import (
    allan_deviation,
    angular_velocity_from_poses,
    estimate_clock_offset,
    estimate_gravity,
    estimate_imu_rotation,
    noise_from_static,
    world_acceleration,
)
from .driver import (
    InertialFilter,
    InertialResult,
    InertialState,
    run_imu_orientation,
    run_inertial,
    tilt_from_accel,
)
from .extrapolation import GyroExtrapolation, fit_gyro_extrapolation
from .model import GRAVITY, MODES, ImuExtrinsics, ImuNoise, InertialModel

__all__ = [
    "GRAVITY",
    "GyroExtrapolation",
    "fit_gyro_extrapolation",
    "MODES",
    "ImuExtrinsics",
    "ImuNoise",
    "InertialFilter",
    "InertialModel",
    "InertialResult",
    "InertialState",
    "allan_deviation",
    "angular_velocity_from_poses",
    "estimate_clock_offset",
    "estimate_gravity",
    "estimate_imu_rotation",
    "noise_from_static",
    "run_imu_orientation",
    "run_inertial",
    "tilt_from_accel",
    "world_acceleration",
]
