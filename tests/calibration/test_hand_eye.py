"""Hand-eye / robot-world-hand-eye: Jacobians, consistency on synthetic truth, degenerate input,
the world-independent motion-pair residual."""

from __future__ import annotations

import numpy as np
import pytest
from _synth import X_TRUE, Z_TRUE, two_trackers
from scipy import stats

from trackflow.calibration import (
    estimate_clock_offset,
    evaluate_hand_eye,
    hand_eye_residuals,
    solve_hand_eye,
)
from trackflow.calibration.hand_eye import _relative, pair_residuals, pair_station_jacobians
from trackflow.math import Pose, quat_conjugate, quat_exp, quat_log, quat_multiply, quat_rotate


def _err(est, true):
    """Error of an estimate in the conventions: t_true = t + dt, R_true = R Exp(dtheta)."""
    dt = true[0] - est.position
    dth = quat_log(quat_multiply(quat_conjugate(est.quaternion), true[1]))
    return np.concatenate([dt, dth])


def _perturb(pose, d):
    return pose[0] + d[:3], quat_multiply(pose[1], quat_exp(d[3:]))


def _random_poses(rng, n):
    return rng.normal(0, 0.5, (n, 3)), quat_exp(rng.normal(0, 1.0, (n, 3)))


def test_robot_world_jacobians_match_finite_differences():
    rng = np.random.default_rng(3)
    Ap, Aq = _random_poses(rng, 5)
    Bp, Bq = _random_poses(rng, 5)
    X = (rng.normal(size=3), quat_exp(rng.normal(size=3)))
    Z = (rng.normal(size=3), quat_exp(rng.normal(size=3)))
    v, w = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    r0, J_X, J_Z, J_off = hand_eye_residuals(Ap, Aq, Bp, Bq, X, Z, v, w, jacobians=True)
    h = 1e-6
    for k in range(6):
        d = np.zeros(6)
        d[k] = h
        fx = (
            hand_eye_residuals(Ap, Aq, Bp, Bq, _perturb(X, d), Z)
            - hand_eye_residuals(Ap, Aq, Bp, Bq, _perturb(X, -d), Z)
        ) / (2 * h)
        fz = (
            hand_eye_residuals(Ap, Aq, Bp, Bq, X, _perturb(Z, d))
            - hand_eye_residuals(Ap, Aq, Bp, Bq, X, _perturb(Z, -d))
        ) / (2 * h)
        np.testing.assert_allclose(J_X[:, :, k], fx, atol=1e-6)
        np.testing.assert_allclose(J_Z[:, :, k], fz, atol=1e-6)

    # a later offset samples B earlier: B(off + h) = (p - h v, q Exp(-h w))
    def shifted(s):
        return hand_eye_residuals(Ap, Aq, Bp - s * v, quat_multiply(Bq, quat_exp(-s * w)), X, Z)

    np.testing.assert_allclose(J_off, (shifted(h) - shifted(-h)) / (2 * h), atol=1e-6)


def test_hand_eye_pair_jacobian_matches_finite_differences():
    rng = np.random.default_rng(4)
    Ap, Aq = _random_poses(rng, 6)
    Bp, Bq = _random_poses(rng, 6)
    X = (rng.normal(size=3), quat_exp(rng.normal(size=3)))
    _, J = pair_residuals(Ap, Aq, Bp, Bq, X, jacobians=True)
    h = 1e-6
    for k in range(6):
        d = np.zeros(6)
        d[k] = h
        f = (
            pair_residuals(Ap, Aq, Bp, Bq, _perturb(X, d))
            - pair_residuals(Ap, Aq, Bp, Bq, _perturb(X, -d))
        ) / (2 * h)
        np.testing.assert_allclose(J[:, :, k], f, atol=1e-6)


