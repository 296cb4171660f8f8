"""``UncertainPose`` API behaviour: construction, batches, operators, special cases.

Propagation accuracy is tested against Monte Carlo in ``test_montecarlo.py`` and Jacobians
against finite differences in ``test_jacobians.py``; this file checks the behaviour around them:
exact cases with known answers, batches equal loops, operators, and bad input.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from trackflow import Pose, UncertainPose


def _cov(rng, pos=1e-3, rot=1e-2) -> np.ndarray:
    a = rng.normal(size=(6, 6))
    s = np.array([pos] * 3 + [rot] * 3)
    return (a @ a.T + np.eye(6)) * s[:, None] * s[None, :] / 6.0


def _up(rng, shape=()) -> UncertainPose:
    n = int(np.prod(shape)) if shape else 1
    q = Rotation.random(n, random_state=rng).as_quat().reshape(tuple(shape) + (4,))
    p = rng.normal(size=tuple(shape) + (3,))
    c = np.stack([_cov(rng) for _ in range(n)]).reshape(tuple(shape) + (6, 6))
    return UncertainPose(Pose(p, q), c)


def test_attributes_and_exact(rng):
    a = _up(rng)
    assert a.shape == ()
    assert a.pose == Pose(a.position, a.quaternion)
    e = UncertainPose.exact(a.pose)
    np.testing.assert_array_equal(e.covariance, np.zeros((6, 6)))
    assert e.pose == a.pose
    eb = UncertainPose.exact(Pose.identity((4, 2)))
    assert eb.covariance.shape == (4, 2, 6, 6)


def test_exact_poses_stay_exact_and_identity_is_neutral(rng):
    a, b = _up(rng), _up(rng)
    ea, eb = UncertainPose.exact(a.pose), UncertainPose.exact(b.pose)
    for out in (ea @ eb, ea.inverse(), ea.between(eb), ea.interpolate(eb, 0.3)):
        np.testing.assert_array_equal(out.covariance, np.zeros((6, 6)))
    ident = UncertainPose.exact(Pose.identity())
    np.testing.assert_allclose((a @ ident).covariance, a.covariance, rtol=1e-14, atol=0)
    # identity on the left: same covariance (translation and right rotation error unchanged)
    np.testing.assert_allclose((ident @ a).covariance, a.covariance, rtol=1e-14, atol=0)


def test_compose_with_plain_pose_on_either_side(rng):
    a = _up(rng)
    p = Pose([0.2, -0.1, 0.5], Rotation.from_rotvec([0.3, 0.2, -0.1]).as_quat())
    right = a @ p
    via = a.compose(UncertainPose.exact(p))
    np.testing.assert_array_equal(right.covariance, via.covariance)
    left = p @ a
    assert isinstance(left, UncertainPose)
    ref = UncertainPose.exact(p).compose(a)
    np.testing.assert_array_equal(left.covariance, ref.covariance)
    assert left.pose.allclose(p @ a.pose, atol=1e-15)


def test_compose_returns_jacobians_and_rejects_other_types(rng):
    a, b = _up(rng), _up(rng)
    c, J_c_a, J_c_b = a.compose(b, jacobians=True)
    np.testing.assert_allclose(
        J_c_a @ a.covariance @ J_c_a.T + J_c_b @ b.covariance @ J_c_b.T, c.covariance,
        rtol=1e-12, atol=1e-20,
    )  # fmt: skip
    with pytest.raises(ValueError, match="cannot compose with ndarray"):
        a.compose(np.eye(4))
    with pytest.raises(ValueError, match=r"cross_covariance must be finite with shape"):
        a.compose(b, cross_covariance=np.eye(3))
    with pytest.raises(ValueError, match=r"cross_covariance must be finite"):
        a.compose(b, cross_covariance=np.full((6, 6), np.nan))


def test_between_self_fully_correlated_is_exact(rng):
    """T_a^-1 @ T_a with the same error on both sides is exactly the identity."""
    a = _up(rng)
    rel = a.between(a, cross_covariance=a.covariance)
    assert rel.pose.allclose(Pose.identity(), atol=1e-14)
    np.testing.assert_allclose(rel.covariance, 0.0, atol=1e-18)
    # independent copies double the uncertainty instead
    ind = a.between(a)
    assert np.trace(ind.covariance) > np.trace(a.covariance)


def test_between_independent_equals_inverse_then_compose(rng):
    a, b = _up(rng), _up(rng)
    one = a.between(b)
    two = a.inverse() @ b
    assert one.pose.allclose(two.pose, atol=1e-14)
    np.testing.assert_allclose(one.covariance, two.covariance, rtol=1e-10, atol=1e-20)
    # and with a plain pose as the second argument
    np.testing.assert_allclose(
        a.between(b.pose).covariance, a.between(UncertainPose.exact(b.pose)).covariance, atol=0
    )


def test_inverse_twice_gives_back_the_covariance(rng):
    a = _up(rng)
    back, J = a.inverse(jacobians=True)
    np.testing.assert_allclose(back.inverse().covariance, a.covariance, rtol=1e-12, atol=1e-20)
    assert J.shape == (6, 6)


def test_interpolate_end_points_and_middle(rng):
    a, b = _up(rng), _up(rng)
    at0 = a.interpolate(b, 0.0)
    at1 = a.interpolate(b, 1.0)
    np.testing.assert_allclose(at0.covariance, a.covariance, rtol=1e-12, atol=1e-20)
    np.testing.assert_allclose(at1.covariance, b.covariance, rtol=1e-9, atol=1e-18)
    # same covariance at both independent ends: position variance is smallest in the middle
    same = UncertainPose(b.pose, a.covariance)
    var = [np.trace(a.interpolate(same, s).covariance[:3, :3]) for s in (0.0, 0.25, 0.5, 1.0)]
    assert var[2] < var[1] < var[0]
    np.testing.assert_allclose(var[2], 0.5 * var[0], rtol=1e-12)  # (1/4 + 1/4) of each
    # s as an array over a single pair
    out = a.interpolate(b, np.linspace(0.0, 1.0, 5))
    assert out.shape == (5,)


def test_transform_point(rng):
    a = _up(rng)
    x = np.array([0.3, -0.2, 1.0])
    xa, cx = a.transform_point(x)
    np.testing.assert_allclose(xa, a.pose.transform_points(x), atol=0)
    assert cx.shape == (3, 3)
    cp = np.diag([1e-4, 2e-4, 3e-4])
    xa2, cx2, J_x_pose, J_x_point = a.transform_point(x, cp, jacobians=True)
    r = a.pose.rotation_matrix
    np.testing.assert_allclose(cx2 - cx, r @ cp @ r.T, rtol=1e-12, atol=1e-20)
    np.testing.assert_allclose(J_x_point, r, atol=1e-15)
    assert J_x_pose.shape == (3, 6)
    # the origin of frame b only sees the translation error
    _, c0 = a.transform_point(np.zeros(3))
    np.testing.assert_allclose(c0, a.covariance[:3, :3], atol=1e-20)
    with pytest.raises(ValueError, match="point_covariance is not positive semi-definite"):
        a.transform_point(x, -np.eye(3))
    with pytest.raises(ValueError, match=r"point must have shape"):
        a.transform_point([1.0, 2.0])


def test_batched_operations_equal_loops(rng):
    a, b = _up(rng, (6,)), _up(rng, (6,))
    results = {
        "compose": a @ b,
        "inverse": a.inverse(),
        "between": a.between(b),
        "interpolate": a.interpolate(b, 0.7),
    }
    for n in range(6):
        single = {
            "compose": a[n] @ b[n],
            "inverse": a[n].inverse(),
            "between": a[n].between(b[n]),
            "interpolate": a[n].interpolate(b[n], 0.7),
        }
        for name, out in results.items():
            assert out[n].pose.allclose(single[name].pose, atol=1e-14), name
            np.testing.assert_allclose(
                out.covariance[n], single[name].covariance, rtol=1e-12, atol=1e-20, err_msg=name
            )
    x = rng.normal(size=(6, 3))
    xa, cx = a.transform_point(x)
    for n in range(6):
        x1, c1 = a[n].transform_point(x[n])
        np.testing.assert_allclose(xa[n], x1, atol=1e-15)
        np.testing.assert_allclose(cx[n], c1, rtol=1e-12, atol=1e-20)


def test_broadcast_single_against_batch(rng):
    a, many = _up(rng), _up(rng, (5,))
    out = a @ many
    assert out.shape == (5,)
    for n in range(5):
        np.testing.assert_allclose(
            out.covariance[n], (a @ many[n]).covariance, rtol=1e-12, atol=1e-20
        )


def test_indexing_len_repr(rng):
    b = _up(rng, (4,))
    assert len(b) == 4
    assert b[1:3].shape == (2,)
    np.testing.assert_array_equal(b[2].covariance, b.covariance[2])
    assert "batch of shape (4,)" in repr(b)
    single = UncertainPose(Pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]),
                           np.diag([4e-6, 9e-6, 1e-6] + [np.radians(2.0) ** 2] * 3))  # fmt: skip
    r = repr(single)
    assert "sigma_mm=[2. 3. 1.]" in r
    assert "sigma_deg=[2. 2. 2.]" in r
    with pytest.raises(TypeError):
        len(single)


def test_interpolate_accepts_plain_pose(rng):
    a = _up(rng)
    p = _up(rng).pose
    out = a.interpolate(p, 0.5)
    ref = a.interpolate(UncertainPose.exact(p), 0.5)
    np.testing.assert_array_equal(out.covariance, ref.covariance)


def test_between_rejects_other_types(rng):
    with pytest.raises(ValueError):
        _up(rng).between(np.eye(4))
    with pytest.raises(ValueError):
        _up(rng).interpolate(np.eye(4), 0.5)
