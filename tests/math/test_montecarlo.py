"""First-order propagated covariances against seeded Monte Carlo.

Realistic case: 1 mm position and 1 degree rotation standard deviation, correlated (non-diagonal)
input covariances, a 1 m lever arm. Each test draws ``N`` samples of the input errors,
applies them with the convention's retraction ``(t + dt, q * Exp(dtheta))``, runs the batched
``Pose`` operation on all samples at once, measures the output errors ``(t' - t, Log(q^* q'))``
about the nominal result and compares their sample covariance ``M`` with the analytic ``C``.

Bars: ``||C - M||_F / ||M||_F <= 2 %`` and every eigenvalue of ``M^-1/2 C M^-1/2`` in
``[0.8, 1.2]``. With ``N = 2e5`` the sampling error of ``M`` is about ``sqrt(2/N) = 0.3 %`` per
direction, so the bars measure the linearisation, not the sampling noise. Two guard tests show
that known slips (a sign flip in the inversion Jacobian; composition Jacobians used for a
relative pose) fail these same bars.
"""

from __future__ import annotations

import numpy as np
import pytest
from _helpers import (
    covariance_agreement,
    local,
    random_covariance,
    random_pose,
    retract,
    sample_covariance,
    sample_errors,
)

from trackflow import Pose, UncertainPose
from trackflow.math import jacobian_inverse, jacobians_compose, numba_available, use_backend

N_SAMPLES = 200_000
FROBENIUS_BAR = 0.02
RATIO_BARS = (0.8, 1.2)
SIGMA_POSITION = 1e-3  # metres
SIGMA_ROTATION = np.radians(1.0)
LEVER = 1.0  # metres
BACKENDS = ["numpy", *(["numba"] if numba_available() else [])]


def within_bars(analytic, reference) -> bool:
    frob, ratios = covariance_agreement(analytic, reference)
    return frob <= FROBENIUS_BAR and RATIO_BARS[0] <= ratios[0] and ratios[-1] <= RATIO_BARS[1]


def assert_matches_mc(analytic, reference):
    frob, ratios = covariance_agreement(analytic, reference)
    assert frob <= FROBENIUS_BAR, f"Frobenius relative error {frob:.4f}"
    assert RATIO_BARS[0] <= ratios[0], f"eigenvalue ratios {ratios}"
    assert ratios[-1] <= RATIO_BARS[1], f"eigenvalue ratios {ratios}"


def realistic_cov(rng, size: int = 6) -> np.ndarray:
    return random_covariance(rng, SIGMA_POSITION, SIGMA_ROTATION, size=size)


def joint_cov(rng) -> np.ndarray:
    """A 12x12 covariance of two correlated pose errors (cross-correlations up to ~0.5)."""
    c = random_covariance(rng, SIGMA_POSITION, SIGMA_ROTATION, size=12)
    # random_covariance gives entries 0..2 metres; make 6..8 metres too.
    s = np.ones(12)
    s[6:9] = SIGMA_POSITION / SIGMA_ROTATION
    s[3:6] = 1.0
    return c * np.outer(s, s)


def pose_pair(rng) -> tuple[Pose, Pose]:
    """``T_a_b`` (0.5 m away) and ``T_b_c`` with the 1 m lever arm."""
    return random_pose(rng, 0.5), random_pose(rng, LEVER)


def relative_pair(rng) -> tuple[Pose, Pose]:
    """``T_w_a`` and ``T_w_b`` with ``T_a_b = T_w_a^-1 T_w_b`` at the 1 m lever arm.

    The lever of a relative pose is the distance ``|t_b - t_a|`` it is expressed over.
    """
    a = random_pose(rng, 2.0)
    return a, a @ random_pose(rng, LEVER)


def sample_pair(rng, a: Pose, b: Pose, c_a, c_b, c_ab=None):
    """Samples of two uncertain poses; independent unless a cross-covariance is given."""
    if c_ab is None:
        return (
            retract(a, sample_errors(rng, c_a, N_SAMPLES)),
            retract(b, sample_errors(rng, c_b, N_SAMPLES)),
        )
    joint = np.block([[c_a, c_ab], [c_ab.T, c_b]])
    e = sample_errors(rng, joint, N_SAMPLES)
    return retract(a, e[:, :6]), retract(b, e[:, 6:])


# -- the propagated covariances ---------------------------------------------------------------


@pytest.mark.parametrize("backend", BACKENDS)
def test_compose_matches_monte_carlo(backend, rng):
    a, b = pose_pair(rng)
    c_a, c_b = realistic_cov(rng), realistic_cov(rng)
    with use_backend(backend):
        c = UncertainPose(a, c_a).compose(UncertainPose(b, c_b))
    sa, sb = sample_pair(rng, a, b, c_a, c_b)
    assert_matches_mc(c.covariance, sample_covariance(local(a @ b, sa @ sb)))


@pytest.mark.parametrize("backend", BACKENDS)
def test_compose_with_cross_covariance_matches_monte_carlo(backend, rng):
    a, b = pose_pair(rng)
    joint = joint_cov(rng)
    c_a, c_b, c_ab = joint[:6, :6], joint[6:, 6:], joint[:6, 6:]
    with use_backend(backend):
        c = UncertainPose(a, c_a).compose(UncertainPose(b, c_b), cross_covariance=c_ab)
    sa, sb = sample_pair(rng, a, b, c_a, c_b, c_ab)
    mc = sample_covariance(local(a @ b, sa @ sb))
    assert_matches_mc(c.covariance, mc)
    independent = UncertainPose(a, c_a).compose(UncertainPose(b, c_b)).covariance
    assert not within_bars(independent, mc)  # the cross term matters in this case


