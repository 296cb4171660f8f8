"""``Pose`` against plain 4x4 homogeneous-matrix algebra built with scipy.

The reference matrices never go through trackflow's quaternion code: rotations come from
``scipy.spatial.transform.Rotation``, composition is ``M_a @ M_b``, inversion is
``np.linalg.inv``. Batched results must equal element-by-element loops.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from trackflow import Pose


def _random(rng, n):
    return rng.normal(size=(n, 3)), Rotation.random(n, random_state=rng).as_quat()


def _matrix(p, q) -> np.ndarray:
    """Homogeneous matrices from positions and scipy rotations (reference path)."""
    p = np.asarray(p, dtype=float)
    m = np.zeros(p.shape[:-1] + (4, 4))
    m[..., :3, :3] = (
        Rotation.from_quat(np.reshape(q, (-1, 4))).as_matrix().reshape(p.shape[:-1] + (3, 3))
    )
    m[..., :3, 3] = p
    m[..., 3, 3] = 1.0
    return m


@pytest.fixture
def batch(rng):
    p, q = _random(rng, 40)
    return Pose(p, q), _matrix(p, q)


@pytest.fixture
def batch2(rng):
    p, q = _random(np.random.default_rng(7), 40)
    return Pose(p, q), _matrix(p, q)


def test_as_matrix_matches_reference(batch):
    pose, m = batch
    np.testing.assert_allclose(pose.as_matrix(), m, atol=1e-15)
    np.testing.assert_allclose(pose.rotation_matrix, m[:, :3, :3], atol=1e-15)


def test_compose_matches_matrix_product(batch, batch2):
    (a, ma), (b, mb) = batch, batch2
    c = a @ b
    assert c.shape == (40,)
    np.testing.assert_allclose(c.as_matrix(), ma @ mb, atol=1e-14)
    assert (a.compose(b)).allclose(c, atol=1e-15)


def test_compose_is_associative_and_identity_neutral(batch, batch2):
    (a, _), (b, _) = batch, batch2
    c = b[::-1]
    assert ((a @ b) @ c).allclose(a @ (b @ c), atol=1e-13)
    assert (Pose.identity() @ a).allclose(a, atol=1e-15)
    assert (a @ Pose.identity()).allclose(a, atol=1e-15)


def test_inverse_matches_matrix_inverse(batch):
    pose, m = batch
    inv = pose.inverse()
    np.testing.assert_allclose(inv.as_matrix(), np.linalg.inv(m), atol=1e-13)
    assert (pose @ inv).allclose(Pose.identity((40,)), atol=1e-14)
    assert (inv @ pose).allclose(Pose.identity((40,)), atol=1e-14)
    assert inv.inverse().allclose(pose, atol=1e-14)


def test_transform_points_matches_matrix(batch, rng):
    pose, m = batch
    x = rng.normal(size=(40, 3))
    xh = np.concatenate([x, np.ones((40, 1))], axis=1)
    ref = np.einsum("nij,nj->ni", m, xh)[:, :3]
    np.testing.assert_allclose(pose.transform_points(x), ref, atol=1e-14)
    # one pose, many points
    many = rng.normal(size=(25, 3))
    ref1 = (m[3] @ np.concatenate([many, np.ones((25, 1))], axis=1).T).T[:, :3]
    np.testing.assert_allclose(pose[3].transform_points(many), ref1, atol=1e-14)
    # T_a_c x = T_a_b (T_b_c x)
    ab = pose[0] @ pose[1]
    np.testing.assert_allclose(
        ab.transform_points(many), pose[0].transform_points(pose[1].transform_points(many)),
        atol=1e-14,
    )  # fmt: skip


def test_interpolate_against_matrix_geodesic(batch, batch2):
    (a, ma), (b, mb) = batch, batch2
    for s in (0.0, 0.3, 0.5, 1.0):
        out = a.interpolate(b, s)
        ra = Rotation.from_matrix(ma[:, :3, :3])
        rb = Rotation.from_matrix(mb[:, :3, :3])
        rel = (ra.inv() * rb).as_rotvec()  # shortest relative rotation, angle <= pi
        rs = (ra * Rotation.from_rotvec(s * rel)).as_matrix()
        ps = (1.0 - s) * ma[:, :3, 3] + s * mb[:, :3, 3]
        np.testing.assert_allclose(out.rotation_matrix, rs, atol=1e-13)
        np.testing.assert_allclose(out.position, ps, atol=1e-15)
    assert a.interpolate(b, 0.0).allclose(a, atol=1e-15)
    assert a.interpolate(b, 1.0).allclose(b, atol=1e-13)


def test_interpolate_broadcasts_s_on_single_poses():
    a = Pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])
    b = Pose([2.0, 0.0, 0.0], Rotation.from_rotvec([0.0, 0.0, 1.0]).as_quat())
    out = a.interpolate(b, np.linspace(0.0, 1.0, 5))
    assert out.shape == (5,)
    np.testing.assert_allclose(out.position[:, 0], np.linspace(0.0, 2.0, 5), atol=1e-15)
    np.testing.assert_allclose(
        Rotation.from_quat(out.quaternion).as_rotvec()[:, 2], np.linspace(0, 1, 5), atol=1e-15
    )


def test_matrix_round_trip(batch):
    pose, m = batch
    back = Pose.from_matrix(m)
    assert back.shape == (40,)
    assert back.allclose(pose, atol=1e-14)
    np.testing.assert_allclose(back.as_matrix(), m, atol=1e-15)
    assert np.all(back.quaternion[:, 3] >= 0.0)
    single = Pose.from_matrix(m[5])
    assert single.shape == ()
    assert single.allclose(pose[5], atol=1e-14)


# -- batches ------------------------------------------------------------------------------------


def test_batched_operations_equal_loops(batch, batch2, rng):
    (a, _), (b, _) = batch, batch2
    x = rng.normal(size=(40, 3))
    c, inv, pts, mid = a @ b, a.inverse(), a.transform_points(x), a.interpolate(b, 0.4)
    for n in range(40):
        one_c = a[n] @ b[n]
        np.testing.assert_array_equal(c.position[n], one_c.position)
        np.testing.assert_array_equal(c.quaternion[n], one_c.quaternion)
        np.testing.assert_array_equal(inv.position[n], a[n].inverse().position)
        np.testing.assert_array_equal(inv.quaternion[n], a[n].inverse().quaternion)
        np.testing.assert_array_equal(pts[n], a[n].transform_points(x[n]))
        one_mid = a[n].interpolate(b[n], 0.4)
        np.testing.assert_allclose(mid.position[n], one_mid.position, rtol=0, atol=0)
        np.testing.assert_allclose(mid.quaternion[n], one_mid.quaternion, rtol=0, atol=1e-16)


def test_broadcasting_one_vs_many(batch, batch2):
    (a, ma), (b, mb) = batch, batch2
    left = a[0] @ b
    right = a @ b[0]
    assert left.shape == right.shape == (40,)
    np.testing.assert_allclose(left.as_matrix(), ma[0] @ mb, atol=1e-14)
    np.testing.assert_allclose(right.as_matrix(), ma @ mb[0], atol=1e-14)
    # outer product of two batches via a singleton dimension
    grid = Pose(a.position[:4, None, :], a.quaternion[:4, None, :]) @ b[:5]
    assert grid.shape == (4, 5)
    np.testing.assert_allclose(
        grid.as_matrix(), ma[:4, None] @ mb[None, :5], atol=1e-14
    )  # fmt: skip
    # a single position with many orientations broadcasts in the constructor
    p = Pose([1.0, 2.0, 3.0], a.quaternion)
    assert p.shape == (40,)
    np.testing.assert_array_equal(p.position, np.tile([1.0, 2.0, 3.0], (40, 1)))


def test_indexing_len_and_shape(batch):
    pose, m = batch
    assert len(pose) == 40
    assert pose.shape == (40,)
    np.testing.assert_allclose(pose[7].as_matrix(), m[7], atol=1e-15)
    assert pose[7].shape == ()
    assert pose[2:9].shape == (7,)
    assert pose[np.array([1, 3, 5])].shape == (3,)
    mask = np.zeros(40, dtype=bool)
    mask[[0, 39]] = True
    sub = pose[mask]
    assert sub.shape == (2,)
    np.testing.assert_array_equal(sub.position, pose.position[[0, 39]])
    assert pose[-1] == pose[39]
    with pytest.raises(IndexError):
        pose[40]
    single = pose[0]
    with pytest.raises(TypeError):
        single[0]
    with pytest.raises(TypeError):
        len(single)


def test_repr():
    p = Pose([1.0, -2.5, 3.0], [0.0, 0.0, 0.0, 1.0])
    r = repr(p)
    assert r.startswith("Pose(")
    assert "-2.5" in r and "position" in r and "quaternion" in r
    assert "(3, 2)" in repr(Pose.identity((3, 2)))


def test_equality():
    q = Rotation.from_rotvec([0.1, 0.2, 0.3]).as_quat()
    a = Pose([1.0, 2.0, 3.0], q)
    assert a == Pose([1.0, 2.0, 3.0], q)
    assert a == Pose([1.0, 2.0, 3.0], -q)  # same rotation
    assert a != Pose([1.0, 2.0, 3.0 + 1e-12], q)
    assert a != Pose([1.0, 2.0, 3.0], Rotation.from_rotvec([0.1, 0.2, 0.31]).as_quat())
    assert a != Pose([1.0, 2.0, 3.0], q * np.array([-1.0, -1.0, -1.0, 1.0]))  # the inverse
    assert (a == "not a pose") is False
    assert a != 3
    with pytest.raises(TypeError):
        hash(a)
    batch = Pose(np.zeros((3, 3)), np.tile(q, (3, 1)))
    assert batch == Pose(np.zeros((3, 3)), np.tile(q, (3, 1)))
    assert batch == Pose(np.zeros((3, 3)), np.tile(-q, (3, 1)))


def test_equality_batch_with_per_element_sign_flip():
    q = Rotation.from_rotvec([[0.1, 0.2, 0.3], [0.0, 1.0, 0.0]]).as_quat()
    a = Pose(np.zeros((2, 3)), q)
    b = Pose(np.zeros((2, 3)), q * np.array([[1.0], [-1.0]]))
    assert a == b


def test_equality_of_different_batch_shapes_is_false():
    a = Pose.identity((2,))
    b = Pose.identity((3,))
    assert (a == b) is False
    assert (Pose.identity() == b) is False  # a single pose is not a batch of three
