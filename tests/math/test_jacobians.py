"""Analytic Jacobians against central finite differences on the manifold.

Inputs are perturbed with the convention's retraction ``(t + dt, q * Exp(dtheta))`` and the
output error is measured as ``(t' - t, Log(q^* q'))`` (``_helpers.retract`` / ``local``), so the
finite differences check the Jacobians against ``docs/conventions.md`` itself, independently
of the formulas in ``_jacobians.py``.

Step and tolerance: central differences with step ``1e-6`` have truncation error ~1e-12 and
rounding error ~1e-10 (relative) here, so a relative tolerance of ``1e-5`` of the largest
entry leaves a wide margin while any wrong sign, transpose or missing term (all O(1)) fails.
"""

from __future__ import annotations

import numpy as np
import pytest
from _helpers import (
    EDGE_QUATERNIONS,
    FD_STEP,
    axis_angle_quaternion,
    local,
    numeric_jacobian,
    random_covariance,
    random_pose,
    random_quaternion,
    retract,
)

from trackflow import Pose, UncertainPose
from trackflow.math import (
    jacobian_inverse,
    jacobians_between,
    jacobians_compose,
    jacobians_interpolate,
    jacobians_transform_point,
    numba_available,
    quat_multiply,
    use_backend,
)

RTOL = 1e-5
EDGE_NAMES = list(EDGE_QUATERNIONS)
# Lever arms (translation lengths, metres): zero, and seeded random lengths in [1, 10].
LEVERS = [0.0, *np.random.default_rng(7).uniform(1.0, 10.0, 2).round(3)]
BACKENDS = ["numpy", *(["numba"] if numba_available() else [])]


def assert_jacobian_close(analytic, numeric, rtol: float = RTOL):
    """Every entry within ``rtol`` times the largest entry (at least 1) of the FD Jacobian."""
    analytic = np.asarray(analytic)
    assert analytic.shape == numeric.shape
    scale = max(1.0, float(np.max(np.abs(numeric))))
    err = float(np.max(np.abs(analytic - numeric)))
    assert err <= rtol * scale, (
        f"max |J - J_fd| = {err:.3g} (scale {scale:.3g})\n{analytic}\n{numeric}"
    )


def pose_with(q, lever: float, rng: np.random.Generator) -> Pose:
    d = rng.standard_normal(3)
    return Pose(lever * d / np.linalg.norm(d), q)


def _compose(a, b):
    return a @ b


def _inverse(a):
    return a.inverse()


def _between(a, b):
    return a.inverse() @ b


def _transform(pose, x):
    return pose.transform_points(x)


# -- the helpers themselves -------------------------------------------------------------------


def test_retract_and_local_are_inverse(rng):
    pose = random_pose(rng, 3.0)
    e = rng.normal(scale=0.3, size=(50, 6))
    np.testing.assert_allclose(local(pose, retract(pose, e)), e, atol=1e-12)


# -- composition ------------------------------------------------------------------------------


@pytest.mark.parametrize("lever", LEVERS)
@pytest.mark.parametrize("name", EDGE_NAMES)
@pytest.mark.parametrize("edge_side", ["a", "b"])
def test_jacobians_compose(name, lever, edge_side, rng):
    q_edge = EDGE_QUATERNIONS[name]
    q_other = random_quaternion(rng)
    q_a, q_b = (q_edge, q_other) if edge_side == "a" else (q_other, q_edge)
    a = pose_with(q_a, 2.5, rng)
    b = pose_with(q_b, lever, rng)
    J_c_a, J_c_b = jacobians_compose(a.position, a.quaternion, b.position, b.quaternion)
    assert_jacobian_close(J_c_a, numeric_jacobian(_compose, [a, b], 0))
    assert_jacobian_close(J_c_b, numeric_jacobian(_compose, [a, b], 1))


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("lever", LEVERS)
@pytest.mark.parametrize("name", EDGE_NAMES)
def test_uncertain_compose_jacobians(name, lever, backend, rng):
    a = UncertainPose(pose_with(EDGE_QUATERNIONS[name], 1.7, rng), random_covariance(rng))
    b = UncertainPose(pose_with(random_quaternion(rng), lever, rng), random_covariance(rng))
    with use_backend(backend):
        c, J_c_a, J_c_b = a.compose(b, jacobians=True)
    assert c.pose.allclose(a.pose @ b.pose, atol=1e-12)
    assert_jacobian_close(J_c_a, numeric_jacobian(_compose, [a.pose, b.pose], 0))
    assert_jacobian_close(J_c_b, numeric_jacobian(_compose, [a.pose, b.pose], 1))
    expected = J_c_a @ a.covariance @ J_c_a.T + J_c_b @ b.covariance @ J_c_b.T
    np.testing.assert_allclose(c.covariance, expected, rtol=1e-10, atol=1e-18)


