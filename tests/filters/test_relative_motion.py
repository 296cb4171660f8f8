"""Tests of the relative-motion EKF of Dorfmueller-Ulhaas (seed 000, section 3)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import expm

from trackflow import Pose, UncertainPose
from trackflow.filters.relative_motion.ekf import (
    RelativeMotionEKF,
    RelativeMotionState,
    motion_jacobians_omega,
    motion_matrices,
    points_from_poses,
    predict,
    predict_pose,
    process_noise,
    residual,
    transition_matrix,
    update,
)
from trackflow.math import (
    quat_conjugate,
    quat_exp,
    quat_log,
    quat_multiply,
    quat_to_matrix,
    skew,
)

REPO = Path(__file__).resolve().parents[2]
H = 0.02


def _load_experiment():
    path = REPO / "experiments" / "dorfmueller_sim.py"
    spec = importlib.util.spec_from_file_location("dorfmueller_sim", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["dorfmueller_sim"] = mod
    spec.loader.exec_module(mod)
    return mod


def _fd(fun, x, eps):
    x = np.asarray(x, dtype=float)
    cols = []
    for j in range(x.size):
        d = np.zeros_like(x)
        d[j] = eps
        cols.append((fun(x + d) - fun(x - d)) / (2 * eps))
    return np.stack(cols, axis=-1)


def _omega(rng, norm):
    w = rng.normal(size=3)
    return w / np.linalg.norm(w) * norm


# angular speeds: exactly 0, near 0 (series branch), moderate, and large enough (phi = |w| h
# above 0.5) to use the closed forms of the paper
SPEEDS = [0.0, 1e-9, 1e-5, 1e-2, 1.0, 24.0, 30.0, 200.0]


# -- Theorem 1 -----------------------------------------------------------------------------------
@pytest.mark.parametrize("speed", SPEEDS)
def test_motion_matrices_are_exp_and_its_integrals(rng, speed):
    w = _omega(rng, speed)
    W, V, A = motion_matrices(w, H)
    K = skew(w)
    np.testing.assert_allclose(W, expm(K * H), atol=1e-13)
    # V = int_0^h Exp(K s) ds and A = int_0^h (h - s) Exp(K s) ds, by Gauss-Legendre quadrature
    x, wq = np.polynomial.legendre.leggauss(60)
    s = 0.5 * H * (x + 1.0)
    E = np.array([expm(K * si) for si in s])
    V_num = 0.5 * H * np.einsum("k,kij->ij", wq, E)
    A_num = 0.5 * H * np.einsum("k,kij->ij", wq * (H - s), E)
    np.testing.assert_allclose(V, V_num, atol=1e-14 + 1e-11 * H)
    np.testing.assert_allclose(A, A_num, atol=1e-15 + 1e-11 * H**2)


def test_theorem1_is_the_flow_of_a_twist_with_linear_velocity(rng):
    """p(h) = W p0 + V v + A a solves dp/ds = w x p + v + a s (RK4 reference)."""
    w, v, a, p0 = _omega(rng, 3.0), rng.normal(size=3), rng.normal(size=3), rng.normal(size=3)
    h = 0.1
    W, V, A = motion_matrices(w, h)

    def rhs(s, p):
        return np.cross(w, p) + v + a * s

    p, n = p0.copy(), 2000
    ds = h / n
    for i in range(n):
        s = i * ds
        k1 = rhs(s, p)
        k2 = rhs(s + ds / 2, p + ds / 2 * k1)
        k3 = rhs(s + ds / 2, p + ds / 2 * k2)
        k4 = rhs(s + ds, p + ds * k3)
        p = p + ds / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    np.testing.assert_allclose(W @ p0 + V @ v + A @ a, p, atol=1e-12)


def test_coefficients_continuous_across_series_switch():
    # phi = |w| h crosses 0.5 where the series hands over to the closed forms
    for eps in (1e-12, 1e-11):  # omega changes by 2 eps: the matrices by ~2 eps h
        w0 = np.array([0.0, 0.0, 0.5 / H - eps])
        w1 = np.array([0.0, 0.0, 0.5 / H + eps])
        for M0, M1 in zip(motion_matrices(w0, H), motion_matrices(w1, H)):
            np.testing.assert_allclose(M0, M1, rtol=0, atol=1e-12 * np.abs(M0).max())
        p = np.array([0.3, -1.0, 2.0])
        for J0, J1 in zip(
            motion_jacobians_omega(w0, H, p, p, p), motion_jacobians_omega(w1, H, p, p, p)
        ):
            np.testing.assert_allclose(J0, J1, rtol=0, atol=1e-10 * np.abs(J0).max())


# -- eqs. 14-16: derivatives ---------------------------------------------------------------------
@pytest.mark.parametrize("speed", SPEEDS)
def test_omega_derivatives_match_finite_differences(rng, speed):
    w = _omega(rng, speed)
    p, v, a = rng.normal(size=(3, 3))
    J = motion_jacobians_omega(w, H, p, v, a)
    eps = 1e-4 * max(1.0, speed)
    for m, x in enumerate((p, v, a)):
        num = _fd(lambda ww, m=m, x=x: motion_matrices(ww, H)[m] @ x, w, eps)
        scale = np.abs(num).max()
        np.testing.assert_allclose(J[m], num, rtol=0, atol=1e-7 * scale)


def test_omega_derivative_limits_at_zero(rng):
    """The paper's limits: -h [P]x, -h^2/2 [v]x, -h^3/6 [a]x (they are right)."""
    p, v, a = rng.normal(size=(3, 3))
    for w in (np.zeros(3), _omega(rng, 1e-10)):
        J_Wp, J_Vv, J_Aa = motion_jacobians_omega(w, H, p, v, a)
        np.testing.assert_allclose(J_Wp, -H * skew(p), atol=1e-14)
        np.testing.assert_allclose(J_Vv, -(H**2) / 2 * skew(v), atol=1e-15)
        np.testing.assert_allclose(J_Aa, -(H**3) / 6 * skew(a), atol=1e-16)