def test_pair_station_jacobians_match_finite_differences():
    rng = np.random.default_rng(5)
    n = 6
    Ap, Aq = _random_poses(rng, n)
    Bp, Bq = _random_poses(rng, n)
    X = (rng.normal(size=3), quat_exp(rng.normal(size=3)))
    i, j = np.array([0, 0, 1, 2, 3]), np.array([1, 3, 4, 5, 5])
    G_i, G_j = pair_station_jacobians(Ap, Aq, Bp, Bq, i, j, X)

    def res(Ap, Aq, Bp, Bq):
        return pair_residuals(*_relative(Ap, Aq, i, j), *_relative(Bp, Bq, i, j), X)

    h = 1e-6
    for stream, (p, q) in enumerate(((Ap, Aq), (Bp, Bq))):
        for k in range(6):
            for which, G in ((i, G_i[stream]), (j, G_j[stream])):
                fd = np.zeros((len(i), 6))
                for m, st in enumerate(which):
                    out = []
                    for sgn in (1, -1):
                        d = np.zeros(6)
                        d[k] = sgn * h
                        pp, qq = p.copy(), q.copy()
                        pp[st], qq[st] = _perturb((p[st], q[st]), d)
                        args = (pp, qq, Bp, Bq) if stream == 0 else (Ap, Aq, pp, qq)
                        out.append(res(*args)[m])
                    fd[m] = (out[0] - out[1]) / (2 * h)
                np.testing.assert_allclose(G[:, :, k], fd, atol=1e-6)


RUNS = 10


@pytest.fixture(scope="module", params=["robot-world", "robot-world-joint"])
def robot_world_runs(request):
    out = []
    for seed in range(RUNS):
        a, b = two_trackers(seed, duration=20.0)
        out.append(solve_hand_eye(a, b, form=request.param))
        assert out[-1].form == request.param
    return out


def _band(dof_per_run, n):
    lo, hi = stats.chi2.ppf([0.025, 0.975], dof_per_run * n)
    return lo / n, hi / n


@pytest.mark.slow
def test_robot_world_is_consistent_and_unbiased(robot_world_runs):
    eX = np.array([_err(r.X, X_TRUE) for r in robot_world_runs])
    eZ = np.array([_err(r.Z, Z_TRUE) for r in robot_world_runs])
    neesX = [e @ np.linalg.solve(r.X.covariance, e) for e, r in zip(eX, robot_world_runs)]
    neesZ = [e @ np.linalg.solve(r.Z.covariance, e) for e, r in zip(eZ, robot_world_runs)]
    lo, hi = _band(6, RUNS)
    assert lo <= np.mean(neesX) <= hi, (np.mean(neesX), lo, hi)
    assert lo <= np.mean(neesZ) <= hi, (np.mean(neesZ), lo, hi)
    # unbiased: the mean error of each component within 4 standard errors of zero
    for e in (eX, eZ):
        se = e.std(axis=0, ddof=1) / np.sqrt(RUNS)
        assert np.all(np.abs(e.mean(axis=0)) <= 4 * se), (e.mean(axis=0), se)


@pytest.mark.slow
def test_offset_within_a_tenth_of_the_slower_period(robot_world_runs):
    err = np.array([r.offset_s - 0.25 for r in robot_world_runs])
    sig = np.array([r.offset_sigma_s for r in robot_world_runs])
    assert np.all(np.abs(err) < 0.1 / 30.0)
    lo, hi = _band(1, RUNS)
    assert lo <= np.mean((err / sig) ** 2) <= hi


HE_RUNS = 20


