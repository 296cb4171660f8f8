"""Quaternion and rotation-vector functions, checked against scipy and first principles.

``scipy.spatial.transform.Rotation`` uses the same ``(x, y, z, w)`` order and Hamilton product,
so it serves as the independent reference. Quaternions are compared up to sign (``q`` and
``-q`` are the same rotation) unless a function promises a particular sign.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from trackflow.math import (
    quat_align_sign,
    quat_angle,
    quat_conjugate,
    quat_exp,
    quat_from_matrix,
    quat_identity,
    quat_log,
    quat_make_continuous,
    quat_multiply,
    quat_normalize,
    quat_rotate,
    quat_slerp,
    quat_to_matrix,
    skew,
    so3_right_jacobian,
    so3_right_jacobian_inverse,
)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def _rv(axis, angle) -> np.ndarray:
    return _unit(axis) * angle


_DIAG = _unit([1.0, -2.0, 0.5])

# Curated rotation vectors (radians): identity, the series/closed-form switch points of
# Exp/Log (1e-4 rad and the 1e-3 rad switch of the Jacobians), tiny angles, quarter turns,
# angles close to and exactly pi about each axis and a skew axis, and a generic rotation.
EDGE_ROTVECS = {
    "identity": np.zeros(3),
    "tiny_1e-12": _rv(_DIAG, 1e-12),
    "tiny_1e-9_x": _rv([1, 0, 0], 1e-9),
    "small_1e-6": _rv(_DIAG, 1e-6),
    "below_series_switch": _rv(_DIAG, 0.99e-4),
    "above_series_switch": _rv(_DIAG, 1.01e-4),
    "at_jacobian_switch": _rv([0, 1, 1], 1e-3),
    "quarter_x": _rv([1, 0, 0], np.pi / 2),
    "quarter_y": _rv([0, 1, 0], np.pi / 2),
    "quarter_z": _rv([0, 0, 1], np.pi / 2),
    "generic": np.array([0.3, -1.1, 0.7]),
    "near_pi_x": _rv([1, 0, 0], np.pi - 1e-7),
    "near_pi_y": _rv([0, 1, 0], np.pi - 1e-3),
    "near_pi_skew": _rv(_DIAG, np.pi - 1e-9),
    "pi_x": _rv([1, 0, 0], np.pi),
    "pi_y": _rv([0, 1, 0], np.pi),
    "pi_z": _rv([0, 0, 1], np.pi),
    "pi_skew": _rv(_DIAG, np.pi),
}
EDGE_IDS = list(EDGE_ROTVECS)
EDGE_ARRAY = np.stack(list(EDGE_ROTVECS.values()))


def _edge_quats() -> np.ndarray:
    """Edge rotations as quaternions built by scipy (independent of ``quat_exp``)."""
    return Rotation.from_rotvec(EDGE_ARRAY).as_quat()


def _assert_same_rotation(q1, q2, atol=1e-12):
    """``q1 == +-q2`` element-wise over a batch."""
    q1 = np.atleast_2d(q1)
    q2 = np.atleast_2d(q2)
    d = np.sum(q1 * q2, axis=-1, keepdims=True)
    s = np.where(d < 0.0, -1.0, 1.0)
    np.testing.assert_allclose(q1, s * q2, atol=atol, rtol=0)


def _random_quats(rng, n) -> np.ndarray:
    return quat_normalize(rng.normal(size=(n, 4)))


# -- product, conjugate, rotate -----------------------------------------------------------------


def test_identity_shape_and_value():
    q = quat_identity((2, 3))
    assert q.shape == (2, 3, 4)
    np.testing.assert_array_equal(q[1, 2], [0.0, 0.0, 0.0, 1.0])
    np.testing.assert_array_equal(quat_identity(), [0.0, 0.0, 0.0, 1.0])


def test_hamilton_basis_products():
    i, j, k, one = np.eye(4)
    np.testing.assert_array_equal(quat_multiply(i, j), k)  # i * j = k (Hamilton, not JPL)
    np.testing.assert_array_equal(quat_multiply(j, k), i)
    np.testing.assert_array_equal(quat_multiply(k, i), j)
    np.testing.assert_array_equal(quat_multiply(j, i), -k)
    np.testing.assert_array_equal(quat_multiply(i, i), -one)


def test_multiply_matches_scipy_batched(rng):
    p = _random_quats(rng, 200)
    q = _random_quats(rng, 200)
    ref = (Rotation.from_quat(p) * Rotation.from_quat(q)).as_quat()
    _assert_same_rotation(quat_multiply(p, q), ref, atol=1e-14)
    # R(p * q) = R(p) R(q)
    np.testing.assert_allclose(
        quat_to_matrix(quat_multiply(p, q)), quat_to_matrix(p) @ quat_to_matrix(q), atol=1e-14
    )


def test_multiply_single_equals_batch_and_broadcasts(rng):
    p = _random_quats(rng, 5)
    q = _random_quats(rng, 7)
    out = quat_multiply(p[:, None, :], q[None, :, :])
    assert out.shape == (5, 7, 4)
    for a in range(5):
        for b in range(7):
            np.testing.assert_allclose(out[a, b], quat_multiply(p[a], q[b]), atol=0, rtol=0)


def test_conjugate_is_inverse(rng):
    q = _random_quats(rng, 50)
    qc = quat_conjugate(q)
    _assert_same_rotation(quat_multiply(q, qc), quat_identity((50,)), atol=1e-15)
    _assert_same_rotation(qc, Rotation.from_quat(q).inv().as_quat(), atol=1e-15)
    np.testing.assert_array_equal(quat_conjugate(quat_conjugate(q)), q)


def test_rotate_matches_scipy_and_broadcasts(rng):
    q = _random_quats(rng, 100)
    v = rng.normal(size=(100, 3))
    np.testing.assert_allclose(quat_rotate(q, v), Rotation.from_quat(q).apply(v), atol=1e-13)
    # one rotation, many vectors; many rotations, one vector
    np.testing.assert_allclose(quat_rotate(q[0], v), Rotation.from_quat(q[0]).apply(v), atol=1e-13)
    np.testing.assert_allclose(quat_rotate(q, v[0]), Rotation.from_quat(q).apply(v[0]), atol=1e-13)
    # q and -q rotate identically
    np.testing.assert_allclose(quat_rotate(-q, v), quat_rotate(q, v), atol=1e-14)


# -- matrices -----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", EDGE_IDS)
def test_to_matrix_edge_cases(name):
    q = Rotation.from_rotvec(EDGE_ROTVECS[name]).as_quat()
    np.testing.assert_allclose(
        quat_to_matrix(q), Rotation.from_rotvec(EDGE_ROTVECS[name]).as_matrix(), atol=1e-15
    )


@pytest.mark.parametrize("name", EDGE_IDS)
def test_from_matrix_edge_cases(name):
    m = Rotation.from_rotvec(EDGE_ROTVECS[name]).as_matrix()
    q = quat_from_matrix(m)
    assert q[3] >= 0.0
    assert abs(np.linalg.norm(q) - 1.0) < 1e-15
    np.testing.assert_allclose(quat_to_matrix(q), m, atol=1e-15)


def test_matrix_round_trips_batched(rng):
    q = np.concatenate([_random_quats(rng, 300), _edge_quats()])
    m = quat_to_matrix(q)
    np.testing.assert_allclose(m, Rotation.from_quat(q).as_matrix(), atol=1e-15)
    back = quat_from_matrix(m)
    assert np.all(back[:, 3] >= 0.0)
    _assert_same_rotation(back, q, atol=1e-15)
    # batched result equals the single-matrix results
    for n in range(0, len(q), 37):
        np.testing.assert_array_equal(quat_from_matrix(m[n]), back[n])
    # leading dimensions are kept
    assert quat_from_matrix(m.reshape(-1, 1, 3, 3)[:6].reshape(2, 3, 3, 3)).shape == (2, 3, 4)


_BRANCH_CASES = [
    (axis, angle, largest)
    for axis, largest in (((1, 0, 0), 0), ((0, 1, 0), 1), ((0, 0, 1), 2))
    for angle in (2.0, 3.0, np.pi)
] + [((0.2, 0.1, -0.1), angle, 3) for angle in (0.0, 0.01, 1.0, 1.5)]


@pytest.mark.parametrize(("axis", "angle", "largest"), _BRANCH_CASES)
def test_from_matrix_all_shepperd_branches(axis, angle, largest):
    """Each of the four branches (largest of |x|, |y|, |z|, |w|) recovers the rotation.

    Rotations by large angles about x, y, z make that component the largest; a rotation by a
    small angle makes w the largest. The branch is identified from the answer, not the code.
    """
    ref = Rotation.from_rotvec(_rv(axis, angle))
    q = quat_from_matrix(ref.as_matrix())
    assert int(np.argmax(np.abs(q))) == largest
    _assert_same_rotation(q, ref.as_quat(), atol=1e-15)
    # a slightly non-orthonormal matrix (float noise) still gives a unit quaternion
    noisy = ref.as_matrix() + 1e-12 * np.arange(9).reshape(3, 3)
    assert abs(np.linalg.norm(quat_from_matrix(noisy)) - 1.0) < 1e-15


# -- Exp / Log ----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", EDGE_IDS)
def test_exp_matches_scipy(name):
    v = EDGE_ROTVECS[name]
    q = quat_exp(v)
    ref = Rotation.from_rotvec(v).as_quat()  # scipy keeps w >= 0 for angles <= pi
    np.testing.assert_allclose(q, ref, atol=1e-16, rtol=1e-15)
    assert abs(np.linalg.norm(q) - 1.0) < 1e-15


@pytest.mark.parametrize("name", EDGE_IDS)
def test_log_exp_round_trip_edge_cases(name):
    v = EDGE_ROTVECS[name]
    back = quat_log(quat_exp(v))
    angle = np.linalg.norm(v)
    if np.isclose(angle, np.pi, rtol=0, atol=1e-12):
        # exactly pi: v and -v are the same rotation, either answer is right
        assert np.allclose(back, v, atol=1e-15) or np.allclose(back, -v, atol=1e-15)
    else:
        # relative precision is kept even for tiny vectors
        np.testing.assert_allclose(back, v, rtol=1e-14, atol=1e-300)


@pytest.mark.parametrize("scale", [1e-12, 1e-15, 1e-30, 3e-8, 7e-5])
def test_tiny_rotations_keep_relative_precision(scale):
    v = np.array([0.3, -0.9, 0.2]) * scale
    q = quat_exp(v)
    # vector part is sin(t/2)/t v to full relative precision (np.sin is exact to 1 ulp there)
    t = np.linalg.norm(v)
    np.testing.assert_allclose(q[:3], np.sin(0.5 * t) / t * v, rtol=1e-15)
    np.testing.assert_allclose(quat_log(q), v, rtol=1e-15)
    # a quaternion built directly, not through quat_exp
    direct = np.concatenate([np.sin(0.5 * t) * v / t, [np.cos(0.5 * t)]])
    np.testing.assert_allclose(quat_log(direct), v, rtol=1e-14)


def test_exp_log_batched_equals_single():
    q = quat_exp(EDGE_ARRAY)
    v = quat_log(q)
    for n in range(len(EDGE_ARRAY)):
        np.testing.assert_array_equal(q[n], quat_exp(EDGE_ARRAY[n]))
        np.testing.assert_array_equal(v[n], quat_log(q[n]))
    assert quat_exp(EDGE_ARRAY.reshape(3, 6, 3)).shape == (3, 6, 4)
    assert quat_log(q.reshape(6, 3, 4)).shape == (6, 3, 3)


@pytest.mark.parametrize("eps", [1e-3, 1e-6, 1e-9, 1e-12])
def test_log_near_pi_and_w_near_zero(eps):
    axis = _unit([0.4, 0.5, -0.2])
    angle = np.pi - eps
    q = np.concatenate([np.sin(angle / 2) * axis, [np.cos(angle / 2)]])
    v = quat_log(q)
    np.testing.assert_allclose(np.linalg.norm(v), angle, rtol=0, atol=4e-16)
    np.testing.assert_allclose(v / np.linalg.norm(v), axis, atol=1e-15)
    # the same rotation with w slightly negative is the short way around the other direction
    v_neg = quat_log(-q)
    np.testing.assert_allclose(v_neg, v, atol=1e-15)
    q_over = np.concatenate([np.sin((np.pi + eps) / 2) * axis, [np.cos((np.pi + eps) / 2)]])
    assert q_over[3] < 0.0
    v_over = quat_log(q_over)
    np.testing.assert_allclose(v_over, -(np.pi - eps) * axis, atol=4e-15)


def test_log_exactly_pi_and_w_zero():
    for axis in (np.eye(3)[0], np.eye(3)[1], np.eye(3)[2], _DIAG):
        q = np.concatenate([axis, [0.0]])
        for sign in (1.0, -1.0):
            v = quat_log(sign * q)
            assert abs(np.linalg.norm(v) - np.pi) < 1e-15
            assert abs(abs(v @ axis) - np.pi) < 1e-15
            _assert_same_rotation(quat_exp(v), q, atol=1e-15)
    # negative zero in w
    v = quat_log(np.array([0.0, 1.0, 0.0, -0.0]))
    assert abs(np.linalg.norm(v) - np.pi) < 1e-15


def test_log_short_way_for_negative_w(rng):
    """For w < 0, Log returns the angle-in-[0, pi] vector of the same rotation."""
    axes = quat_normalize(rng.normal(size=(500, 3)))  # normalise 3-vectors too
    angles = rng.uniform(np.pi + 1e-6, 2 * np.pi - 1e-6, size=500)
    v = axes * angles[:, None]
    q = quat_exp(v)  # w = cos(angle / 2) < 0
    assert np.all(q[:, 3] < 0.0)
    back = quat_log(q)
    n = np.linalg.norm(back, axis=-1)
    assert np.all(n <= np.pi + 1e-15)
    np.testing.assert_allclose(back, axes * (angles - 2 * np.pi)[:, None], atol=1e-13)
    np.testing.assert_allclose(back, Rotation.from_quat(q).as_rotvec(), atol=1e-13)
    # Exp(Log(q)) is -q here: same rotation, other sign
    np.testing.assert_allclose(quat_exp(back), -q, atol=1e-15)


def test_exp_log_random_round_trip(rng):
    q = np.concatenate([_random_quats(rng, 1000), _edge_quats(), -_edge_quats()])
    v = quat_log(q)
    assert np.all(np.linalg.norm(v, axis=-1) <= np.pi + 1e-15)
    _assert_same_rotation(quat_exp(v), q, atol=1e-15)
    ref = Rotation.from_quat(q[:1000]).as_rotvec()
    np.testing.assert_allclose(v[:1000], ref, atol=1e-13)


# -- interpolation, sign handling, angle --------------------------------------------------------


def test_slerp_ends_and_matches_scipy(rng):
    q0 = _random_quats(rng, 20)
    q1 = _random_quats(rng, 20)
    _assert_same_rotation(quat_slerp(q0, q1, 0.0), q0, atol=1e-15)
    _assert_same_rotation(quat_slerp(q0, q1, 1.0), q1, atol=1e-14)
    s = np.linspace(0.0, 1.0, 11)
    for n in range(20):
        ref = Slerp([0.0, 1.0], Rotation.from_quat([q0[n], q1[n]]))(s).as_quat()
        _assert_same_rotation(quat_slerp(q0[n], q1[n], s), ref, atol=1e-13)


def test_slerp_midpoint_angle_and_constant_speed(rng):
    q0 = _random_quats(rng, 50)
    q1 = _random_quats(rng, 50)
    total = quat_angle(q0, q1)
    for s in (0.25, 0.5, 0.9):
        qs = quat_slerp(q0, q1, s)
        np.testing.assert_allclose(quat_angle(q0, qs), s * total, atol=1e-13)
        np.testing.assert_allclose(quat_angle(qs, q1), (1 - s) * total, atol=1e-13)


def test_slerp_takes_shortest_path_with_negated_end(rng):
    q0 = _random_quats(rng, 30)
    q1 = _random_quats(rng, 30)
    q1 = quat_align_sign(q1, q0)
    s = 0.3
    a = quat_slerp(q0, q1, s)
    b = quat_slerp(q0, -q1, s)
    _assert_same_rotation(a, b, atol=1e-14)
    # shortest: the rotation from q0 travels at most pi in total
    assert np.all(quat_angle(q0, b) <= s * np.pi + 1e-12)
    # a concrete case: 350 degrees "the long way" about z is 10 degrees the short way
    z = np.array([0.0, 0.0, 1.0])
    mid = quat_slerp(quat_identity(), quat_exp(np.radians(350.0) * z), 0.5)
    np.testing.assert_allclose(quat_log(mid), np.radians(-5.0) * z, atol=1e-15)


def test_slerp_broadcasts_s():
    q0 = quat_identity()
    q1 = quat_exp([0.0, 0.0, 1.0])
    out = quat_slerp(q0, q1, np.linspace(0, 1, 5))
    assert out.shape == (5, 4)
    np.testing.assert_allclose(quat_log(out)[:, 2], np.linspace(0, 1, 5), atol=1e-15)


def test_align_sign(rng):
    q = _random_quats(rng, 100)
    ref = _random_quats(rng, 100)
    out = quat_align_sign(q, ref)
    assert np.all(np.sum(out * ref, axis=-1) >= 0.0)
    _assert_same_rotation(out, q, atol=0.0)
    assert np.all(np.all(out == q, axis=-1) | np.all(out == -q, axis=-1))
    # a single reference for a whole batch
    out1 = quat_align_sign(q, ref[0])
    assert np.all(out1 @ ref[0] >= 0.0)


def test_make_continuous_synthetic(rng):
    q = quat_exp(np.cumsum(rng.normal(scale=0.05, size=(400, 3)), axis=0))
    flips = rng.random(400) < 0.3
    flipped = np.where(flips[:, None], -q, q)
    out = quat_make_continuous(flipped)
    assert np.all(np.sum(out[1:] * out[:-1], axis=-1) >= 0.0)
    np.testing.assert_array_equal(out[0], flipped[0])  # the first one is kept
    np.testing.assert_array_equal(np.abs(out), np.abs(flipped))
    np.testing.assert_array_equal(out, q * np.sign(q[:1] @ flipped[0]))
    # large steps (dot product only slightly negative) are flipped too
    steps = quat_exp(np.outer(np.arange(6), [0.0, 0.0, 2.6]))  # 149 degrees per step
    steps[1::2] *= -1.0  # with sign flips, consecutive dot products are -cos(1.3) = -0.27
    assert np.all(np.sum(steps[1:] * steps[:-1], axis=-1) < 0.0)
    smooth = quat_make_continuous(steps)
    assert np.all(np.sum(smooth[1:] * smooth[:-1], axis=-1) > 0.0)
    # input untouched, short inputs fine
    assert np.any(np.sum(flipped[1:] * flipped[:-1], axis=-1) < 0.0)
    np.testing.assert_array_equal(quat_make_continuous(q[:1]), q[:1])


def test_make_continuous_batched_sequences_and_single(rng):
    """Shape (N, M, 4): M independent sequences along axis 0, each as if alone."""
    q = quat_exp(np.cumsum(rng.normal(scale=0.1, size=(50, 3, 3)), axis=0))
    flipped = np.where((rng.random((50, 3)) < 0.4)[..., None], -q, q)
    out = quat_make_continuous(flipped)
    assert out.shape == (50, 3, 4)
    assert np.all(np.sum(out[1:] * out[:-1], axis=-1) >= 0.0)
    for m in range(3):
        np.testing.assert_array_equal(out[:, m], quat_make_continuous(flipped[:, m]))
    single = quat_exp([0.1, 0.2, 0.3])
    np.testing.assert_array_equal(quat_make_continuous(single), single)
    assert quat_make_continuous(np.zeros((0, 4))).shape == (0, 4)


def test_make_continuous_on_real_recording(shared_data):
    data = np.loadtxt(shared_data / "ar_table" / "table_01.txt")
    q = quat_normalize(data[:, 4:8])
    dots = np.sum(q[1:] * q[:-1], axis=-1)
    assert np.count_nonzero(dots < 0.0) >= 1, "the recording is documented to have sign flips"
    out = quat_make_continuous(q)
    assert np.all(np.sum(out[1:] * out[:-1], axis=-1) >= 0.0)
    # every rotation is unchanged: each output is +q or -q of its input
    same = np.all(out == q, axis=-1) | np.all(out == -q, axis=-1)
    assert np.all(same)
    np.testing.assert_allclose(quat_to_matrix(out), quat_to_matrix(q), atol=1e-15)


def test_angle_matches_scipy_and_is_sign_invariant(rng):
    q0 = np.concatenate([_random_quats(rng, 200), _edge_quats()])
    q1 = np.concatenate([_random_quats(rng, 200), _edge_quats()[::-1]])
    ref = (Rotation.from_quat(q0).inv() * Rotation.from_quat(q1)).magnitude()
    a = quat_angle(q0, q1)
    np.testing.assert_allclose(a, ref, atol=1e-13)
    assert np.all((a >= 0.0) & (a <= np.pi))
    np.testing.assert_array_equal(quat_angle(q0, -q1), a)
    np.testing.assert_allclose(quat_angle(q1, q0), a, atol=1e-15)
    # tiny angles: absolute precision near 1e-16 rad (the product rounds at that level)
    v = np.array([1e-11, -2e-11, 0.5e-11])
    q = _random_quats(rng, 1)[0]
    a_tiny = quat_angle(q, quat_multiply(q, quat_exp(v)))
    np.testing.assert_allclose(a_tiny, np.linalg.norm(v), rtol=0, atol=1e-15)
    np.testing.assert_allclose(
        quat_angle(quat_identity(), quat_exp(v)), np.linalg.norm(v), rtol=1e-15
    )


# -- SO(3) Jacobians ----------------------------------------------------------------------------

_JAC_CASES = {
    "zero": np.zeros(3),
    "tiny": _rv(_DIAG, 1e-8),
    "below_switch": _rv(_DIAG, 0.9e-3),
    "above_switch": _rv(_DIAG, 1.1e-3),
    "generic": np.array([0.3, -1.1, 0.7]),
    "large": _rv([0.1, 0.2, 1.0], 3.0),
}


def _fd_right_jacobian(phi, h=1e-6):
    """Column i = Log(Exp(phi)^-1 Exp(phi + h e_i)) / h, central."""
    q = quat_exp(phi)
    cols = []
    for i in range(3):
        d = np.zeros(3)
        d[i] = h
        plus = quat_log(quat_multiply(quat_conjugate(q), quat_exp(phi + d)))
        minus = quat_log(quat_multiply(quat_conjugate(q), quat_exp(phi - d)))
        cols.append((plus - minus) / (2 * h))
    return np.stack(cols, axis=-1)


def _fd_right_jacobian_inverse(phi, h=1e-6):
    """Column i = (Log(Exp(phi) Exp(h e_i)) - Log(Exp(phi) Exp(-h e_i))) / 2h."""
    q = quat_exp(phi)
    cols = []
    for i in range(3):
        d = np.zeros(3)
        d[i] = h
        plus = quat_log(quat_multiply(q, quat_exp(d)))
        minus = quat_log(quat_multiply(q, quat_exp(-d)))
        cols.append((plus - minus) / (2 * h))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("name", list(_JAC_CASES))
def test_right_jacobian_vs_finite_differences(name):
    phi = _JAC_CASES[name]
    np.testing.assert_allclose(so3_right_jacobian(phi), _fd_right_jacobian(phi), atol=2e-9)
    np.testing.assert_allclose(
        so3_right_jacobian_inverse(phi), _fd_right_jacobian_inverse(phi), atol=2e-9
    )
    np.testing.assert_allclose(
        so3_right_jacobian(phi) @ so3_right_jacobian_inverse(phi), np.eye(3), atol=1e-14
    )


def test_right_jacobian_properties(rng):
    phi = rng.normal(size=(100, 3))
    phi *= (rng.uniform(0, 3.1, 100) / np.linalg.norm(phi, axis=-1))[:, None]
    jr = so3_right_jacobian(phi)
    jri = so3_right_jacobian_inverse(phi)
    np.testing.assert_allclose(jr @ jri, np.broadcast_to(np.eye(3), jr.shape), atol=1e-12)
    # J_r(phi) phi = phi and J_l(phi) = J_r(-phi) = R(phi) J_r(phi)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", jr, phi), phi, atol=1e-14)
    np.testing.assert_allclose(
        so3_right_jacobian(-phi), quat_to_matrix(quat_exp(phi)) @ jr, atol=1e-14
    )
    # batched equals single
    for n in range(0, 100, 17):
        np.testing.assert_allclose(so3_right_jacobian(phi[n]), jr[n], atol=0, rtol=0)
        np.testing.assert_allclose(so3_right_jacobian_inverse(phi[n]), jri[n], atol=0, rtol=0)


def test_skew_is_cross_product(rng):
    a = rng.normal(size=(10, 3))
    b = rng.normal(size=(10, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", skew(a), b), np.cross(a, b), atol=1e-15)
    np.testing.assert_array_equal(skew(a), -np.swapaxes(skew(a), -1, -2))