def _paper_dWp(w, h, p, bracket):
    """d(W P)/d omega as printed in eq. 16, with the bracket supplied."""
    th = np.linalg.norm(w)
    ph = th * h
    K = skew(w)
    return (
        -np.sin(ph) / th * skew(p)
        + (ph * np.cos(ph) - np.sin(ph)) / th**3 * np.outer(K @ p, w)
        + (ph * np.sin(ph) - 2 * (1 - np.cos(ph))) / th**4 * np.outer(K @ (K @ p), w)
        + (1 - np.cos(ph)) / th**2 * bracket
    )


def test_printed_bracket_is_wrong_as_a_matrix_product(rng):
    """Eq. 16 prints the last term as (1 - cos)/th^2 [-w~ P~ + (w^T P) I - P w^T].

    Read as the matrix product w~ P~ this disagrees with finite differences (by
    (1 - cos)/th^2 ((w^T P) I - w P^T)); read as the skew matrix of the vector w~ P, i.e.
    -[w x P]x + (w^T P) I - P w^T = (w^T P) I + w P^T - 2 P w^T, it is right. The same holds
    for the V and A terms, where "-w~ v" only makes sense as the matrix [w x v]x. The module
    implements the second reading (and uses series near theta = 0).
    """
    w = _omega(rng, 2.0)
    h = 0.2
    p = rng.normal(size=3)
    num = _fd(lambda ww: motion_matrices(ww, h)[0] @ p, w, 1e-6)
    K = skew(w)
    as_product = -K @ skew(p) + np.dot(w, p) * np.eye(3) - np.outer(p, w)
    as_skew_of_vector = -skew(K @ p) + np.dot(w, p) * np.eye(3) - np.outer(p, w)
    err_product = np.abs(_paper_dWp(w, h, p, as_product) - num).max()
    err_vector = np.abs(_paper_dWp(w, h, p, as_skew_of_vector) - num).max()
    assert err_vector < 1e-8 * np.abs(num).max()
    assert err_product > 1e-3 * np.abs(num).max()


