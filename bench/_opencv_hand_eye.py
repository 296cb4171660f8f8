"""OpenCV's hand-eye solvers as references on trackflow streams (used by bench and tests).

``cv2.calibrateHandEye`` (Tsai, Park, Horaud, Andreff, Daniilidis) and
``cv2.calibrateRobotWorldHandEye`` (Shah, Li) take lists of rotation matrices and translations
in OpenCV's ``X2Y`` naming (``gripper2base`` maps gripper coordinates into the base frame, i.e.
trackflow's ``T_base_gripper``). The conversion happens here and nowhere else:

* ``R_gripper2base, t_gripper2base`` = ``A_k = T_base_tool``;
  ``R_target2cam, t_target2cam`` = ``B_k^-1 = T_body_world``; the result ``cam2gripper`` is
  ``X = T_tool_body``.
* ``R_world2cam, t_world2cam`` = ``B_k^-1``; ``R_base2gripper, t_base2gripper`` = ``A_k^-1``;
  the results ``base2world`` = ``T_world_base`` = ``Z^-1`` and ``gripper2cam`` =
  ``T_body_tool`` = ``X^-1``.

OpenCV is a ``dev``/``bench`` extra, never a runtime dependency of trackflow.
"""

from __future__ import annotations

import numpy as np

from trackflow.io import PoseStream
from trackflow.math import Pose, quat_from_matrix, quat_to_matrix

__all__ = ["HAND_EYE_METHODS", "ROBOT_WORLD_METHODS", "opencv_solutions", "stations"]

HAND_EYE_METHODS = ("TSAI", "PARK", "HORAUD", "ANDREFF", "DANIILIDIS")
ROBOT_WORLD_METHODS = ("SHAH", "LI")


def stations(robot: PoseStream, sensor: PoseStream, offset_s: float, spacing_s: float):
    """Robot samples every ``spacing_s`` inside the overlap and the sensor interpolated there.

    Returns ``(A, B)`` as Poses (M,) with ``t_robot = t_sensor + offset_s``.
    """
    from trackflow.calibration._sampling import common_epoch_ns, trajectory

    e = common_epoch_ns(robot, sensor)
    ta, tb = trajectory(robot, e), trajectory(sensor, e)
    lo = max(ta.t[0], tb.t[0] + offset_s) + 0.1
    hi = min(ta.t[-1], tb.t[-1] + offset_s) - 0.1
    t = np.arange(lo, hi, spacing_s)
    A, B = ta.sample(t), tb.sample(t - offset_s)
    ok = A.valid & B.valid
    return Pose(A.p[ok], A.q[ok], normalize=True), Pose(B.p[ok], B.q[ok], normalize=True)


def _split(p: Pose):
    return list(quat_to_matrix(p.quaternion)), list(p.position.reshape(-1, 3, 1))


def _pose(R, t) -> Pose:
    return Pose(np.asarray(t, float).reshape(3), quat_from_matrix(np.asarray(R, float)))


def opencv_solutions(A: Pose, B: Pose) -> dict[str, tuple[Pose, Pose | None]]:
    """Every OpenCV method's ``(X, Z or None)`` from station poses A (T_base_tool), B."""
    import cv2

    RA, tA = _split(A)
    RBi, tBi = _split(B.inverse())
    RAi, tAi = _split(A.inverse())
    out: dict[str, tuple[Pose, Pose | None]] = {}
    for m in HAND_EYE_METHODS:
        R, t = cv2.calibrateHandEye(RA, tA, RBi, tBi, method=getattr(cv2, f"CALIB_HAND_EYE_{m}"))
        out[m] = (_pose(R, t), None)
    for m in ROBOT_WORLD_METHODS:
        Rbw, tbw, Rgc, tgc = cv2.calibrateRobotWorldHandEye(
            RBi, tBi, RAi, tAi, method=getattr(cv2, f"CALIB_ROBOT_WORLD_HAND_EYE_{m}")
        )
        out[m] = (_pose(Rgc, tgc).inverse(), _pose(Rbw, tbw).inverse())
    return out
