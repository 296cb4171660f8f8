"""Quaternion-space filter of Ude (1999): prediction Jacobians and noise, manifold Gauss-Newton,
covariance mapping to trackflow, NEES consistency, and the section-5 figures."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import quad_vec
from scipy.optimize import least_squares

from trackflow import UncertainPose
from trackflow.filters.quaternion_space.camera_features import CameraObservation, PinholeCamera
from trackflow.filters.quaternion_space.gauss_newton import (
    QuaternionSpaceFilter,
    QuaternionSpaceState,
    adjust_state,
    estimate_pose,
    predict_state,
    prior_residual,
    process_noise,
    transition_jacobian,
)
from trackflow.math import (
    Pose,
    quat_conjugate,
    quat_exp,
    quat_log,
    quat_multiply,
    quat_normalize,
    quat_to_matrix,
)

REPO = Path(__file__).resolve().parents[2]


def _load_experiment():
    spec = importlib.util.spec_from_file_location("ude_cube", REPO / "experiments/ude_cube.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["ude_cube"] = mod
    spec.loader.exec_module(mod)
    return mod


def _random_state(rng, time=0.0) -> QuaternionSpaceState:
    A = rng.normal(size=(12, 12)) * 0.01
    return QuaternionSpaceState(
        time,
        rng.normal(0, 0.3, 3),
        quat_normalize(rng.normal(size=4)),
        rng.normal(0, 0.3, 3),
        rng.normal(0, 0.8, 3),
        A @ A.T + 1e-6 * np.eye(12),
    )


def _boxminus(x: QuaternionSpaceState, y: QuaternionSpaceState) -> np.ndarray:
    """Error e with x = y (+) e in the filter's parameterisation."""
    return np.concatenate(
        [
            x.position - y.position,
            quat_log(quat_multiply(x.quaternion, quat_conjugate(y.quaternion))),
            x.velocity - y.velocity,
            x.angular_velocity - y.angular_velocity,
        ]
    )


def _boxplus(y: QuaternionSpaceState, e: np.ndarray) -> QuaternionSpaceState:
    return QuaternionSpaceState(
        y.time,
        y.position + e[0:3],
        quat_multiply(quat_exp(e[3:6]), y.quaternion),
        y.velocity + e[6:9],
        y.angular_velocity + e[9:12],
        y.covariance,
    )


# -- prediction ----------------------------------------------------------------------------------


def test_prediction_follows_constant_velocity_motion(rng):
    s = _random_state(rng)
    pred, _ = predict_state(s, 0.4, 0.0, 0.0)
    # Two half steps give the same as one step (exact for zero acceleration).
    half, _ = predict_state(s, 0.2, 0.0, 0.0)
    half2, _ = predict_state(half, 0.2, 0.0, 0.0)
    np.testing.assert_allclose(_boxminus(pred, half2), 0.0, atol=1e-12)
    np.testing.assert_allclose(pred.position, s.position + 0.4 * s.velocity)
    # Orientation: rotation about the world-frame axis w by |w| dt (paper eq. 12, full angle).
    R = quat_to_matrix(pred.quaternion) @ quat_to_matrix(s.quaternion).T
    np.testing.assert_allclose(R, quat_to_matrix(quat_exp(0.4 * s.angular_velocity)), atol=1e-12)
    assert pred.time == pytest.approx(0.4)


@pytest.mark.parametrize("w_scale", [0.0, 1e-7, 1.0, 5.0])
def test_transition_jacobian_vs_finite_differences(rng, w_scale):
    s = _random_state(rng)
    s = QuaternionSpaceState(
        0.0, s.position, s.quaternion, s.velocity, w_scale * s.angular_velocity, s.covariance
    )
    dt = 0.3
    J = transition_jacobian(s.angular_velocity, dt)
    nominal, J2 = predict_state(s, dt, 0.0, 0.0)
    np.testing.assert_array_equal(J, J2)
    eps = 1e-6
    J_fd = np.zeros((12, 12))
    for i in range(12):
        e = np.zeros(12)
        e[i] = eps
        plus, _ = predict_state(_boxplus(s, e), dt, 0.0, 0.0)
        minus, _ = predict_state(_boxplus(s, -e), dt, 0.0, 0.0)
        J_fd[:, i] = (_boxminus(plus, nominal) - _boxminus(minus, nominal)) / (2 * eps)
    np.testing.assert_allclose(J, J_fd, atol=1e-8)