@pytest.mark.parametrize("speed", [0.0, 1e-7, 0.5, 40.0])
def test_residual_jacobians_match_finite_differences(rng, speed):
    s = np.concatenate([_omega(rng, speed), rng.normal(size=6)])
    prev, curr = rng.normal(size=(2, 3, 3))
    f, J_f_s, J_f_x = residual(s, prev, curr, H, jacobians=True)
    num_s = _fd(lambda ss: residual(ss, prev, curr, H), s, 1e-5 * max(1.0, speed))
    x = np.concatenate([prev.ravel(), curr.ravel()])
    num_x = _fd(lambda xx: residual(s, xx[:9].reshape(3, 3), xx[9:].reshape(3, 3), H), x, 1e-6)
    np.testing.assert_allclose(J_f_s, num_s, rtol=0, atol=1e-7 * np.abs(num_s).max())
    np.testing.assert_allclose(J_f_x, num_x, rtol=0, atol=1e-9)


def test_residual_zero_for_exact_motion(rng):
    s = np.concatenate([_omega(rng, 0.7), rng.normal(size=6)])
    W, V, A = motion_matrices(s[:3], H)
    prev = rng.normal(size=(3, 3))
    curr = prev @ W.T + V @ s[3:6] + A @ s[6:9]
    np.testing.assert_allclose(residual(s, prev, curr, H), 0.0, atol=1e-15)


def test_transition_shift_matches_world_and_body_origins(rng):
    """Moving the origin by dc adds w x dc to v: both origins then predict the same points."""
    s = np.concatenate([_omega(rng, 0.8), rng.normal(size=6)])
    R0 = expm(skew(rng.normal(size=3)))
    t0 = rng.normal(size=3) * 2.0
    # exact motion about the world origin over two intervals
    W, V, A = motion_matrices(s[:3], H)
    R1, t1 = W @ R0, W @ t0 + V @ s[3:6] + A @ s[6:9]
    s_world = transition_matrix(H) @ s
    R2, t2 = W @ R1, W @ t1 + V @ s_world[3:6] + A @ s_world[6:9]
    # the same state about c = t0 (the body origin at frame 0), then shifted to c = t1
    s_body = s.copy()
    s_body[3:6] = s[3:6] + np.cross(s[:3], t0)
    np.testing.assert_allclose(
        residual(s_body, R0.T - 0 * t0, R1.T + t1 - t0, H), 0.0, atol=1e-14
    )  # rows R e_i = columns of R
    s_body_next = transition_matrix(H, t1 - t0) @ s_body
    np.testing.assert_allclose(residual(s_body_next, R1.T, R2.T + t2 - t1, H), 0.0, atol=1e-14)


# -- eq. 11 and the pose interface ---------------------------------------------------------------
def _random_uncertain_pose(rng, sigma_t=1e-3, sigma_r=1e-2):
    L = rng.normal(size=(6, 6)) * np.repeat([sigma_t, sigma_r], 3)[:, None] * 0.5
    C = L @ L.T + np.diag(np.repeat([sigma_t, sigma_r], 3) ** 2)
    return UncertainPose(Pose(rng.normal(size=3), quat_exp(rng.normal(size=3))), C)


def _perturb(pose, rng, n):
    e = rng.multivariate_normal(np.zeros(6), pose.covariance, size=n)
    return pose.position + e[:, :3], quat_multiply(pose.quaternion, quat_exp(e[:, 3:]))


@pytest.mark.parametrize("origin", ["world", "body"])
def test_points_from_poses_covariance_monte_carlo(rng, origin):
    a, b = _random_uncertain_pose(rng), _random_uncertain_pose(rng)
    prev, curr, Cx, _ = points_from_poses(a, b, origin)
    n = 20000
    pa, qa = _perturb(a, rng, n)
    pb, qb = _perturb(b, rng, n)
    c = pa if origin == "body" else 0.0
    # rows of R^T are the rotated unit axes R e_i
    xs_prev = np.swapaxes(quat_to_matrix(qa), -1, -2) + (pa - c)[:, None, :]
    xs_curr = np.swapaxes(quat_to_matrix(qb), -1, -2) + (pb - c)[:, None, :]
    xs = np.concatenate([xs_prev.reshape(n, 9), xs_curr.reshape(n, 9)], axis=1)
    C_mc = np.cov(xs.T)
    # first order vs Monte Carlo: 1e-2 rad rotation noise keeps linearisation error ~1e-4
    assert np.linalg.norm(C_mc - Cx) / np.linalg.norm(Cx) < 0.05
    np.testing.assert_allclose(
        prev[0], a.pose.rotation_matrix[:, 0] + a.position * (origin == "world")
    )
    np.testing.assert_allclose(
        curr[2], b.pose.rotation_matrix[:, 2] + b.position - a.position * (origin == "body")
    )