@pytest.mark.slow
def test_hand_eye_form_is_consistent_and_unbiased():
    """Motion pairs share stations: the covariance must account for it, neither treating the
    pairs as independent (overconfident) nor inflating by a bound (conservative)."""
    e, nees, z = [], [], []
    for seed in range(HE_RUNS):
        a, b = two_trackers(seed, duration=20.0)
        r = solve_hand_eye(a, b, form="hand-eye")
        e.append(_err(r.X, X_TRUE))
        nees.append(e[-1] @ np.linalg.solve(r.X.covariance, e[-1]))
        z.append((r.offset_s - 0.25) / r.offset_sigma_s)
    lo, hi = _band(6, HE_RUNS)
    assert lo <= np.mean(nees) <= hi, (np.mean(nees), lo, hi)
    lo, hi = _band(1, HE_RUNS)
    assert lo <= np.mean(np.square(z)) <= hi, (np.mean(np.square(z)), lo, hi)
    e = np.array(e)
    se = e.std(axis=0, ddof=1) / np.sqrt(HE_RUNS)
    assert np.all(np.abs(e.mean(axis=0)) <= 4 * se), (e.mean(axis=0), se)


def test_hand_eye_form_recovers_X():
    a, b = two_trackers(11, duration=30.0)
    r = solve_hand_eye(a, b, form="hand-eye")
    assert r.Z is None and r.form == "hand-eye"
    e = _err(r.X, X_TRUE)
    assert e @ np.linalg.solve(r.X.covariance, e) < stats.chi2.ppf(0.999, 6)
    assert abs(r.offset_s - 0.25) < 0.1 / 30.0