def test_G_matches_integral_and_printed_eq21(rng):
    w = rng.normal(size=3)
    dt = 0.7
    G = transition_jacobian(w, dt)[3:6, 9:12]
    G_int, _ = quad_vec(lambda s: quat_to_matrix(quat_exp(s * w)), 0.0, dt, epsabs=1e-13)
    np.testing.assert_allclose(G, G_int, atol=1e-10)
    # Eq. 21 as printed.
    th = dt * np.linalg.norm(w)
    n = w / np.linalg.norm(w)
    s = 2 / th * np.sin(th / 2) ** 2
    c = 2 / th * np.sin(th / 2) * np.cos(th / 2)
    N = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
    G21 = dt * ((1 - c) * np.outer(n, n) + c * np.eye(3) + s * N)
    np.testing.assert_allclose(G, G21, atol=1e-12)


def test_process_noise_is_integrated_white_acceleration():
    dt, a, alpha = 0.25, 2.0, 0.3
    Q = process_noise(dt, a, alpha)

    # Noise entering at time s moves (p, v) by ((dt - s), 1) per unit acceleration impulse.
    def integrand(s):
        g = np.array([dt - s, 1.0])
        return np.outer(g, g)

    Qs, _ = quad_vec(integrand, 0.0, dt)
    for k, psd in ((0, a), (3, alpha)):
        idx = [k, k + 6]
        np.testing.assert_allclose(Q[np.ix_(idx, idx)], psd * Qs, rtol=1e-12)
    with pytest.raises(ValueError):
        process_noise(-1.0, a, alpha)


def test_paper_literal_mode_scales_orientation_terms(rng):
    s = _random_state(rng)
    full, _ = predict_state(s, 0.1, 1.0, 0.5, "full")
    lit, _ = predict_state(s, 0.1, 1.0, 0.5, "paper")
    np.testing.assert_allclose(lit.covariance[:3, :3], full.covariance[:3, :3])
    assert not np.allclose(lit.covariance[3:6, 3:6], full.covariance[3:6, 3:6])
    with pytest.raises(ValueError, match="orientation_error"):
        predict_state(s, 0.1, 1.0, 0.5, "half")


# -- adjustment ----------------------------------------------------------------------------------


def test_prior_residual_jacobian_vs_finite_differences(rng):
    pred = _random_state(rng)
    x = _boxplus(pred, rng.normal(0, 0.4, 12)).as_vector()
    r, J = prior_residual(x, pred)
    eps = 1e-6
    J_fd = np.zeros((12, 12))
    for i in range(12):
        d = np.zeros(12)
        d[i] = eps
        xs = [
            np.concatenate(
                [
                    x[:3] + sg * d[:3],
                    quat_multiply(quat_exp(sg * d[3:6]), x[3:7]),
                    x[7:] + sg * d[6:],
                ]
            )
            for sg in (1, -1)
        ]
        J_fd[:, i] = (prior_residual(xs[0], pred)[0] - prior_residual(xs[1], pred)[0]) / (2 * eps)
    np.testing.assert_allclose(J, J_fd, atol=1e-8)


def _scene(rng, n_cams=2):
    """Cameras looking at the origin from ~3 m and a few model points and segments."""
    cams = []
    for k in range(n_cams):
        ang = 0.5 * (k - (n_cams - 1) / 2)
        pos = np.array([3.0 * np.sin(ang), 0.0, -3.0 * np.cos(ang)])
        q = quat_exp(np.array([0.0, -ang, 0.0]))
        cams.append(PinholeCamera(800.0, 800.0, 320.0, 240.0, 640, 480, Pose(pos, q)))
    pts = rng.uniform(-0.3, 0.3, (6, 3))
    segs = rng.uniform(-0.3, 0.3, (4, 2, 3))
    return cams, pts, segs