@pytest.mark.parametrize("backend", BACKENDS)
def test_uncertain_compose_batched_matches_single(backend, rng):
    """The batched kernel returns, per element, the Jacobians of the single-pose path."""
    n = 5
    t_a, t_b = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    q_a, q_b = random_quaternion(rng, (n,)), random_quaternion(rng, (n,))
    cov = np.stack([random_covariance(rng) for _ in range(n)])
    a = UncertainPose(Pose(t_a, q_a), cov)
    b = UncertainPose(Pose(t_b, q_b), cov[::-1].copy())
    with use_backend(backend):
        _, J_c_a, J_c_b = a.compose(b, jacobians=True)
    for i in range(n):
        assert_jacobian_close(J_c_a[i], numeric_jacobian(_compose, [a.pose[i], b.pose[i]], 0))
        assert_jacobian_close(J_c_b[i], numeric_jacobian(_compose, [a.pose[i], b.pose[i]], 1))


# -- inversion --------------------------------------------------------------------------------


@pytest.mark.parametrize("lever", LEVERS)
@pytest.mark.parametrize("name", EDGE_NAMES)
def test_jacobian_inverse(name, lever, rng):
    a = pose_with(EDGE_QUATERNIONS[name], lever, rng)
    J = jacobian_inverse(a.position, a.quaternion)
    assert_jacobian_close(J, numeric_jacobian(_inverse, [a], 0))
    u = UncertainPose(a, random_covariance(rng))
    inv, J_i_a = u.inverse(jacobians=True)
    assert inv.pose.allclose(a.inverse(), atol=1e-12)
    assert_jacobian_close(J_i_a, numeric_jacobian(_inverse, [a], 0))


# -- relative pose ----------------------------------------------------------------------------

# The second pose of `between`: random, equal to the first (relative identity), and equal to the
# first with the quaternion negated (the same rotation written as -q).
BETWEEN_PARTNERS = ["random", "same", "same-negated"]


@pytest.mark.parametrize("partner", BETWEEN_PARTNERS)
@pytest.mark.parametrize("name", EDGE_NAMES)
def test_jacobians_between(name, partner, rng):
    a = pose_with(EDGE_QUATERNIONS[name], 4.0, rng)
    if partner == "random":
        b = pose_with(random_quaternion(rng), 6.0, rng)
    else:
        sign = -1.0 if partner == "same-negated" else 1.0
        b = Pose(a.position, sign * a.quaternion)
    J_c_a, J_c_b = jacobians_between(a.position, a.quaternion, b.position, b.quaternion)
    J_fd_a = numeric_jacobian(_between, [a, b], 0)
    J_fd_b = numeric_jacobian(_between, [a, b], 1)
    assert_jacobian_close(J_c_a, J_fd_a)
    assert_jacobian_close(J_c_b, J_fd_b)
    ua = UncertainPose(a, random_covariance(rng))
    ub = UncertainPose(b, random_covariance(rng))
    c, J_a, J_b = ua.between(ub, jacobians=True)
    assert c.pose.allclose(a.inverse() @ b, atol=1e-12)
    assert_jacobian_close(J_a, J_fd_a)
    assert_jacobian_close(J_b, J_fd_b)


# -- point transformation ---------------------------------------------------------------------


@pytest.mark.parametrize("lever", LEVERS)
@pytest.mark.parametrize("name", EDGE_NAMES)
def test_jacobians_transform_point(name, lever, rng):
    pose = pose_with(EDGE_QUATERNIONS[name], 3.0, rng)
    d = rng.standard_normal(3)
    x = lever * d / np.linalg.norm(d)
    J_x_pose, J_x_point = jacobians_transform_point(pose.quaternion, x)
    J_fd_pose = numeric_jacobian(_transform, [pose, x], 0)
    J_fd_point = numeric_jacobian(_transform, [pose, x], 1)
    assert_jacobian_close(J_x_pose, J_fd_pose)
    assert_jacobian_close(J_x_point, J_fd_point)
    u = UncertainPose(pose, random_covariance(rng))
    x_a, c, J_pose, J_point = u.transform_point(x, np.eye(3) * 1e-6, jacobians=True)
    np.testing.assert_allclose(x_a, pose.transform_points(x), atol=1e-12)
    assert_jacobian_close(J_pose, J_fd_pose)
    assert_jacobian_close(J_point, J_fd_point)


# -- interpolation ----------------------------------------------------------------------------

