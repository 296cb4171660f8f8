"""A user-defined measurement (thesis 7.3.2) in the pose Kalman filter: its Jacobian against
finite differences on the curated edge-case rotations, and the filter's consistency with it."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from trackflow import Pose, UncertainPose
from trackflow.filters import (
    MeasurementFunction,
    MotionModel,
    PoseKalmanFilter,
    numerical_jacobian,
)
from trackflow.math import quat_to_matrix, skew

_spec = importlib.util.spec_from_file_location(
    "math_test_helpers", Path(__file__).resolve().parents[1] / "math" / "_helpers.py"
)
_helpers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_helpers)
EDGE_QUATERNIONS = _helpers.EDGE_QUATERNIONS


class BeaconInBody:
    """A beacon at a known point ``b`` (frame a) observed in the body frame:
    ``h(T) = R^T (b - t)``; ``J_h_pose = [-R^T, [h]x]`` over ``(dt, dtheta)``."""

    def __init__(self, beacon, observed, sigma):
        self.beacon = np.asarray(beacon, dtype=float)
        self.observed = np.asarray(observed, dtype=float)
        self.covariance = np.eye(3) * sigma**2

    def predicted(self, pose: Pose) -> np.ndarray:
        return quat_to_matrix(pose.quaternion).T @ (self.beacon - pose.position)

    def residual(self, pose: Pose):
        h = self.predicted(pose)
        J = np.hstack([-quat_to_matrix(pose.quaternion).T, skew(h)])
        return self.observed - h, J


def test_measurement_meets_the_contract():
    assert isinstance(BeaconInBody([1, 2, 3], [0, 0, 0], 1e-3), MeasurementFunction)


@pytest.mark.parametrize("name", sorted(EDGE_QUATERNIONS))
def test_jacobian_matches_finite_differences(name):
    pose = Pose([0.3, -0.2, 1.1], EDGE_QUATERNIONS[name])
    m = BeaconInBody([1.0, 2.0, -0.5], [0.1, 0.2, 0.3], 1e-3)
    _, J = m.residual(pose)
    np.testing.assert_allclose(J, numerical_jacobian(m, pose), atol=1e-7)


def test_a_wrong_jacobian_is_caught():
    pose = Pose([0.3, -0.2, 1.1], EDGE_QUATERNIONS["generic"])
    m = BeaconInBody([1.0, 2.0, -0.5], [0.1, 0.2, 0.3], 1e-3)
    _, J = m.residual(pose)
    J_wrong = J.copy()
    J_wrong[:, 3:] = -J_wrong[:, 3:]  # the sign of the rotation part flipped
    assert np.max(np.abs(J_wrong - numerical_jacobian(m, pose))) > 1e-2


def _run(rng, truth: Pose, beacons, sigma: float) -> UncertainPose:
    """A static filter: a pose prior, then one noisy beacon observation per beacon."""
    kf = PoseKalmanFilter(MotionModel.static(), gate_probability=None)
    # small enough that the first linearisation is good (an EKF, not an iterated one)
    prior_cov = np.diag([0.005**2] * 3 + [0.01**2] * 3)
    e = rng.multivariate_normal(np.zeros(6), prior_cov)
    start = _helpers.retract(truth, e)
    assert kf.update_pose(0.0, UncertainPose(start, prior_cov))
    for k, b in enumerate(beacons):
        clean = BeaconInBody(b, np.zeros(3), sigma).predicted(truth)
        m = BeaconInBody(b, clean + rng.normal(0.0, sigma, 3), sigma)
        assert kf.update_measurement(0.0 + 1e-3 * (k + 1), m)
    return kf.predict(1e-3 * len(beacons))


def test_filter_with_the_measurement_is_consistent():
    rng = np.random.default_rng(7)
    truth = Pose([0.2, 0.1, 1.0], EDGE_QUATERNIONS["generic"])
    beacons = [[1.0, 0.0, 0.0], [0.0, 1.5, 0.2], [-1.0, -0.5, 2.0], [0.5, -1.0, -1.0]] * 3
    nees = []
    for _ in range(300):
        est = _run(rng, truth, beacons, 2e-3)
        err = _helpers.local(est.pose, truth)  # truth = estimate [+] err
        nees.append(err @ np.linalg.solve(est.covariance, err))
    n = len(nees)
    lo, hi = chi2.ppf([0.025, 0.975], 6 * n) / n
    assert lo <= np.mean(nees) <= hi, (np.mean(nees), lo, hi)
    # the beacons shrink the 5 mm prior to about a millimetre
    assert np.sqrt(np.max(np.diag(est.covariance)[:3])) < 1.5e-3


def test_rejections_and_bad_input():
    kf = PoseKalmanFilter(MotionModel(1, 1, noise=(0.0, 1.0, 0.0, 1.0)))
    m = BeaconInBody([1.0, 0.0, 0.0], [1.0, 0.0, 0.0], 1e-3)
    assert not kf.update_measurement(0.0, m)  # no pose yet: counted, not integrated
    assert kf.stats["rejected_uninitialized"] == 1
    kf.update_pose(0.0, UncertainPose(Pose([0, 0, 0], [0, 0, 0, 1]), np.eye(6) * 1e-4))
    far = BeaconInBody([1.0, 0.0, 0.0], [5.0, 0.0, 0.0], 1e-3)  # 4 m off: gated
    assert not kf.update_measurement(0.01, far)
    assert kf.stats["rejected_gate"] == 1
    with pytest.raises(ValueError, match="residual"):
        kf.update_measurement(0.02, object())

    class Broken(BeaconInBody):
        def residual(self, pose):
            return np.zeros(3), np.zeros((3, 5))

    with pytest.raises(ValueError, match=r"J_h_pose \(m, 6\)"):
        kf.update_measurement(0.03, Broken([1.0, 0, 0], [1.0, 0, 0], 1e-3))
    additive = PoseKalmanFilter(MotionModel(1, 1), formulation="additive")
    with pytest.raises(ValueError, match="error_state"):
        additive.update_measurement(0.0, m)