def test_predict_pose_exact_motion_and_horizon_zero(rng):
    s = np.concatenate([_omega(rng, 1.5), rng.normal(size=6)])
    pose = _random_uncertain_pose(rng)
    state = RelativeMotionState(s, np.zeros((9, 9)))
    h = 0.05
    W, V, A = motion_matrices(s[:3], h)
    for origin in ("world", "body"):
        out = predict_pose(state, pose, h, origin)
        c = pose.position if origin == "body" else np.zeros(3)
        np.testing.assert_allclose(
            out.pose.rotation_matrix, W @ pose.pose.rotation_matrix, atol=1e-12
        )
        np.testing.assert_allclose(
            out.position, c + W @ (pose.position - c) + V @ s[3:6] + A @ s[6:9], atol=1e-12
        )
    same = predict_pose(state, pose, 0.0)
    assert same.pose.allclose(pose.pose, atol=1e-12)
    np.testing.assert_allclose(same.covariance, pose.covariance, atol=1e-15)


@pytest.mark.parametrize("origin", ["world", "body"])
def test_predict_pose_covariance_monte_carlo(rng, origin):
    """Propagated covariance (trackflow convention) vs seeded Monte Carlo of state and pose."""
    s = np.concatenate([_omega(rng, 2.0), rng.normal(size=3), rng.normal(size=3)])
    L = rng.normal(size=(9, 9)) * 0.02
    P = L @ L.T + np.diag(np.repeat([0.05, 0.02, 0.2], 3) ** 2)
    pose = _random_uncertain_pose(rng)
    h = 0.1
    out = predict_pose(RelativeMotionState(s, P), pose, h, origin)
    n = 20000
    ss = rng.multivariate_normal(s, P, size=n)
    pp, qq = _perturb(pose, rng, n)
    # the same formulas, batched over the samples (motion_matrices broadcasts)
    W, V, A = motion_matrices(ss[:, :3], h)
    c = pp if origin == "body" else np.zeros((n, 3))
    pos = (
        c
        + np.einsum("nij,nj->ni", W, pp - c)
        + np.einsum("nij,nj->ni", V, ss[:, 3:6])
        + np.einsum("nij,nj->ni", A, ss[:, 6:9])
    )
    quat = quat_multiply(quat_exp(h * ss[:, :3]), qq)
    errs = np.concatenate(
        [pos - out.position, quat_log(quat_multiply(quat_conjugate(out.quaternion), quat))], axis=1
    )
    C_mc = np.cov(errs.T)
    assert np.linalg.norm(C_mc - out.covariance) / np.linalg.norm(out.covariance) < 0.05


# -- the filter ----------------------------------------------------------------------------------
def test_state_nees_consistent_with_gaussian_point_noise(rng):
    """Exact constant motion, independent Gaussian noise on every point pair: NEES ~ chi2(9)."""
    s_true = np.array([0.3, -0.2, 0.5, 0.4, 0.1, -0.3, 0.0, 0.0, 0.0])
    sigma = 1e-4
    W, V, A = motion_matrices(s_true[:3], H)
    Q = 1e-14 * np.eye(9)  # constant motion: an almost-zero random walk keeps P well defined
    nees = []
    P0 = np.diag(np.repeat([0.1, 0.1, 0.1], 3) ** 2)
    for _run in range(40):
        # initial estimate drawn from its own prior, as NEES requires
        state = RelativeMotionState(rng.multivariate_normal(s_true, P0), P0)
        truth = s_true.copy()
        R0 = expm(skew(rng.normal(size=3)))
        for _ in range(30):
            W, V, A = motion_matrices(truth[:3], H)
            prev = R0.T + rng.normal(size=3)
            curr = prev @ W.T + V @ truth[3:6] + A @ truth[6:9]
            noisy_prev = prev + rng.normal(scale=sigma, size=(3, 3))
            noisy_curr = curr + rng.normal(scale=sigma, size=(3, 3))
            post, info = update(state, noisy_prev, noisy_curr, sigma**2 * np.eye(18), H)
            assert info.dof == 9
            state = predict(post, H, Q)
            truth = transition_matrix(H) @ truth
        e = post.mean - transition_matrix(-H) @ truth  # posterior describes the last interval
        nees.append(e @ np.linalg.solve(post.covariance, e))
    mean = float(np.mean(nees))
    # 40 runs of chi2(9): mean 9, std of the mean sqrt(18/40) ~ 0.67; allow ~3 sigma
    assert 7.0 < mean < 11.0, mean