def test_gaps_and_outliers_are_handled():
    a, b = two_trackers(12, duration=25.0, gap=(8.0, 9.5))
    r = solve_hand_eye(a, b)
    e = _err(r.X, X_TRUE)
    assert e @ np.linalg.solve(r.X.covariance, e) < stats.chi2.ppf(0.999, 6)
    # corrupt 2 % of the sensor samples by 5 cm jumps: rejected, estimate still consistent
    rng = np.random.default_rng(0)
    p = np.array(b.position)
    bad = rng.choice(len(p), len(p) // 50, replace=False)
    p[bad] += rng.normal(0, 0.05, (len(bad), 3))
    r2 = solve_hand_eye(a, b.with_(position=p))
    e2 = _err(r2.X, X_TRUE)
    assert r2.n_outliers >= len(bad) // 3
    assert e2 @ np.linalg.solve(r2.X.covariance, e2) < stats.chi2.ppf(0.999, 6)


def test_single_axis_rotation_is_a_clear_error():
    a, b = two_trackers(5, duration=20.0, axes=(0, 0, 1))
    with pytest.raises(ValueError, match="single axis"):
        solve_hand_eye(a, b, offset_s=0.25)


def test_too_little_rotation_is_a_clear_error():
    a, b = two_trackers(5, duration=20.0, rot_amp=0.02)
    with pytest.raises(ValueError, match="rotation"):
        solve_hand_eye(a, b, offset_s=0.25, estimate_offset=False)


def test_no_motion_is_a_clear_error_for_the_offset():
    a, b = two_trackers(5, duration=20.0, rot_amp=0.0)
    still = a.with_(position=np.broadcast_to(a.position[0], a.position.shape).copy())
    with pytest.raises(ValueError, match="no motion"):
        estimate_clock_offset(still, b.with_(position=np.zeros(b.position.shape)))


def test_no_overlap_is_a_clear_error():
    a, b = two_trackers(5, duration=10.0)
    later = b.with_(t_ns=b.t_ns + 10**12)
    with pytest.raises(ValueError, match="overlap"):
        solve_hand_eye(a, later)


@pytest.mark.parametrize("form", ["robot-world", "robot-world-joint", "hand-eye"])
def test_clock_drift_is_estimated_jointly(form):
    a, b = two_trackers(2, duration=40.0, offset=0.2)
    t = b.t_ns.astype(np.int64)
    mid = t[len(t) // 2]
    # b's clock runs 200 ppm fast: t_a = t_b + offset + drift (t_a - ref) with drift = -2e-4
    fast = b.with_(t_ns=mid + np.round((t - mid) * (1 + 2e-4)).astype(np.int64))
    r = solve_hand_eye(a, fast, form=form, estimate_drift=True)
    assert abs(r.drift + 2e-4) < 4 * r.drift_sigma
    assert abs(r.offset_s - 0.2) < 0.1 / 30.0


@pytest.mark.slow
def test_a_drifting_sensor_world_does_not_bias_the_default_robot_world_form():
    """Inside-out trackers' world frames drift within a run: X from motion pairs stays
    consistent, the joint absolute-pose fit takes up the drift."""
    from trackflow.math import quat_rotate

    err = {"robot-world": [], "robot-world-joint": []}
    for seed in range(4):
        a, b = two_trackers(seed, duration=20.0)
        t = (b.t_ns - b.t_ns[0]) * 1e-9
        s = np.sin(2 * np.pi * t / 40.0)[:, None]
        # T_world'_world(t): a few millimetres and tenths of a degree over the run
        qW = quat_exp(s * np.radians([0.2, 0.1, -0.15]))
        drifting = b.with_(
            position=s * np.array([0.004, -0.003, 0.002]) + quat_rotate(qW, b.position),
            quaternion=quat_multiply(qW, b.quaternion),
        )
        for form in err:
            r = solve_hand_eye(a, drifting, form=form)
            e = _err(r.X, X_TRUE)
            err[form].append(np.linalg.norm(e[:3]))
            if form == "robot-world":
                assert e @ np.linalg.solve(r.X.covariance, e) < stats.chi2.ppf(0.999, 6)
    assert np.mean(err["robot-world"]) < 0.5 * np.mean(err["robot-world-joint"]), err


def test_pair_residual_does_not_depend_on_either_world():
    a, b = two_trackers(4, duration=20.0)
    r = solve_hand_eye(a, b, form="hand-eye")
    # on the hand-eye form's own pairs, the pair residual is the form's residual
    assert r.pair_residual_pos_mm == pytest.approx(r.residual_pos_mm, rel=0.05)
    assert r.pair_residual_ori_deg == pytest.approx(r.residual_ori_deg, rel=0.05)
    # moving the sensor's world (a new session) changes nothing in it, unlike A X = Z B
    W = (np.array([0.4, -1.0, 0.3]), quat_exp(np.array([0.3, -1.1, 2.0])))
    moved = b.with_(position=W[0] + quat_rotate(W[1], b.position),
                    quaternion=quat_multiply(W[1], b.quaternion))  # fmt: skip
    same = evaluate_hand_eye(a, b, r.X.pose, Pose(*Z_TRUE), r.offset_s)
    other = evaluate_hand_eye(a, moved, r.X.pose, Pose(*Z_TRUE), r.offset_s)
    assert other["residual_pos_mm"] > 100 * same["residual_pos_mm"]
    assert other["pair_residual_pos_mm"] == pytest.approx(same["pair_residual_pos_mm"], rel=1e-9)
    assert other["pair_residual_ori_deg"] == pytest.approx(same["pair_residual_ori_deg"], rel=1e-9)
    # a wrong X shows in it: 5 mm off along x
    off = Pose(r.X.position + np.array([0.005, 0.0, 0.0]), r.X.quaternion)
    worse = evaluate_hand_eye(a, b, off, None, r.offset_s)
    assert worse["pair_residual_pos_mm"] > 2 * same["pair_residual_pos_mm"]


def test_pair_residual_leaves_out_a_pose_jump():
    a, b = two_trackers(5, duration=20.0)
    r = solve_hand_eye(a, b, form="hand-eye")
    p = np.array(b.position)
    p[len(p) // 2 : len(p) // 2 + 3] += 0.03  # a 3 cm jump of the sensor for 3 samples
    jumped = evaluate_hand_eye(a, b.with_(position=p), r.X.pose, None, r.offset_s)
    clean = evaluate_hand_eye(a, b, r.X.pose, None, r.offset_s)
    assert jumped["residual_pos_mm"] > 1.5 * clean["residual_pos_mm"]  # plain RMS: every pair
    assert jumped["pair_residual_pos_mm"] == pytest.approx(clean["pair_residual_pos_mm"], rel=0.1)