def _observe(cams, pts, segs, p, q, rng, sigma=1.0):
    obs = []
    R = quat_to_matrix(q)
    for cam in cams:
        uv, _ = cam.project(pts @ R.T + p)
        y_s, _ = CameraObservation(
            cam,
            segment_model=segs,
            segment_meas=np.zeros((len(segs), 3)),
            segment_cov=np.tile(np.eye(3), (len(segs), 1, 1)),
        ).predict(p, q)
        y_s = y_s.reshape(-1, 3)
        sc = np.tile(np.diag([sigma**2, sigma**2, (sigma / 100.0) ** 2]), (len(segs), 1, 1))
        pc = np.tile(sigma**2 * np.eye(2), (len(pts), 1, 1))
        noise_s = rng.standard_normal(y_s.shape) * np.array([sigma, sigma, sigma / 100.0])
        obs.append(
            CameraObservation(
                cam,
                point_model=pts,
                point_meas=uv + sigma * rng.standard_normal(uv.shape),
                point_cov=pc,
                segment_model=segs,
                segment_meas=y_s + noise_s,
                segment_cov=sc,
            )
        )
    return obs


def test_gauss_newton_matches_scipy_least_squares(rng):
    cams, pts, segs = _scene(rng)
    truth_q = quat_exp(np.array([0.2, -0.1, 0.3]))
    truth_p = np.array([0.05, -0.02, 0.1])
    obs = _observe(cams, pts, segs, truth_p, truth_q, rng)
    S = np.diag([1e-4] * 3 + [1e-3] * 3 + [1e-2] * 3 + [1e-2] * 3)
    pred = QuaternionSpaceState(
        0.0,
        truth_p + 0.01,
        quat_multiply(quat_exp(np.array([0.02, 0.0, -0.02])), truth_q),
        np.array([0.1, 0.0, 0.0]),
        np.array([0.0, 0.2, 0.0]),
        S,
    )
    state, report = adjust_state(pred, obs, gradient_tolerance=1e-10)
    assert report.converged
    L = np.linalg.cholesky(np.linalg.inv(S))

    def cost_terms(e):
        x = _boxplus(pred, e)
        r = [o.whitened_residual(x.position, x.quaternion)[0] for o in obs]
        return np.concatenate(r + [L.T @ _boxminus(x, pred)])

    ref = least_squares(cost_terms, np.zeros(12), xtol=1e-15, ftol=1e-15, gtol=1e-15)
    x_ref = _boxplus(pred, ref.x)
    np.testing.assert_allclose(_boxminus(state, x_ref), 0.0, atol=1e-9)

    # Eq. 30: covariance = inverse Gauss-Newton Hessian at the solution, here in e-coordinates
    # of the solution; compare with the finite-difference Jacobian of the same criterion.
    def at_solution(e):
        x = _boxplus(state, e)
        r = [o.whitened_residual(x.position, x.quaternion)[0] for o in obs]
        return np.concatenate(r + [L.T @ _boxminus(x, pred)])

    eps = 1e-7
    D = np.stack(
        [
            (at_solution(eps * np.eye(12)[i]) - at_solution(-eps * np.eye(12)[i])) / (2 * eps)
            for i in range(12)
        ],
        axis=1,
    )
    np.testing.assert_allclose(state.covariance, np.linalg.inv(D.T @ D), rtol=1e-4, atol=1e-12)


def test_gauss_newton_converges_fast_and_lm_recovers_bad_start(rng):
    cams, pts, segs = _scene(rng, n_cams=1)
    truth_q = quat_exp(np.array([0.1, 0.2, -0.1]))
    truth_p = np.array([0.0, 0.02, 0.0])
    obs = _observe(cams, pts, segs, truth_p, truth_q, rng, sigma=0.5)
    # Near start: gradient norm falls by orders of magnitude per iteration.
    p, q, _, rep = estimate_pose(
        obs, truth_p + 0.01, quat_multiply(quat_exp([0.02, 0, 0]), truth_q), "gauss_newton", 0.0, 4
    )
    g = np.linalg.norm(rep.gradients, axis=1)
    assert g[1] < 1e-2 * g[0] and g[2] < 1e-2 * g[1]
    # Far start (0.5 m, ~50 deg): Levenberg-Marquardt reaches the same minimum.
    p_lm, q_lm, cov, rep_lm = estimate_pose(
        obs, truth_p + [0.3, -0.3, 0.3], quat_multiply(quat_exp([0.5, -0.6, 0.3]), truth_q)
    )
    assert rep_lm.converged
    np.testing.assert_allclose(p_lm, p, atol=1e-7)
    assert np.linalg.norm(quat_log(quat_multiply(q_lm, quat_conjugate(q)))) < 1e-7
    assert np.all(np.linalg.eigvalsh(cov) > 0)


