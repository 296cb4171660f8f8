"""SO(3) kernels of trackflow.math._lie: maps, Jacobians against finite differences on curated
edge-case rotations (identity, tiny, at the series threshold, pi - eps, exactly pi, random), the
batched NumPy forms, and compiled copies equal to the reference."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.math import (
    _lie,
    kernels_for,
    numba_available,
    quat_between,
    quat_exp,
    quat_from_matrix,
    quat_log,
    quat_rminus,
    quat_rplus,
    so3_right_jacobian,
    so3_right_jacobian_inverse,
    use_backend,
)

_AXIS = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
_RNG = np.random.default_rng(7)
CURATED = {
    "identity": np.zeros(3),
    "tiny": 1e-9 * _AXIS,
    "below-threshold": 0.999 * _lie.SMALL_ANGLE * _AXIS,
    "above-threshold": 1.001 * _lie.SMALL_ANGLE * _AXIS,
    "random": _RNG.normal(size=3),
    "pi-eps": (np.pi - 1e-7) * _AXIS,
    "pi": np.pi * _AXIS,
    "pi-on-x": np.array([np.pi, 0.0, 0.0]),
}
NAMES = list(CURATED)
H = 1e-6  # finite-difference step [rad]
BASE = _lie.qexp(np.array([0.4, 0.1, -0.7]))


def _unwrap(w, ref):
    """The rotation vector of ``w``'s rotation nearest to ``ref`` (only differs near pi)."""
    n = np.linalg.norm(w)
    if n > 2.0 and np.dot(w, ref) < 0.0:
        return w - 2.0 * np.pi * w / n
    return w


def _fd(f, ref):
    """Central differences (3 x 3) of a rotation-vector valued ``f`` of a right error."""
    J = np.empty((3, 3))
    for k in range(3):
        e = np.zeros(3)
        e[k] = H
        J[:, k] = (_unwrap(f(e), ref) - _unwrap(f(-e), ref)) / (2.0 * H)
    return J


@pytest.mark.parametrize("name", NAMES)
def test_exp_log_round_trip_keeps_relative_precision(name):
    v = CURATED[name]
    back = _lie.qlog(_lie.qexp(v))
    back_m = _lie.so3_log(_lie.so3_exp(v))
    tol = 4e-16 * max(np.linalg.norm(v), 1e-300)
    if name.startswith("pi"):
        # at exactly pi the sign is a choice: the same rotation
        back, back_m = _unwrap(back, v), _unwrap(back_m, v)
        tol = 1e-12
    np.testing.assert_allclose(back, v, rtol=0, atol=tol)
    np.testing.assert_allclose(back_m, v, rtol=0, atol=max(tol, 1e-15))
    assert np.linalg.norm(_lie.qlog(_lie.qexp(v))) <= np.pi + 1e-15


def test_series_and_closed_forms_agree_at_the_threshold():
    # the coefficients are smooth in t^2: across the switch they may move by rounding only
    t_lo, t_hi = (1.0 - 1e-9) * _lie.SMALL_ANGLE, (1.0 + 1e-9) * _lie.SMALL_ANGLE
    np.testing.assert_allclose(
        _lie.exp_coefficients(t_lo**2), _lie.exp_coefficients(t_hi**2), rtol=2e-15, atol=0
    )
    (a_lo, b_lo, c_lo), (a_hi, b_hi, c_hi) = (
        _lie.jacobian_coefficients(t**2) for t in (t_lo, t_hi)
    )
    # a = (1 - cos t)/t^2 is computed as the recorded filter runs were (bit for bit): its
    # cancellation costs up to ~1e-8 relative just above the switch (documented in _lie)
    assert a_lo == pytest.approx(a_hi, rel=1e-8, abs=0)
    # b and c multiply [v]x^2 (size t^2): that product is what must agree to rounding
    assert b_lo * t_lo**2 == pytest.approx(b_hi * t_hi**2, rel=0, abs=2e-16)
    assert c_lo * t_lo**2 == pytest.approx(c_hi * t_hi**2, rel=0, abs=2e-16)
    n_lo, n_hi = 0.5 * t_lo, 0.5 * t_hi  # Log switches on |q_xyz| = sin(t/2) ~ t/2
    w_lo, w_hi = np.sqrt(1.0 - n_lo**2), np.sqrt(1.0 - n_hi**2)
    np.testing.assert_allclose(
        _lie.log_coefficient(n_lo, w_lo), _lie.log_coefficient(n_hi, w_hi), rtol=2e-15, atol=0
    )


