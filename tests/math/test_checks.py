"""Input validation: bad data raises ``ValueError`` whose message names the problem."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from trackflow import Pose, UncertainPose
from trackflow.math import UNIT_TOLERANCE, check_covariance, check_position, check_quaternion

# -- positions ----------------------------------------------------------------------------------


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_position_non_finite_single(bad):
    with pytest.raises(ValueError, match=r"position contains NaN or inf") as err:
        check_position([1.0, bad, 3.0])
    assert "index" not in str(err.value)


def test_position_non_finite_in_batch_names_index():
    p = np.zeros((5, 3))
    p[3, 2] = np.nan
    with pytest.raises(ValueError, match=r"position contains NaN or inf at index 3\b"):
        check_position(p)
    p = np.zeros((2, 4, 3))
    p[1, 2, 0] = np.inf
    with pytest.raises(ValueError, match=r"at index \(1, 2\)"):
        check_position(p)


@pytest.mark.parametrize("shape", [(2,), (4,), (3, 2), (0,), ()])
def test_position_wrong_shape(shape):
    with pytest.raises(ValueError, match=r"position must have shape \(\.\.\., 3\), got"):
        check_position(np.zeros(shape))


def test_position_not_numeric_and_custom_name():
    with pytest.raises(ValueError, match="must be numeric"):
        check_position("1 2 3")
    with pytest.raises(ValueError, match=r"^lever_arm must have shape"):
        check_position([1.0, 2.0], name="lever_arm")


def test_position_valid_passes_through():
    p = check_position([[1, 2, 3], [4, 5, 6]])
    assert p.dtype == float
    np.testing.assert_array_equal(p, [[1, 2, 3], [4, 5, 6]])


# -- quaternions --------------------------------------------------------------------------------


def test_quaternion_non_finite_batch_names_index():
    q = np.tile([0.0, 0.0, 0.0, 1.0], (6, 1))
    q[4, 1] = np.nan
    with pytest.raises(ValueError, match=r"quaternion contains NaN or inf at index 4\b"):
        check_quaternion(q)
    # NaN is rejected even when normalisation is requested
    with pytest.raises(ValueError, match="NaN or inf"):
        check_quaternion([np.inf, 0.0, 0.0, 1.0], normalize=True)


@pytest.mark.parametrize("scale", [1.0 + 2 * UNIT_TOLERANCE, 1.0 - 2 * UNIT_TOLERANCE, 2.0, 0.5])
def test_quaternion_non_unit_rejected_unless_normalize(scale):
    q = Rotation.from_rotvec([0.2, -0.3, 0.1]).as_quat()
    with pytest.raises(ValueError, match=r"not unit length.*normalize=True") as err:
        check_quaternion(scale * q)
    assert "index" not in str(err.value)
    out = check_quaternion(scale * q, normalize=True)
    np.testing.assert_allclose(out, q, atol=1e-15)


def test_quaternion_non_unit_in_batch_names_index():
    q = np.tile([0.0, 0.0, 0.0, 1.0], (5, 1))
    q[2] *= 1.01
    with pytest.raises(ValueError, match=r"not unit length at index 2\b"):
        check_quaternion(q)
    out = check_quaternion(q, normalize=True)
    np.testing.assert_allclose(np.linalg.norm(out, axis=-1), 1.0, atol=1e-15)


def test_quaternion_within_tolerance_is_renormalised():
    q = Rotation.from_rotvec([0.5, 0.1, -0.4]).as_quat()
    for scale in (1.0 + 0.5 * UNIT_TOLERANCE, 1.0 - 0.5 * UNIT_TOLERANCE):
        out = check_quaternion(scale * q)
        assert abs(np.linalg.norm(out) - 1.0) < 1e-15
        batch = check_quaternion(np.tile(scale * q, (3, 1)))
        np.testing.assert_allclose(np.linalg.norm(batch, axis=-1), 1.0, atol=1e-15)


def test_quaternion_wrong_shape():
    with pytest.raises(ValueError, match=r"quaternion must have shape \(\.\.\., 4\), got \(3,\)"):
        check_quaternion([0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match=r"got \(2, 3\)"):
        check_quaternion(np.zeros((2, 3)))


@pytest.mark.parametrize("normalize", [False, True])
def test_zero_quaternion_rejected(normalize):
    with pytest.raises(ValueError, match=r"quaternion is zero"):
        check_quaternion([0.0, 0.0, 0.0, 0.0], normalize=normalize)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (3, 1))
    q[1] = 0.0
    with pytest.raises(ValueError, match=r"quaternion is zero at index 1\b"):
        check_quaternion(q, normalize=normalize)


# -- covariances --------------------------------------------------------------------------------


def _spd(rng, n=6):
    a = rng.normal(size=(n, n))
    return a @ a.T + 1e-3 * np.eye(n)


@pytest.mark.parametrize("shape", [(5, 5), (7, 7), (6,), (6, 5), (3, 3)])
def test_covariance_wrong_shape(shape):
    with pytest.raises(ValueError, match=r"covariance must have shape \(\.\.\., 6, 6\)"):
        check_covariance(np.zeros(shape))


def test_covariance_not_symmetric(rng):
    c = _spd(rng)
    c[0, 4] += 1e-3 * np.max(np.abs(c))
    with pytest.raises(ValueError, match=r"covariance is not symmetric: max \|C - C\^T\|"):
        check_covariance(c)
    batch = np.stack([_spd(rng) for _ in range(4)])
    batch[3, 5, 1] += 1.0
    with pytest.raises(ValueError, match=r"not symmetric at index 3\b"):
        check_covariance(batch)


def test_covariance_tiny_asymmetry_is_symmetrised(rng):
    c = _spd(rng)
    c[2, 3] += 1e-12 * np.max(np.abs(c))
    out = check_covariance(c)
    np.testing.assert_array_equal(out, out.T)
    np.testing.assert_allclose(out, c, rtol=0, atol=1e-11 * np.max(np.abs(c)))


def test_covariance_not_psd(rng):
    c = np.diag([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, -1e-8])
    with pytest.raises(ValueError, match=r"not positive semi-definite: smallest eigenvalue -1e-08"):
        check_covariance(c)
    # symmetric, positive diagonal, but indefinite
    c = np.eye(6)
    c[0, 1] = c[1, 0] = 2.0
    with pytest.raises(ValueError, match=r"not positive semi-definite.*-1"):
        check_covariance(c)
    batch = np.stack([_spd(rng) for _ in range(3)])
    batch[1] = c
    with pytest.raises(ValueError, match=r"not positive semi-definite at index 1\b"):
        check_covariance(batch)


def test_covariance_non_finite():
    c = np.eye(6)
    c[2, 2] = np.nan
    with pytest.raises(ValueError, match=r"covariance contains NaN or inf"):
        check_covariance(c)
    b = np.tile(np.eye(6), (3, 1, 1))
    b[2, 0, 5] = np.inf
    with pytest.raises(ValueError, match=r"NaN or inf at index 2\b"):
        check_covariance(b)


def test_covariance_singular_psd_accepted(rng):
    np.testing.assert_array_equal(check_covariance(np.zeros((6, 6))), np.zeros((6, 6)))
    v = rng.normal(size=6)
    rank1 = np.outer(v, v)  # PSD with five zero eigenvalues (some round slightly negative)
    np.testing.assert_allclose(check_covariance(rank1), rank1, rtol=0, atol=0)
    position_only = np.diag([1e-6, 1e-6, 1e-6, 0.0, 0.0, 0.0])
    check_covariance(np.stack([position_only, np.zeros((6, 6)), _spd(rng)]))


def test_covariance_other_size():
    check_covariance(np.eye(3), size=3, name="point_covariance")
    with pytest.raises(ValueError, match=r"^point_covariance must have shape \(\.\.\., 3, 3\)"):
        check_covariance(np.eye(6), size=3, name="point_covariance")


# -- through the classes ------------------------------------------------------------------------


def test_pose_constructor_rejects_bad_input():
    with pytest.raises(ValueError, match="not unit length"):
        Pose([0.0, 0.0, 0.0], [1.0, 1.0, 0.0, 0.0])
    p = Pose([0.0, 0.0, 0.0], [1.0, 1.0, 0.0, 0.0], normalize=True)
    np.testing.assert_allclose(p.quaternion, [2**-0.5, 2**-0.5, 0.0, 0.0], atol=1e-16)
    with pytest.raises(ValueError, match="position contains NaN"):
        Pose([0.0, np.nan, 0.0], [0.0, 0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="quaternion is zero"):
        Pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], normalize=True)


def test_pose_constructor_mismatched_batches_raise_value_error():
    with pytest.raises(ValueError):
        Pose(np.zeros((2, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (3, 1)))


def test_pose_constructor_mismatch_message_names_arguments():
    with pytest.raises(ValueError) as err:
        Pose(np.zeros((2, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (3, 1)))
    assert "position" in str(err.value) and "quaternion" in str(err.value)


def test_uncertain_pose_rejects_bad_covariance(rng):
    pose = Pose(np.zeros((3, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (3, 1)))
    with pytest.raises(ValueError, match="not positive semi-definite"):
        UncertainPose(pose[0], -np.eye(6))
    with pytest.raises(ValueError, match=r"covariance batch shape \(2,\) does not match"):
        UncertainPose(pose, np.zeros((2, 6, 6)))
    with pytest.raises(ValueError, match="pose must be a trackflow Pose"):
        UncertainPose(np.eye(4), np.eye(6))
    # a single covariance broadcasts over the batch
    up = UncertainPose(pose, 1e-6 * np.eye(6))
    assert up.covariance.shape == (3, 6, 6)


# -- Pose.from_matrix ---------------------------------------------------------------------------


def _homogeneous(rotvec=(0.1, 0.2, 0.3), t=(1.0, 2.0, 3.0)) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    m[:3, 3] = t
    return m


def test_from_matrix_rejections():
    with pytest.raises(ValueError, match=r"matrix must have shape \(\.\.\., 4, 4\), got \(3, 3\)"):
        Pose.from_matrix(np.eye(3))
    m = _homogeneous()
    m[1, 3] = np.nan
    with pytest.raises(ValueError, match="matrix contains NaN or inf"):
        Pose.from_matrix(m)
    scaled = _homogeneous()
    scaled[:3, :3] *= 1.01
    with pytest.raises(ValueError, match=r"not a rotation \(\|R R\^T - I\| = 0\.0201\)"):
        Pose.from_matrix(scaled)
    reflected = _homogeneous()
    reflected[:3, 0] *= -1.0  # orthonormal but det = -1
    with pytest.raises(ValueError, match=r"not a rotation: a reflection \(determinant -1\)"):
        Pose.from_matrix(reflected)
    sheared = _homogeneous()
    sheared[0, 1] += 1e-4
    with pytest.raises(ValueError, match="not a rotation"):
        Pose.from_matrix(sheared)
    bad_row = _homogeneous()
    bad_row[3, 0] = 0.1
    with pytest.raises(ValueError, match=r"last row must be \[0, 0, 0, 1\]"):
        Pose.from_matrix(bad_row)
    projective = _homogeneous()
    projective[3, 3] = 2.0
    with pytest.raises(ValueError, match="last row"):
        Pose.from_matrix(projective)


def test_from_matrix_batch_with_one_bad_entry():
    batch = np.stack([_homogeneous(), _homogeneous((0.0, 0.0, 3.0)), _homogeneous()])
    Pose.from_matrix(batch)
    batch[1, :3, 2] *= -1.0
    with pytest.raises(ValueError, match="not a rotation"):
        Pose.from_matrix(batch)


def test_from_matrix_accepts_float_noise():
    m = _homogeneous()
    m[:3, :3] += 1e-9 * np.arange(9).reshape(3, 3) / 9.0
    p = Pose.from_matrix(m)
    assert abs(np.linalg.norm(p.quaternion) - 1.0) < 1e-15