def test_uncertain_pose_covariance_mapping_monte_carlo(rng):
    s = _random_state(rng)
    up = s.uncertain_pose()
    assert isinstance(up, UncertainPose)
    n = 20000
    E = rng.multivariate_normal(np.zeros(12), s.covariance, size=n)
    R = quat_to_matrix(s.quaternion)
    q_true = quat_multiply(quat_exp(E[:, 3:6]), s.quaternion)
    # trackflow: t_true = t + dt, R_true = R Exp(dtheta)
    dtheta = quat_log(quat_multiply(quat_conjugate(s.quaternion), q_true))
    errs = np.concatenate([E[:, :3], dtheta], axis=1)
    C_mc = np.cov(errs.T)
    np.testing.assert_allclose(up.covariance, C_mc, atol=0.05 * np.abs(up.covariance).max())
    np.testing.assert_allclose(up.covariance[3:, 3:], R.T @ s.covariance[3:6, 3:6] @ R, atol=1e-12)


def test_invalid_state_rejected():
    with pytest.raises(ValueError, match="position"):
        QuaternionSpaceState(
            0.0, [np.nan, 0, 0], [0, 0, 0, 1], np.zeros(3), np.zeros(3), np.eye(12)
        )
    with pytest.raises(ValueError, match="symmetric"):
        QuaternionSpaceState(
            0.0, np.zeros(3), [0, 0, 0, 1], np.zeros(3), np.zeros(3), np.triu(np.ones((12, 12)))
        )
    with pytest.raises(ValueError, match="a and alpha"):
        QuaternionSpaceFilter(-1.0, 0.0)


# -- consistency -------------------------------------------------------------------------------


def test_nees_consistent_on_model_motion(rng):
    """Truth driven by white accelerations of the modelled PSDs: mean NEES ~ 12."""
    cams, pts, segs = _scene(rng, n_cams=2)
    a, alpha, dt = 0.05, 0.2, 1.0 / 30.0
    filt = QuaternionSpaceFilter(a, alpha)
    Q = process_noise(dt, a, alpha)
    L = np.linalg.cholesky(Q)
    S0 = np.diag([1e-4] * 3 + [1e-3] * 3 + [1e-2] * 3 + [1e-2] * 3)
    nees = []
    for _ in range(6):
        truth = QuaternionSpaceState(
            0.0, np.zeros(3), quat_exp(rng.normal(0, 0.3, 3)), [0.2, 0.0, 0.1], [0.0, 0.5, 0.2], S0
        )
        state = _boxplus(truth, np.linalg.cholesky(S0) @ rng.standard_normal(12))
        for k in range(36):
            # Exact-in-distribution truth step: constant-velocity motion plus noise drawn from Q.
            nxt, _ = predict_state(truth, dt, 0.0, 0.0)
            truth = _boxplus(nxt, L @ rng.standard_normal(12))
            obs = _observe(cams, pts, segs, truth.position, truth.quaternion, rng, sigma=1.0)
            _, state, _ = filt.step(state, truth.time, obs)
            if k >= 10:
                e = _boxminus(truth, state)
                nees.append(e @ np.linalg.solve(state.covariance, e))
    m = float(np.mean(nees))
    # 156 correlated samples of a chi2(12) variable; a wrong covariance by x2 fails clearly.
    print(f"mean NEES {m:.2f}")
    assert 12 * 0.75 < m < 12 * 1.3, m


# -- the paper's experiment --------------------------------------------------------------------


def test_section5_figures_within_25_percent_or_better():
    ude = _load_experiment()
    summary = ude.run_many(3, ude.Setup(), seed=1999)
    for key, paper in ude.PAPER.items():
        assert summary[key] <= 1.25 * paper, (key, summary[key], paper)
        assert summary[key] > 0.1 * paper, (key, summary[key], paper)
    # Table 1: Gauss-Newton on the manifold; each iteration cuts the gradient norm^2 by > 1e3
    # until round-off.
    g2 = [row[4] for row in summary["gauss_newton"]]
    assert g2[1] < 1e-3 * g2[0] and g2[2] < 1e-3 * g2[1]
    assert summary["mean_gn_iterations"] < 6