@pytest.mark.parametrize("name", NAMES)
def test_J_Exp_v_is_the_right_jacobian(name):
    v = CURATED[name]
    q0 = _lie.qexp(v)
    fd = _fd(lambda d: _lie.qrminus(_lie.qexp(v + d), q0), np.zeros(3))
    np.testing.assert_allclose(_lie.right_jac(v), fd, rtol=0, atol=1e-9)
    # the kernel's a = (1 - cos t)/t^2 (bit for bit with recorded runs) against the NumPy
    # form's 2 sin^2(t/2)/t^2: they differ by the former's cancellation, ~2e-13 at the switch
    np.testing.assert_allclose(_lie.right_jac(v), so3_right_jacobian(v), rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", NAMES)
def test_J_Log_R_is_the_inverse_right_jacobian(name):
    v = CURATED[name]
    q0 = _lie.qexp(v)
    fd = _fd(lambda d: _lie.qlog(_lie.qrplus(q0, d)), v)
    J = _lie.right_jac_inv(v)
    np.testing.assert_allclose(J, fd, rtol=0, atol=1e-8)
    # Jr's a coefficient carries the cancellation of (1 - cos t)/t^2 (about 2e-13 absolute in
    # the product just above the switch; see test_series_and_closed_forms_agree_at_the_threshold)
    np.testing.assert_allclose(J @ _lie.right_jac(v), np.eye(3), rtol=0, atol=1e-12)
    np.testing.assert_allclose(J, so3_right_jacobian_inverse(v), rtol=0, atol=1e-14)


@pytest.mark.parametrize("name", NAMES)
def test_rminus_jacobians(name):
    v = CURATED[name]
    qa, qb = BASE, _lie.qrplus(BASE, v)
    J_d_qb, J_d_qa = _lie.qrminus_jacobians(qb, qa)
    fd_b = _fd(lambda e: _lie.qrminus(_lie.qrplus(qb, e), qa), v)
    fd_a = _fd(lambda e: _lie.qrminus(qb, _lie.qrplus(qa, e)), v)
    np.testing.assert_allclose(J_d_qb, fd_b, rtol=0, atol=1e-8)
    np.testing.assert_allclose(J_d_qa, fd_a, rtol=0, atol=1e-8)


@pytest.mark.parametrize("name", NAMES)
def test_rplus_jacobians(name):
    v = CURATED[name]
    out = _lie.qrplus(BASE, v)
    J_out_q, J_out_v = _lie.qrplus_jacobians(BASE, v)
    fd_q = _fd(lambda e: _lie.qrminus(_lie.qrplus(_lie.qrplus(BASE, e), v), out), np.zeros(3))
    fd_v = _fd(lambda e: _lie.qrminus(_lie.qrplus(BASE, v + e), out), np.zeros(3))
    np.testing.assert_allclose(J_out_q, fd_q, rtol=0, atol=1e-9)
    np.testing.assert_allclose(J_out_v, fd_v, rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", NAMES)
def test_between_jacobians(name):
    v = CURATED[name]
    qa, qb = BASE, _lie.qrplus(BASE, v)
    c = _lie.qbetween(qa, qb)
    J_c_qa, J_c_qb = _lie.qbetween_jacobians(qa, qb)
    fd_a = _fd(lambda e: _lie.qrminus(_lie.qbetween(_lie.qrplus(qa, e), qb), c), np.zeros(3))
    fd_b = _fd(lambda e: _lie.qrminus(_lie.qbetween(qa, _lie.qrplus(qb, e)), c), np.zeros(3))
    np.testing.assert_allclose(J_c_qa, fd_a, rtol=0, atol=1e-9)
    np.testing.assert_allclose(J_c_qb, fd_b, rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", NAMES)
def test_exp_jac_is_the_derivative_of_the_components(name):
    v = CURATED[name]
    fd = np.empty((4, 3))
    for k in range(3):
        e = np.zeros(3)
        e[k] = H
        fd[:, k] = (_lie.qexp(v + e) - _lie.qexp(v - e)) / (2.0 * H)
    np.testing.assert_allclose(_lie.exp_jac(v), fd, rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", NAMES)
def test_rplus_rminus_between_are_inverse_and_consistent(name):
    v = CURATED[name]
    qb = _lie.qrplus(BASE, v)
    np.testing.assert_allclose(qb, _lie.qmul(BASE, _lie.qexp(v)), rtol=0, atol=0)
    d = _lie.qrminus(qb, BASE)
    np.testing.assert_allclose(_unwrap(d, v), v, rtol=0, atol=1e-12)
    np.testing.assert_allclose(
        _lie.qbetween(BASE, qb), _lie.qmul(BASE * [-1, -1, -1, 1], qb), rtol=0, atol=0
    )
    # the batched NumPy forms give the same numbers
    np.testing.assert_allclose(quat_rplus(BASE, v), qb, rtol=0, atol=1e-16)
    np.testing.assert_allclose(quat_rminus(qb, BASE), d, rtol=0, atol=1e-15)
    np.testing.assert_allclose(quat_between(BASE, qb), _lie.qbetween(BASE, qb), atol=1e-16)
    np.testing.assert_allclose(quat_exp(v), _lie.qexp(v), rtol=0, atol=1e-16)
    np.testing.assert_allclose(quat_log(qb), _lie.qlog(qb), rtol=0, atol=1e-15)


@pytest.mark.parametrize("name", NAMES)
def test_quaternion_of_a_matrix(name):
    r = _lie.so3_exp(CURATED[name])
    q = _lie.quat_of_rotmat(r)
    assert q[3] >= 0.0 and abs(np.dot(q, q) - 1.0) < 1e-15
    np.testing.assert_allclose(_lie.rotmat(q), r, rtol=0, atol=1e-15)
    ref = quat_from_matrix(r)
    np.testing.assert_allclose(q * np.sign(q @ ref), ref, rtol=0, atol=1e-15)


@pytest.mark.skipif(not numba_available(), reason="numba not installed")
def test_compiled_kernels_equal_the_reference():
    with use_backend("numba"):
        k = kernels_for(_lie)
        for v in CURATED.values():
            qb = _lie.qrplus(BASE, v)
            for f, args in (
                ("qexp", (v,)),
                ("qlog", (qb,)),
                ("qrplus", (BASE, v)),
                ("qrminus", (qb, BASE)),
                ("qbetween", (BASE, qb)),
                ("so3_exp", (v,)),
                ("so3_log", (_lie.so3_exp(v),)),
                ("right_jac", (v,)),
                ("right_jac_inv", (v,)),
                ("exp_jac", (v,)),
            ):
                np.testing.assert_allclose(
                    getattr(k, f)(*args), getattr(_lie, f)(*args), rtol=0, atol=4e-16
                )
