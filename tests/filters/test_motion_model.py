"""Motion models: time-update and measurement Jacobians against finite differences."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from trackflow.filters import MotionModel
from trackflow.math import _lie as _core

LAYOUTS = [(n_dp, n_do) for n_dp in range(4) for n_do in range(3)]
EPS = 1e-6


def random_state(model: MotionModel, rng, rate: float = 1.0) -> np.ndarray:
    x = model.initial_state()
    npl = model.n_dp + 1
    x[: 3 * npl] = rng.normal(0.0, rate, 3 * npl)
    if model.n_do >= 0:
        x[3 * npl : 3 * npl + 4] = Rotation.random(random_state=rng).as_quat()
        x[3 * npl + 4 :] = rng.normal(0.0, rate, 3 * model.n_do)
    return x


def fd_transition(model, x, dt, formulation):
    _, J = model.transition(x, dt, formulation)
    n = J.shape[0]
    num = np.zeros((n, n))
    for j in range(n):
        d = np.zeros(n)
        d[j] = EPS
        if formulation == "additive":  # plain vector perturbation, no re-normalisation
            xp, xm = x + d, x - d
        else:
            xp, xm = model.retract(x, d), model.retract(x, -d)
        fp, _ = model.transition(xp, dt, formulation)
        fm, _ = model.transition(xm, dt, formulation)
        f0, _ = model.transition(x, dt, formulation)
        num[:, j] = (model.local(fp, f0, formulation) - model.local(fm, f0, formulation)) / (
            2 * EPS
        )
    return J, num


@pytest.mark.parametrize("formulation", ["error_state", "additive"])
@pytest.mark.parametrize(("n_dp", "n_do"), LAYOUTS)
def test_transition_jacobian_matches_finite_differences(n_dp, n_do, formulation, rng):
    model = MotionModel(n_dp, n_do)
    for dt, rate in ((0.05, 2.0), (0.013, 0.0), (0.3, 0.5)):
        x = random_state(model, rng, rate)
        J, num = fd_transition(model, x, dt, formulation)
        np.testing.assert_allclose(J, num, atol=2e-7, rtol=1e-6)


@pytest.mark.parametrize("formulation", ["error_state", "additive"])
@pytest.mark.parametrize(("n_dp", "n_do"), LAYOUTS)
def test_measurement_jacobians_match_finite_differences(n_dp, n_do, formulation, rng):
    model = MotionModel(n_dp, n_do)
    x = random_state(model, rng)
    npl = n_dp + 1
    kinds = [(lp, -1) for lp in range(min(n_dp, 2) + 1)]
    kinds += [(-1, lo) for lo in range(min(n_do, 1) + 1)] + [(0, 0)]
    for lp, lo in kinds:
        zp = x[3 * lp : 3 * lp + 3] if lp >= 0 else None
        if lo == 0:
            zo = x[3 * npl : 3 * npl + 4]
        elif lo == 1:
            zo = x[3 * npl + 4 : 3 * npl + 7]
        else:
            zo = None
        y0, H = model.residual(x, lp, lo, zp, zo, formulation)
        np.testing.assert_allclose(y0, 0.0, atol=1e-12)
        n = H.shape[1]
        num = np.zeros_like(H)
        for j in range(n):
            d = np.zeros(n)
            d[j] = EPS
            if formulation == "additive":
                xp, xm = x + d, x - d
            else:
                xp, xm = model.retract(x, d), model.retract(x, -d)
            yp, _ = model.residual(xp, lp, lo, zp, zo, formulation)
            ym, _ = model.residual(xm, lp, lo, zp, zo, formulation)
            num[:, j] = -(yp - ym) / (2 * EPS)  # y = z - h(x): dy/dx = -H
        np.testing.assert_allclose(H, num, atol=1e-7, err_msg=f"lp={lp} lo={lo}")


def test_quaternion_normalisation_jacobian_is_eq_6_23(rng):
    """H_R = (D I - r r^T) / (L D) for an unnormalised state quaternion."""
    model = MotionModel(0, 0)
    x = random_state(model, rng)
    x[3:7] *= 1.3
    _, H = model.residual(x, -1, 0, None, x[3:7] / 1.3, "additive")
    r = x[3:7]
    d = r @ r
    np.testing.assert_allclose(H[:, 3:7], (d * np.eye(4) - np.outer(r, r)) / (math.sqrt(d) * d))


def test_b_matrix_and_its_zero_rotation_limit(rng):
    """B = d(r * Exp(b))/db: finite differences at b != 0, the thesis's B-tilde at b = 0."""
    r = Rotation.random(random_state=rng).as_quat()
    for b in (rng.normal(size=3), np.array([1e-6, -2e-6, 5e-7]), np.zeros(3)):
        B = _core.left_mult(r) @ _core.exp_jac(b)
        num = np.zeros((4, 3))
        for j in range(3):
            d = np.zeros(3)
            d[j] = EPS
            num[:, j] = (_core.qmul(r, _core.qexp(b + d)) - _core.qmul(r, _core.qexp(b - d))) / (
                2 * EPS
            )
        np.testing.assert_allclose(B, num, atol=1e-8)
    x, y, z, w = r
    b_tilde = 0.5 * np.array([[w, -z, y], [z, w, -x], [-y, x, w], [-x, -y, -z]])
    np.testing.assert_allclose(_core.left_mult(r) @ _core.exp_jac(np.zeros(3)), b_tilde)


