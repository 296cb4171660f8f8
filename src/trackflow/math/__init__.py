"""Uncertain-pose mathematics: quaternions, poses, covariances and their propagation.

Conventions (frames, quaternion order, error model) are in ``docs/conventions.md``.
"""

from ._backend import frozen, get_backend, numba_available, set_backend, use_backend
from ._backend import kernels as kernels_for
from ._checks import (
    UNIT_TOLERANCE,
    check_covariance,
    check_position,
    check_quaternion,
    check_trajectory,
)
from ._covariance import (
    cov_from_additive_quaternion,
    cov_from_gtsam,
    cov_from_ros,
    cov_from_thesis,
    cov_to_additive_quaternion,
    cov_to_gtsam,
    cov_to_ros,
    cov_to_thesis,
    quat_left_matrix,
)
from ._jacobians import (
    jacobian_inverse,
    jacobians_between,
    jacobians_compose,
    jacobians_interpolate,
    jacobians_transform_point,
    propagate_covariance,
)
from ._pose import Pose
from ._quaternion import (
    quat_align_sign,
    quat_angle,
    quat_conjugate,
    quat_exp,
    quat_from_matrix,
    quat_identity,
    quat_log,
    quat_make_continuous,
    quat_multiply,
    quat_normalize,
    quat_rotate,
    quat_slerp,
    quat_to_matrix,
    skew,
    so3_right_jacobian,
    so3_right_jacobian_inverse,
)
from ._uncertain import UncertainPose, ellipsoid, evaluate_covariance

__all__ = [
    "UNIT_TOLERANCE",
    "Pose",
    "UncertainPose",
    "check_covariance",
    "check_position",
    "check_quaternion",
    "check_trajectory",
    "cov_from_additive_quaternion",
    "cov_from_gtsam",
    "cov_from_ros",
    "cov_from_thesis",
    "cov_to_additive_quaternion",
    "cov_to_gtsam",
    "cov_to_ros",
    "cov_to_thesis",
    "ellipsoid",
    "evaluate_covariance",
    "frozen",
    "get_backend",
    "jacobian_inverse",
    "kernels_for",
    "jacobians_between",
    "jacobians_compose",
    "jacobians_interpolate",
    "jacobians_transform_point",
    "numba_available",
    "propagate_covariance",
    "quat_align_sign",
    "quat_angle",
    "quat_conjugate",
    "quat_exp",
    "quat_from_matrix",
    "quat_identity",
    "quat_left_matrix",
    "quat_log",
    "quat_make_continuous",
    "quat_multiply",
    "quat_normalize",
    "quat_rotate",
    "quat_slerp",
    "quat_to_matrix",
    "set_backend",
    "skew",
    "so3_right_jacobian",
    "so3_right_jacobian_inverse",
    "use_backend",
]