# Relative rotation angles between the two end points. slerp follows Log(R_a^T R_b), which has
# its branch cut at pi: its derivative J_r^-1(phi) stays bounded (perpendicular gain -> pi/2),
# but at exactly pi the shortest path flips and the map jumps. So near pi the Jacobian is fine as
# long as the finite-difference step stays below the distance to pi; it is scaled to
# 1e-3 * (pi - angle) there. Exactly pi is tested separately as a discontinuity.
RELATIVE_ANGLES = [0.0, 1e-9, 0.3, 2.0, np.pi - 1e-3, np.pi - 1e-6]
S_VALUES = [0.0, 0.3, 0.5, 1.0]
INTERP_EDGES = ["identity", "pi", "179.9999deg(w~0)", "generic-negated(-q)"]


def _fd_step_for(angle: float) -> float:
    return min(FD_STEP, 1e-3 * (np.pi - angle))


def _interp_pair(name, angle, rng, negate_b=False):
    q_a = EDGE_QUATERNIONS[name]
    q_b = quat_multiply(q_a, axis_angle_quaternion([0.2, -1.0, 0.6], angle))
    if negate_b:
        q_b = -q_b
    a = pose_with(q_a, 2.0, rng)
    b = pose_with(q_b, 5.0, rng)
    return a, b


@pytest.mark.parametrize("s", S_VALUES)
@pytest.mark.parametrize("angle", RELATIVE_ANGLES, ids=lambda x: f"{x:.9g}")
@pytest.mark.parametrize("name", INTERP_EDGES)
def test_jacobians_interpolate(name, angle, s, rng):
    a, b = _interp_pair(name, angle, rng)
    step = _fd_step_for(angle)

    def interp(x, y):
        return x.interpolate(y, s)

    J_s_a, J_s_b = jacobians_interpolate(a.quaternion, b.quaternion, s)
    J_fd_a = numeric_jacobian(interp, [a, b], 0, step)
    J_fd_b = numeric_jacobian(interp, [a, b], 1, step)
    assert_jacobian_close(J_s_a, J_fd_a)
    assert_jacobian_close(J_s_b, J_fd_b)
    ua = UncertainPose(a, random_covariance(rng))
    ub = UncertainPose(b, random_covariance(rng))
    out, J_a, J_b = ua.interpolate(ub, s, jacobians=True)
    assert out.pose.allclose(a.interpolate(b, s), atol=1e-12)
    assert_jacobian_close(J_a, J_fd_a)
    assert_jacobian_close(J_b, J_fd_b)


@pytest.mark.parametrize("s", [0.3, 0.7])
def test_jacobians_interpolate_sign_of_end_point(s, rng):
    """``q_b`` and ``-q_b`` are the same end point: same path, same Jacobians."""
    a, b = _interp_pair("generic", 2.0, rng)
    b_neg = Pose(b.position, -b.quaternion)
    J = jacobians_interpolate(a.quaternion, b.quaternion, s)
    J_neg = jacobians_interpolate(a.quaternion, b_neg.quaternion, s)
    np.testing.assert_allclose(J_neg[0], J[0], atol=1e-12)
    np.testing.assert_allclose(J_neg[1], J[1], atol=1e-12)
    assert a.interpolate(b_neg, s).allclose(a.interpolate(b, s), atol=1e-12)
    assert_jacobian_close(
        J_neg[1], numeric_jacobian(lambda x, y: x.interpolate(y, s), [a, b_neg], 1)
    )


def test_interpolate_jacobian_near_pi_has_a_finite_limit(rng):
    """Approaching opposite end points, the Jacobian converges (it does not blow up) ...

    ... but a finite-difference step larger than the distance to pi crosses the branch cut of
    Log and no longer measures it: the singularity is a jump, not an unbounded derivative.
    """
    gaps = [1e-2, 1e-4, 1e-6]
    blocks = []
    for gap in gaps:
        a, b = _interp_pair("generic", np.pi - gap, rng)
        blocks.append(jacobians_interpolate(a.quaternion, b.quaternion, 0.5)[1][3:, 3:])
    assert np.linalg.norm(blocks[2] - blocks[1]) < 0.05 * np.linalg.norm(blocks[1] - blocks[0])
    assert np.linalg.norm(blocks[2], 2) < 2.0

    a, b = _interp_pair("generic", np.pi - 1e-6, rng)

    def interp(x, y):
        return x.interpolate(y, 0.5)

    J_b = jacobians_interpolate(a.quaternion, b.quaternion, 0.5)[1]
    good = numeric_jacobian(interp, [a, b], 1, step=1e-9)
    crossing = numeric_jacobian(interp, [a, b], 1, step=1e-5)
    assert_jacobian_close(J_b, good)
    assert np.max(np.abs(crossing - J_b)) > 1.0


