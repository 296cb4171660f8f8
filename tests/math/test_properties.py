"""Algebraic properties of poses, quaternions and covariance propagation (hypothesis).

The examples are derandomised (the same every run) and kept few, so this file runs in a few
seconds; the settings live in one object applied to each test, not in a global profile.
"""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from trackflow import Pose, UncertainPose
from trackflow.math import quat_angle, quat_exp, quat_log

SETTINGS = settings(
    derandomize=True,
    max_examples=60,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)

_unit_floats = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)


@st.composite
def quaternions(draw):
    v = np.array([draw(_unit_floats) for _ in range(4)])
    n = np.linalg.norm(v)
    if n < 0.1:
        v = np.array([0.0, 0.0, 0.0, 1.0]) + v  # keep it away from zero
        n = np.linalg.norm(v)
    return v / n


@st.composite
def rotation_vectors(draw, max_angle=np.pi - 1e-6):
    axis = np.array([draw(_unit_floats) for _ in range(3)])
    if np.linalg.norm(axis) < 0.1:
        axis = axis + np.array([0.0, 0.0, 1.0])
    angle = draw(
        st.one_of(
            st.floats(0.0, max_angle),
            st.sampled_from([0.0, 1e-12, 1e-8, 1e-4, max_angle]),
        )
    )
    return axis / np.linalg.norm(axis) * angle


@st.composite
def poses(draw):
    t = np.array([draw(st.floats(-10.0, 10.0)) for _ in range(3)])
    return Pose(t, draw(quaternions()))


@st.composite
def covariances(draw):
    """SPD or PSD-singular 6x6 covariances with realistic scales."""
    a = np.array([[draw(_unit_floats) for _ in range(6)] for _ in range(draw(st.integers(1, 6)))])
    s = np.array([draw(st.floats(1e-4, 1e-1)) for _ in range(6)])
    b = a * s[None, :]
    return b.T @ b


@st.composite
def uncertain_poses(draw):
    return UncertainPose(draw(poses()), draw(covariances()))


def _assert_symmetric_psd(c):
    np.testing.assert_array_equal(c, c.T)
    w = np.linalg.eigvalsh(c)
    assert w[0] >= -1e-12 * max(w[-1], 1e-300), w


@SETTINGS
@given(poses(), poses(), poses())
def test_compose_is_associative(a, b, c):
    scale = 1.0 + max(np.abs(x.position).max() for x in (a, b, c))
    assert ((a @ b) @ c).allclose(a @ (b @ c), atol=1e-13 * scale)


@SETTINGS
@given(poses())
def test_pose_times_inverse_is_identity(a):
    scale = 1.0 + np.abs(a.position).max()
    assert (a @ a.inverse()).allclose(Pose.identity(), atol=1e-14 * scale)
    assert (a.inverse() @ a).allclose(Pose.identity(), atol=1e-14 * scale)


@SETTINGS
@given(quaternions())
def test_exp_log_is_identity_up_to_sign(q):
    back = quat_exp(quat_log(q))
    assert np.allclose(back, q, atol=1e-15) or np.allclose(back, -q, atol=1e-15)
    assert np.linalg.norm(quat_log(q)) <= np.pi + 1e-15


@SETTINGS
@given(rotation_vectors())
def test_log_exp_is_identity_below_pi(v):
    back = quat_log(quat_exp(v))
    np.testing.assert_allclose(back, v, rtol=1e-13, atol=1e-15)


@SETTINGS
@given(quaternions(), quaternions())
def test_angle_is_a_symmetric_sign_invariant_distance(p, q):
    a = quat_angle(p, q)
    assert 0.0 <= a <= np.pi + 1e-15
    np.testing.assert_allclose(quat_angle(q, p), a, atol=1e-15)
    np.testing.assert_allclose(quat_angle(p, -q), a, atol=1e-15)


_OPS = st.sampled_from(["compose", "compose_pose", "inverse", "between", "interpolate"])


@SETTINGS
@given(uncertain_poses(), st.lists(st.tuples(_OPS, uncertain_poses(), st.floats(0, 1)), max_size=6))
def test_covariance_stays_symmetric_psd_through_chains(start, steps):
    x = start
    _assert_symmetric_psd(x.covariance)
    for op, other, s in steps:
        if op == "compose":
            x = x @ other
        elif op == "compose_pose":
            x = other.pose @ x
        elif op == "inverse":
            x = x.inverse()
        elif op == "between":
            x = x.between(other)
        else:
            x = x.interpolate(other, s)
        _assert_symmetric_psd(x.covariance)
        assert abs(np.linalg.norm(x.quaternion) - 1.0) < 1e-12
