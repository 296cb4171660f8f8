"""Every streaming family meets the one filter contract and applies the one gate policy."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow import Pose, UncertainPose
from trackflow.filters import (
    FilterStatus,
    GatePolicy,
    MotionModel,
    PoseFilter,
    PoseKalmanFilter,
    QuaternionSpacePoseFilter,
    RelativeMotionPoseFilter,
)

FAMILIES = {
    "derivative": lambda **kw: PoseKalmanFilter(MotionModel(1, 1, noise=(0, 1, 0, 1)), **kw),
    "relative_motion": lambda **kw: RelativeMotionPoseFilter(1.0, 1.0, **kw),
    "quaternion_space": lambda **kw: QuaternionSpacePoseFilter(1.0, 1.0, **kw),
}
C = np.diag([1e-6] * 3 + [1e-5] * 3)


@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_meets_the_protocol(family):
    f = FAMILIES[family]()
    assert isinstance(f, PoseFilter)
    assert not f.initialized and f.time is None


@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_one_gate_and_reset_policy(family):
    """A far outlier is gated; ``reset_after`` of them in a row re-initialise the filter on the
    next absolute measurement, which the filter then reports from."""
    f = FAMILIES[family](gate_probability=0.999, reset_after=2)
    for k in range(5):
        assert f.update_pose(0.01 * k, UncertainPose(Pose([0.001 * k, 0, 0], [0, 0, 0, 1]), C))
    far = UncertainPose(Pose([5.0, 0, 0], [0, 0, 0, 1]), C)
    assert not f.update_pose(0.05, far)
    assert not f.update_pose(0.06, far)
    assert f.stats["rejected_gate"] == 2
    assert f.update_pose(0.07, far)  # the third: the filter restarts on it
    assert f.stats["resets"] == 1
    np.testing.assert_allclose(f.predict(0.07).position, [5.0, 0, 0], atol=1e-6)


def test_policy_validates_and_gates():
    with pytest.raises(ValueError, match="gate_probability"):
        GatePolicy(gate_probability=1.5)
    with pytest.raises(ValueError, match="reset_after"):
        GatePolicy(reset_after=0)
    assert GatePolicy(gate_probability=None).threshold(6) == np.inf
    assert GatePolicy(0.999).threshold(6) > GatePolicy(0.99).threshold(6)


def test_status_codes_are_the_offline_codes():
    # the int8 codes of FilterResult.status / TwistARResult.status (docs/filters.md)
    assert [int(s) for s in FilterStatus] == [0, 1, 2, 3, 4, 5]
    assert FilterStatus(1) is FilterStatus.GATED
