"""Covariance converters, evaluation, ellipsoids and estimation from samples.

Semantic checks draw seeded samples in one convention, build the perturbed poses that the
convention defines, measure the error in the other convention, and compare sample covariances.
To separate sampling noise from convention errors, the converter is applied to the *sample*
covariance of the drawn errors: for a linear relation (ROS, thesis) the result then matches the
sample covariance of the converted errors to rounding; for a nonlinear one (GTSAM, additive
quaternion) the remaining difference is the second-order linearisation error only.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from trackflow import Pose, UncertainPose
from trackflow.math import (
    cov_from_additive_quaternion,
    cov_from_gtsam,
    cov_from_ros,
    cov_from_thesis,
    cov_to_additive_quaternion,
    cov_to_gtsam,
    cov_to_ros,
    cov_to_thesis,
    evaluate_covariance,
    quat_exp,
    quat_log,
    quat_multiply,
)

Q = Rotation.from_rotvec([0.9, -1.7, 0.4]).as_quat()  # a generic rotation, far from identity
R = Rotation.from_quat(Q).as_matrix()
T = np.array([0.4, -1.2, 2.0])


def _cov(rng, pos_sigma=5e-3, rot_sigma=0.02, n=6) -> np.ndarray:
    """A correlated SPD covariance with the given scales (metres, radians)."""
    a = rng.normal(size=(n, n))
    c = a @ a.T + 0.5 * np.eye(n)
    d = 1.0 / np.sqrt(np.diag(c))
    c = c * d[:, None] * d[None, :]  # correlation matrix
    s = np.array([pos_sigma] * 3 + [rot_sigma] * 3)[:n]
    return c * s[:, None] * s[None, :]


def _sample_cov(x) -> np.ndarray:
    x = x - x.mean(axis=0)
    return x.T @ x / (len(x) - 1)


def _rel(a, b) -> float:
    """Relative Frobenius difference."""
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def _our_error(t_true, q_true) -> np.ndarray:
    """(dt, dtheta) of perturbed poses around (T, Q): t_true = T + dt, R_true = R Exp(dtheta)."""
    dtheta = Rotation.from_quat(Q).inv() * Rotation.from_quat(q_true)
    return np.concatenate([t_true - T, dtheta.as_rotvec()], axis=1)


# -- round trips --------------------------------------------------------------------------------


def test_round_trips_single_and_batched(rng):
    c = _cov(rng)
    for q in (Q, -Q, np.array([0.0, 0.0, 0.0, 1.0])):
        for to, back in ((cov_to_ros, cov_from_ros), (cov_to_gtsam, cov_from_gtsam)):
            np.testing.assert_allclose(back(to(c, q), q), c, rtol=0, atol=1e-16)
            np.testing.assert_allclose(to(back(c, q), q), c, rtol=0, atol=1e-16)
        seven = cov_to_additive_quaternion(c, q)
        np.testing.assert_allclose(cov_from_additive_quaternion(seven, q), c, atol=1e-17)
    np.testing.assert_allclose(cov_from_thesis(cov_to_thesis(c)), c, atol=1e-18)
    np.testing.assert_allclose(cov_to_thesis(cov_from_thesis(c)), c, atol=1e-18)

    qs = Rotation.random(8, random_state=rng).as_quat()
    cs = np.stack([_cov(rng) for _ in range(8)])
    for to, back in ((cov_to_ros, cov_from_ros), (cov_to_gtsam, cov_from_gtsam)):
        out = to(cs, qs)
        assert out.shape == (8, 6, 6)
        for n in range(8):
            np.testing.assert_allclose(out[n], to(cs[n], qs[n]), rtol=0, atol=1e-19)
        np.testing.assert_allclose(back(out, qs), cs, atol=1e-16)
        np.testing.assert_array_equal(out, np.swapaxes(out, -1, -2))
    seven = cov_to_additive_quaternion(cs, qs)
    assert seven.shape == (8, 7, 7)
    np.testing.assert_allclose(cov_from_additive_quaternion(seven, qs), cs, atol=1e-17)
    # one quaternion for a batch of covariances
    np.testing.assert_allclose(cov_from_ros(cov_to_ros(cs, Q), Q), cs, atol=1e-16)


def test_additive_quaternion_rejects_wrong_shape(rng):
    with pytest.raises(ValueError, match=r"\(\.\.\., 7, 7\)"):
        cov_from_additive_quaternion(_cov(rng), Q)


# -- semantics by Monte Carlo -------------------------------------------------------------------


def test_ros_convention_is_left_perturbation(rng):
    """ROS: R_true = Exp(dphi) R with dphi about the fixed axes of frame a."""
    c_ros = _cov(rng, rot_sigma=0.1)
    e_ros = rng.multivariate_normal(np.zeros(6), c_ros, size=20000)
    r_true = Rotation.from_rotvec(e_ros[:, 3:]) * Rotation.from_quat(Q)
    ours = _our_error(T + e_ros[:, :3], r_true.as_quat())
    s_ros, s_ours = _sample_cov(e_ros), _sample_cov(ours)
    assert _rel(cov_from_ros(s_ros, Q), s_ours) < 1e-12  # the relation is exactly linear
    assert _rel(cov_to_ros(s_ours, Q), s_ros) < 1e-12
    assert _rel(cov_from_ros(c_ros, Q), s_ours) < 0.05  # and vs the true covariance
    # the test can tell left from right: for this Q the two conventions differ a lot
    assert _rel(s_ros, s_ours) > 0.3


def test_gtsam_convention_with_real_gtsam(rng):
    gtsam = pytest.importorskip("gtsam")
    c_ours_true = _cov(rng, pos_sigma=0.01, rot_sigma=0.02)
    c_gtsam = cov_to_gtsam(c_ours_true, Q)
    xi = rng.multivariate_normal(np.zeros(6), c_gtsam, size=4000)  # (omega, v)
    x, y, z, w = Q
    mean = gtsam.Pose3(gtsam.Rot3.Quaternion(w, x, y, z), gtsam.Point3(*T))
    m = np.stack([mean.compose(gtsam.Pose3.Expmap(v)).matrix() for v in xi])
    t_true = m[:, :3, 3]
    q_true = Rotation.from_matrix(m[:, :3, :3]).as_quat()
    ours = _our_error(t_true, q_true)
    s_gtsam, s_ours = _sample_cov(xi), _sample_cov(ours)
    # second-order effects of SE(3) Exp at 0.02 rad are ~1e-3 relative
    assert _rel(cov_from_gtsam(s_gtsam, Q), s_ours) < 5e-3
    assert _rel(cov_to_gtsam(s_ours, Q), s_gtsam) < 5e-3
    assert _rel(cov_from_gtsam(c_gtsam, Q), s_ours) < 0.06
    # a wrong frame for GTSAM's translation (frame a instead of b) would be caught
    swapped = np.block([[s_gtsam[3:, 3:], s_gtsam[3:, :3]], [s_gtsam[:3, 3:], s_gtsam[:3, :3]]])
    assert _rel(swapped, s_ours) > 0.1


def test_thesis_units_are_half_angle_small_quaternion(rng):
    """Thesis / Ubitrack: R_true = R q(e) with the small quaternion q(e) ~ (e, 1)."""
    c = _cov(rng, rot_sigma=0.01)
    e = rng.multivariate_normal(np.zeros(6), c, size=20000)
    dq = quat_exp(e[:, 3:])
    thesis = np.concatenate([e[:, :3], dq[:, :3] / dq[:, 3:]], axis=1)  # (e, 1) scaling
    s, s_thesis = _sample_cov(e), _sample_cov(thesis)
    # e = tan(|dtheta|/2) axis = dtheta/2 (1 + O(dtheta^2)): 1e-4 relative at 0.01 rad
    assert _rel(cov_to_thesis(s), s_thesis) < 2e-4
    assert _rel(cov_from_thesis(s_thesis), s) < 2e-4
    np.testing.assert_allclose(np.diag(cov_to_thesis(c))[3:], np.diag(c)[3:] / 4, rtol=1e-15)


def test_additive_quaternion_vs_monte_carlo(rng):
    """7x7 of (t, q_true - q) with q_true = q * Exp(dtheta)."""
    c = _cov(rng, rot_sigma=0.02)
    e = rng.multivariate_normal(np.zeros(6), c, size=20000)
    dq = quat_multiply(Q, quat_exp(e[:, 3:])) - Q
    seven = np.concatenate([e[:, :3], dq], axis=1)
    s6, s7 = _sample_cov(e), _sample_cov(seven)
    assert _rel(cov_to_additive_quaternion(s6, Q), s7) < 2e-3
    assert _rel(cov_from_additive_quaternion(s7, Q), s6) < 2e-3
    # the true error stays on the unit sphere: to first order dq is orthogonal to q
    rot7 = cov_to_additive_quaternion(c, Q)[3:, 3:]
    np.testing.assert_allclose(rot7 @ Q, 0.0, atol=1e-18)
    assert abs(Q @ s7[3:, 3:] @ Q) < 1e-3 * np.trace(s7[3:, 3:])


def test_additive_quaternion_scalar_variance(rng):
    c = _cov(rng)
    plain = cov_to_additive_quaternion(c, Q)
    assert np.linalg.matrix_rank(plain, tol=1e-14 * np.max(plain)) == 6  # singular along q
    for s in (1.0, 1e-4):
        padded = cov_to_additive_quaternion(c, Q, scalar_variance=s)
        np.testing.assert_allclose(padded[3:, 3:] - plain[3:, 3:], s * np.outer(Q, Q), atol=1e-16)
        np.testing.assert_array_equal(padded[:3], plain[:3])
        np.linalg.cholesky(padded)  # invertible now
        np.testing.assert_allclose(cov_from_additive_quaternion(padded, Q), c, atol=1e-16)
    # batched with a batch of quaternions
    qs = Rotation.random(3, random_state=rng).as_quat()
    out = cov_to_additive_quaternion(np.stack([c] * 3), qs, scalar_variance=1.0)
    for n in range(3):
        np.testing.assert_allclose(out[n], cov_to_additive_quaternion(c, qs[n], 1.0), atol=0)


# -- evaluation ---------------------------------------------------------------------------------


def test_evaluate_covariance_matches_eigenvalue_sum_and_monte_carlo(rng):
    c = _cov(rng)
    ref = np.sqrt(np.sum(np.linalg.eigvalsh(c)))
    np.testing.assert_allclose(evaluate_covariance(c), ref, rtol=1e-13)
    e = rng.multivariate_normal(np.zeros(6), c, size=40000)
    mc = np.sqrt(np.mean(np.sum(e * e, axis=1)))  # sqrt(E |e|^2) = sqrt(trace C)
    assert abs(mc / ref - 1.0) < 0.02
    up = UncertainPose(Pose(T, Q), c)
    np.testing.assert_allclose(up.evaluate(), ref, rtol=1e-13)


def test_evaluate_covariance_with_weights(rng):
    c = _cov(rng)
    position_only = np.hstack([np.eye(3), np.zeros((3, 3))])
    np.testing.assert_allclose(
        evaluate_covariance(c, position_only), np.sqrt(np.trace(c[:3, :3])), rtol=1e-14
    )
    # directions perpendicular to a viewing ray along z, with rotation weighted by 1 m lever
    a = np.zeros((4, 6))
    a[0, 0] = a[1, 1] = 1.0
    a[2, 3] = a[3, 4] = 1.0
    ref = np.sqrt(np.sum(np.linalg.eigvalsh(a @ c @ a.T)))
    np.testing.assert_allclose(evaluate_covariance(c, a), ref, rtol=1e-13)
    e = rng.multivariate_normal(np.zeros(6), c, size=40000)
    mc = np.sqrt(np.mean(np.sum((e @ a.T) ** 2, axis=1)))
    assert abs(mc / ref - 1.0) < 0.02
    # batched
    cs = np.stack([_cov(rng) for _ in range(5)])
    out = evaluate_covariance(cs, a)
    assert out.shape == (5,)
    for n in range(5):
        np.testing.assert_allclose(out[n], evaluate_covariance(cs[n], a), rtol=1e-15)
    with pytest.raises(ValueError, match="weights must have 6 columns"):
        evaluate_covariance(c, np.eye(3))
    assert evaluate_covariance(np.zeros((6, 6))) == 0.0


# -- ellipsoids ---------------------------------------------------------------------------------


def test_position_ellipsoid(rng):
    c = _cov(rng)
    up = UncertainPose(Pose(T, Q), c)
    radii, axes = up.position_ellipsoid()
    assert np.all(np.diff(radii) >= 0.0)
    np.testing.assert_allclose(axes.T @ axes, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(axes @ np.diag(radii**2) @ axes.T, c[:3, :3], atol=1e-18)
    radii3, _ = up.position_ellipsoid(sigma=3.0)
    np.testing.assert_allclose(radii3, 3.0 * radii, rtol=1e-15)
    # MC: the spread of sampled positions along each axis is the radius
    e = rng.multivariate_normal(np.zeros(6), c, size=40000)
    along = (e[:, :3]) @ axes
    np.testing.assert_allclose(along.std(axis=0), radii, rtol=0.02)
    # batched
    ub = UncertainPose(Pose(np.zeros((4, 3)), np.tile(Q, (4, 1))), np.stack([c] * 4))
    rb, ab = ub.position_ellipsoid()
    assert rb.shape == (4, 3) and ab.shape == (4, 3, 3)
    np.testing.assert_allclose(rb, np.tile(radii, (4, 1)), rtol=1e-14)


@pytest.mark.parametrize("length", [1.0, 0.25])
def test_axis_ellipsoids_flat_and_match_monte_carlo(rng, length):
    c = _cov(rng, rot_sigma=0.01)
    covs, radii, axes = UncertainPose(Pose(T, Q), c).axis_ellipsoids(length=length)
    assert covs.shape == (3, 3, 3) and radii.shape == (3, 3) and axes.shape == (3, 3, 3)
    for k in range(3):
        axis_a = R[:, k]  # body axis k in frame a
        # flat along the axis itself: the tip cannot move along its own axis to first order
        np.testing.assert_allclose(covs[k] @ axis_a, 0.0, atol=1e-18)
        assert radii[k, 0] < 1e-7 * radii[k, 2]
        assert abs(abs(axes[k][:, 0] @ axis_a) - 1.0) < 1e-9

    # MC of the rotated tips (the position error does not move the axes)
    e = rng.multivariate_normal(np.zeros(6), c, size=20000)
    r_true = (Rotation.from_quat(Q) * Rotation.from_rotvec(e[:, 3:])).as_matrix()
    s = np.zeros((6, 6))
    s[3:, 3:] = _sample_cov(e[:, 3:])
    covs_s, _, _ = UncertainPose(Pose(T, Q), s).axis_ellipsoids(length=length)
    for k in range(3):
        tip = length * r_true[:, :, k]  # true tip positions relative to the origin of b
        disp = tip - length * R[:, k]
        assert _rel(covs_s[k], _sample_cov(disp)) < 2e-3
        assert _rel(covs[k], _sample_cov(disp)) < 0.06
    # sigma scales the radii
    _, radii2, _ = UncertainPose(Pose(T, Q), c).axis_ellipsoids(length=length, sigma=2.0)
    np.testing.assert_allclose(radii2[:, 1:], 2.0 * radii[:, 1:], rtol=1e-12)


# -- estimation from samples (thesis 6.1.5) -----------------------------------------------------


def _draw_poses(rng, q_mean, c, n, flip_fraction=0.5):
    e = rng.multivariate_normal(np.zeros(6), c, size=n)
    q = quat_multiply(q_mean, quat_exp(e[:, 3:]))
    flip = rng.random(n) < flip_fraction
    q = np.where(flip[:, None], -q, q)  # sign flips as in real recordings
    return Pose(T + e[:, :3], q), e


@pytest.mark.parametrize(
    "q_mean",
    [
        Q,
        Rotation.from_rotvec([0.0, 0.0, 0.0]).as_quat(),
        Rotation.from_rotvec(
            np.array([0.3, -0.8, 0.5]) / np.linalg.norm([0.3, -0.8, 0.5]) * (np.pi - 0.005)
        ).as_quat(),  # fmt: skip
        Rotation.from_rotvec([np.pi, 0.0, 0.0]).as_quat(),
    ],
    ids=["generic", "identity", "near_pi", "pi"],
)
def test_from_samples_recovers_mean_and_covariance(rng, q_mean):
    c = _cov(rng, pos_sigma=2e-3, rot_sigma=0.02)
    n = 3000
    poses, e = _draw_poses(rng, q_mean, c, n)
    # samples straddle the angle pi when the mean is close to it
    angles = np.linalg.norm(quat_log(poses.quaternion), axis=-1)
    est = UncertainPose.from_samples(poses)
    assert est.shape == ()
    sig = np.sqrt(np.diag(c))
    # mean: the estimate is the mean of the drawn errors, up to second order
    np.testing.assert_allclose(est.position, T + e[:, :3].mean(axis=0), atol=1e-15)
    rot_err = quat_log(quat_multiply(Rotation.from_quat(q_mean).inv().as_quat(), est.quaternion))
    np.testing.assert_allclose(rot_err, e[:, 3:].mean(axis=0), atol=1e-5)
    assert np.all(np.abs(rot_err) < 5 * sig[3:] / np.sqrt(n))
    # covariance: that of the drawn errors (second order differences only), and near the truth
    assert _rel(est.covariance, _sample_cov(e)) < 3e-3
    assert _rel(est.covariance, c) < 0.1
    np.testing.assert_array_equal(est.covariance, est.covariance.T)
    if q_mean is not Q and abs(q_mean[3]) < 0.01:
        assert np.any(angles > np.pi - 0.01)


def test_from_samples_is_the_unbiased_sample_covariance(rng):
    """With small errors the residuals are the drawn errors almost exactly (relative
    differences ~ sigma / sqrt(N) from the mean's own error), so ``N - 1`` is visible."""
    c = _cov(rng, pos_sigma=1e-3, rot_sigma=1e-3)
    for n in (20, 200):
        poses, e = _draw_poses(rng, Q, c, n)
        est = UncertainPose.from_samples(poses)
        assert _rel(est.covariance, _sample_cov(e)) < 5e-4
        assert _rel(est.covariance, _sample_cov(e) * (n - 1) / n) > 2e-3


def test_from_samples_ignores_sign_flips(rng):
    c = _cov(rng)
    poses, _ = _draw_poses(rng, Q, c, 500, flip_fraction=0.0)
    flipped = Pose(poses.position, -poses.quaternion)
    a = UncertainPose.from_samples(poses)
    b = UncertainPose.from_samples(flipped)
    assert a.pose.allclose(b.pose, atol=1e-14)
    np.testing.assert_allclose(a.covariance, b.covariance, rtol=0, atol=1e-16)


def test_from_samples_rejects_bad_batches():
    with pytest.raises(ValueError, match="N >= 2"):
        UncertainPose.from_samples(Pose.identity((1,)))
    with pytest.raises(ValueError, match="N >= 2"):
        UncertainPose.from_samples(Pose.identity((3, 2)))
    with pytest.raises(ValueError, match="N >= 2"):
        UncertainPose.from_samples(Pose.identity())