def test_filter_rejects_bad_input():
    state = RelativeMotionState(np.zeros(9), np.eye(9))
    with pytest.raises(ValueError):
        residual(np.zeros(8), np.eye(3), np.eye(3), H)
    with pytest.raises(ValueError):
        update(state, np.eye(3), np.eye(3), np.eye(9), H)
    with pytest.raises(ValueError):
        RelativeMotionState(np.full(9, np.nan), np.eye(9))
    with pytest.raises(ValueError):
        predict_pose(state, UncertainPose.exact(Pose.identity()), 0.1, origin="camera")
    with pytest.raises(ValueError):
        process_noise(0.01, -1.0, 1.0, 1.0)
    ekf = RelativeMotionEKF(state, process_noise(0.01, 1.0, 1.0, 1.0))
    p = UncertainPose(Pose.identity(), 1e-6 * np.eye(6))
    ekf.step(1.0, p)
    with pytest.raises(ValueError, match="increase"):
        ekf.step(1.0, p)


# -- section 3.3 ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def experiment():
    return _load_experiment()


def test_paper_convergence_within_three_iterations(experiment):
    """Paper (fig. 9): omega converges to (0, 0, 0.02) after three iterations, ideal and noisy.

    Ours: one iteration on ideal data (exact points determine omega in one update) and on the
    perturbed data (to within 10% of |omega|), for every seed tried.
    """
    for seed in range(5):
        sim = experiment.sim_experiments(seed)
        assert 1 <= sim["ideal"]["converge_omega"] <= 3
        assert sim["noisy"]["converge_omega"] is not None
        assert sim["noisy"]["converge_omega"] <= 3
        w_final = sim["ideal"]["pred"][experiment.CHANGE_FRAME - 1, :3]
        np.testing.assert_allclose(w_final, [0.0, 0.0, 0.02], atol=1e-6)
    # a also converges on ideal data within three iterations (fig. 11 (a))
    assert sim["ideal"]["converge_a"] <= 3


def test_paper_realignment_after_abrupt_change(experiment):
    """Paper (fig. 13-14): realigns three to four iterations after the change at frame 10.

    Ours (10% tolerance, 5 seeds): omega and v realign within 2-3 updates on perturbed data; a
    does not converge at all under the paper's v perturbations (not observable, see the doc),
    but on ideal data it realigns within five, as the paper reports for a.
    """
    for seed in range(5):
        sim = experiment.sim_experiments(seed)
        ch = sim["change_noisy"]
        assert ch["realign_omega"] is not None and 1 <= ch["realign_omega"] <= 5
        assert ch["realign_v"] is not None and 1 <= ch["realign_v"] <= 5
        assert sim["change_ideal"]["realign_a"] is not None
        assert sim["change_ideal"]["realign_a"] <= 5
        # the prediction overshoots right after the change (fig. 15) and settles again
        err = ch["pred_pos_err"]  # index i: frame i + 2
        c = experiment.CHANGE_FRAME
        assert err[c - 2 : c + 1].max() > 5 * err[: c - 3].max()
        assert err[-3:].max() < 0.2 * err[c - 2 : c + 1].max()


def test_json_interface(experiment, capsys):
    assert experiment.main(["--json", "--no-real"]) == 0
    import json

    out = json.loads(capsys.readouterr().out)
    assert {"iterations_to_converge", "iterations_to_realign", "w_final"} <= set(out)
    assert len(out["w_final"]) == 3


def test_real_recording_prediction_beats_holding_the_pose(shared_data, experiment):
    res = experiment.real_experiment(
        shared_data / "ar_table" / "table_01.txt",
        0,
        400,
        0.05,
        2.5e-4,
        np.radians(0.05),
        start=3000,  # the first frames are nearly still
    )
    for r in res.values():
        assert r["pred_pos_mm"] < 0.7 * r["hold_pos_mm"]
        assert r["filt_pos_mm"] < 1.2 * r["meas_pos_mm"]