@pytest.mark.parametrize("s", [0.3, 0.5])
def test_interpolate_exactly_pi_has_no_jacobian(s, rng):
    """At a relative angle of exactly pi slerp jumps: no finite Jacobian exists.

    Perturbing the end point by +-h about the rotation axis makes the relative angle pi - h or
    pi + h; the latter is reached the short way round in the opposite sense, so the interpolated
    rotation moves by O(s * pi), not O(h). This documents the singularity (callers must not
    interpolate between opposite orientations); it does not check the value of
    ``jacobians_interpolate`` there.
    """
    axis = np.array([0.0, 0.0, 1.0])
    a = Pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])
    b = Pose([1.0, 0.0, 0.0], axis_angle_quaternion(axis, np.pi))
    h = 1e-7
    e = np.array([0.0, 0.0, 0.0, 0.0, 0.0, h])  # about z, the relative rotation axis
    mid = a.interpolate(b, s)
    d_plus = local(mid, a.interpolate(retract(b, e), s))[3:]
    d_minus = local(mid, a.interpolate(retract(b, -e), s))[3:]
    jump = np.linalg.norm(d_plus - d_minus)
    assert jump > 0.1 * s * np.pi  # O(1), not O(h): the map is discontinuous here


# -- batches ----------------------------------------------------------------------------------


def test_batched_jacobians_match_finite_differences_per_element(rng):
    """Batched calls return, element by element, the Jacobians of each single pose."""
    n = 4
    a = Pose(rng.normal(size=(n, 3)) * 3.0, random_quaternion(rng, (n,)))
    b = Pose(rng.normal(size=(n, 3)) * 3.0, random_quaternion(rng, (n,)))
    x = rng.normal(size=(n, 3)) * 5.0
    s = np.array([0.0, 0.3, 0.7, 1.0])
    J_inv = jacobian_inverse(a.position, a.quaternion)
    J_bet = jacobians_between(a.position, a.quaternion, b.position, b.quaternion)
    J_int = jacobians_interpolate(a.quaternion, b.quaternion, s)
    J_pt = jacobians_transform_point(a.quaternion, x)
    for i in range(n):
        ai, bi = a[i], b[i]
        assert_jacobian_close(J_inv[i], numeric_jacobian(_inverse, [ai], 0))
        assert_jacobian_close(J_bet[0][i], numeric_jacobian(_between, [ai, bi], 0))
        assert_jacobian_close(J_bet[1][i], numeric_jacobian(_between, [ai, bi], 1))

        def interp(p, r, si=s[i]):
            return p.interpolate(r, si)

        assert_jacobian_close(J_int[0][i], numeric_jacobian(interp, [ai, bi], 0))
        assert_jacobian_close(J_int[1][i], numeric_jacobian(interp, [ai, bi], 1))
        assert_jacobian_close(J_pt[0][i], numeric_jacobian(_transform, [ai, x[i]], 0))
        assert_jacobian_close(J_pt[1][i], numeric_jacobian(_transform, [ai, x[i]], 1))


def test_interpolate_jacobians_broadcast_over_s(rng):
    """One pair of poses and an array of ``s``: one Jacobian per ``s``."""
    a, b = _interp_pair("generic", 1.2, rng)
    s = np.array([0.0, 0.3, 1.0])
    J_a, J_b = jacobians_interpolate(a.quaternion, b.quaternion, s)
    assert J_a.shape == J_b.shape == (3, 6, 6)
    for k, sk in enumerate(s):
        single = jacobians_interpolate(a.quaternion, b.quaternion, sk)
        np.testing.assert_allclose(J_a[k], single[0], atol=1e-14)
        np.testing.assert_allclose(J_b[k], single[1], atol=1e-14)
    # the end points: s = 0 is T_a itself, s = 1 is T_b itself
    np.testing.assert_allclose(J_a[0], np.eye(6), atol=1e-12)
    np.testing.assert_allclose(J_b[0], np.zeros((6, 6)), atol=1e-12)
    np.testing.assert_allclose(J_a[2], np.zeros((6, 6)), atol=1e-12)
    np.testing.assert_allclose(J_b[2], np.eye(6), atol=1e-12)


# -- exact end points -------------------------------------------------------------------------


@pytest.mark.parametrize("operation", ["between", "interpolate"])
def test_plain_pose_counts_as_exact(operation, rng):
    """A plain ``Pose`` as the second operand is an exact pose; other types are a ValueError."""
    a = UncertainPose(random_pose(rng, 1.0), random_covariance(rng))
    b = random_pose(rng, 2.0)

    def run(other):
        if operation == "between":
            return a.between(other, jacobians=True)
        return a.interpolate(other, 0.3, jacobians=True)

    got, J_a, J_b = run(b)
    want, J_a_ref, J_b_ref = run(UncertainPose.exact(b))
    assert got.pose.allclose(want.pose, atol=1e-15)
    np.testing.assert_allclose(got.covariance, want.covariance, atol=1e-18)
    np.testing.assert_allclose(got.covariance, J_a @ a.covariance @ J_a.T, atol=1e-18)
    with pytest.raises(ValueError, match="UncertainPose or Pose"):
        run(np.zeros(7))