def test_inverse_matches_monte_carlo(rng):
    a = random_pose(rng, LEVER)
    c_a = realistic_cov(rng)
    inv = UncertainPose(a, c_a).inverse()
    s = retract(a, sample_errors(rng, c_a, N_SAMPLES))
    assert_matches_mc(inv.covariance, sample_covariance(local(a.inverse(), s.inverse())))


def test_between_independent_matches_monte_carlo(rng):
    a, b = relative_pair(rng)
    c_a, c_b = realistic_cov(rng), realistic_cov(rng)
    ua, ub = UncertainPose(a, c_a), UncertainPose(b, c_b)
    rel = ua.between(ub)
    # independent inputs: one step equals inverse-then-compose
    np.testing.assert_allclose(rel.covariance, (ua.inverse() @ ub).covariance, atol=1e-15)
    sa, sb = sample_pair(rng, a, b, c_a, c_b)
    mc = sample_covariance(local(a.inverse() @ b, sa.inverse() @ sb))
    assert_matches_mc(rel.covariance, mc)


def test_between_with_cross_covariance_matches_monte_carlo(rng):
    a, b = relative_pair(rng)
    joint = joint_cov(rng)
    c_a, c_b, c_ab = joint[:6, :6], joint[6:, 6:], joint[:6, 6:]
    rel = UncertainPose(a, c_a).between(UncertainPose(b, c_b), cross_covariance=c_ab)
    sa, sb = sample_pair(rng, a, b, c_a, c_b, c_ab)
    mc = sample_covariance(local(a.inverse() @ b, sa.inverse() @ sb))
    assert_matches_mc(rel.covariance, mc)
    independent = UncertainPose(a, c_a).between(UncertainPose(b, c_b)).covariance
    assert not within_bars(independent, mc)


def test_transform_point_matches_monte_carlo(rng):
    pose = random_pose(rng, 0.5)
    c_pose = realistic_cov(rng)
    d = rng.standard_normal(3)
    x = LEVER * d / np.linalg.norm(d)
    c_point = random_covariance(rng, SIGMA_POSITION, SIGMA_POSITION, size=3)
    x_a, c_x = UncertainPose(pose, c_pose).transform_point(x, c_point)
    poses = retract(pose, sample_errors(rng, c_pose, N_SAMPLES))
    points = x + sample_errors(rng, c_point, N_SAMPLES)
    y = poses.transform_points(points)
    assert_matches_mc(c_x, sample_covariance(y - x_a))
    # the point's own covariance is a visible part of the result
    _, c_without = UncertainPose(pose, c_pose).transform_point(x)
    assert not within_bars(c_without, sample_covariance(y - x_a))


@pytest.mark.parametrize("s", [0.3, 0.5])
def test_interpolate_independent_matches_monte_carlo(s, rng):
    a = random_pose(rng, LEVER)
    b = retract(a, np.concatenate([rng.normal(size=3) * 0.2, rng.normal(size=3) * 0.5]))
    c_a, c_b = realistic_cov(rng), realistic_cov(rng)
    out = UncertainPose(a, c_a).interpolate(UncertainPose(b, c_b), s)
    sa, sb = sample_pair(rng, a, b, c_a, c_b)
    mc = sample_covariance(local(a.interpolate(b, s), sa.interpolate(sb, s)))
    assert_matches_mc(out.covariance, mc)


def test_interpolate_with_cross_covariance_matches_monte_carlo(rng):
    a = random_pose(rng, LEVER)
    b = retract(a, np.concatenate([rng.normal(size=3) * 0.2, rng.normal(size=3) * 0.5]))
    joint = joint_cov(rng)
    c_a, c_b, c_ab = joint[:6, :6], joint[6:, 6:], joint[:6, 6:]
    out = UncertainPose(a, c_a).interpolate(UncertainPose(b, c_b), 0.4, cross_covariance=c_ab)
    sa, sb = sample_pair(rng, a, b, c_a, c_b, c_ab)
    mc = sample_covariance(local(a.interpolate(b, 0.4), sa.interpolate(sb, 0.4)))
    assert_matches_mc(out.covariance, mc)


# -- guards: known slips must fail the same bars -----------------------------------------------


def test_guard_inverse_rotation_sign_flip_fails(rng):
    """``+R`` instead of ``-R`` in the rotation block flips the translation-rotation cross term."""
    a = random_pose(rng, LEVER)
    c_a = realistic_cov(rng)
    s = retract(a, sample_errors(rng, c_a, N_SAMPLES))
    mc = sample_covariance(local(a.inverse(), s.inverse()))
    J = jacobian_inverse(a.position, a.quaternion)
    J_slip = J.copy()
    J_slip[3:, 3:] *= -1.0
    good = J @ c_a @ J.T
    slip = J_slip @ c_a @ J_slip.T
    np.testing.assert_allclose(slip[:3, 3:], -good[:3, 3:])  # what the slip does
    assert within_bars(good, mc)
    assert not within_bars(slip, mc)


def test_guard_composition_jacobians_for_relative_pose_fail(rng):
    """``inverse(a) @ b`` propagated with the plain composition Jacobians and ``C_a`` is wrong."""
    a, b = relative_pair(rng)
    c_a, c_b = realistic_cov(rng), realistic_cov(rng)
    a_inv = a.inverse()
    J_a, J_b = jacobians_compose(a_inv.position, a_inv.quaternion, b.position, b.quaternion)
    slip = J_a @ c_a @ J_a.T + J_b @ c_b @ J_b.T
    good = UncertainPose(a, c_a).between(UncertainPose(b, c_b)).covariance
    sa, sb = sample_pair(rng, a, b, c_a, c_b)
    mc = sample_covariance(local(a_inv @ b, sa.inverse() @ sb))
    assert within_bars(good, mc)
    assert not within_bars(slip, mc)