def test_white_noise_is_ude_eq_23():
    """Random acceleration of intensity a (constant-velocity model): Ude's eq. 23 blocks."""
    a, alpha, dt = 0.7**2, 1.3**2, 0.04
    Q = MotionModel(1, 1, noise=(0.0, 0.7, 0.0, 1.3)).process_noise(dt)
    blk = np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    np.testing.assert_allclose(Q[0:12:3, 0:12:3][:2, :2], a * blk)
    np.testing.assert_allclose(Q[6:12:3, 6:12:3], alpha * blk)
    assert np.all(Q[:6, 6:] == 0.0)


def test_white_noise_matches_monte_carlo_integration(rng):
    """Q of a white jerk (n_dp = 2) equals the covariance of a finely simulated integrator."""
    dt, s, n, steps = 0.1, 2.0, 20000, 200
    h = dt / steps
    state = np.zeros((n, 3))
    for _ in range(steps):
        state[:, 0] += state[:, 1] * h + state[:, 2] * h * h / 2
        state[:, 1] += state[:, 2] * h
        state[:, 2] += rng.normal(0.0, s * math.sqrt(h), n)
    Q = MotionModel(2, -1, noise=(0.0, 0.0, s)).process_noise(dt)[0:9:3, 0:9:3]
    emp = np.cov(state.T)
    np.testing.assert_allclose(
        emp, Q, rtol=0.06, atol=0.04 * np.sqrt(np.outer(np.diag(Q), np.diag(Q))).max()
    )


def test_thesis_noise_is_diagonal_eq_6_21():
    Q = MotionModel(2, 1, noise=(1, 2, 3, 4, 5), kind="thesis").process_noise(0.1)
    expected = np.repeat(np.array([1, 2, 3, 4, 5]) * 0.1, 3) ** 2
    np.testing.assert_allclose(Q, np.diag(expected))
    # additive formulation: isotropic quaternion block (q dt / 2)^2 I_4
    m = MotionModel(0, 0, noise=(1.0, 4.0), kind="thesis")
    Qa = m.process_noise(0.1, formulation="additive")
    np.testing.assert_allclose(Qa[3:, 3:], np.eye(4) * (0.4 / 2) ** 2, atol=1e-15)


def test_static_model_and_sizes():
    m = MotionModel.static()
    assert (m.n_dp, m.n_do, m.noise) == (0, 0, (0.0, 0.0))
    assert np.all(m.process_noise(10.0) == 0)
    assert MotionModel(2, 2).state_size == 7 + 3 * 4
    assert MotionModel(2, 2).error_size == 6 + 3 * 4
    assert MotionModel(2, -1).state_size == 9
    assert MotionModel(-1, 2).error_size == 9


@pytest.mark.parametrize(
    "kwargs",
    [
        {"n_dp": -2},
        {"n_dp": -1, "n_do": -1},
        {"n_dp": 1.5},
        {"noise": (1, 2)},
        {"noise": (0, 0, -1, 0, 1)},
        {"noise": (0, 0, np.nan, 0, 1)},
        {"kind": "pink"},
    ],
)
def test_bad_models_raise(kwargs):
    with pytest.raises(ValueError):
        MotionModel(**kwargs)
