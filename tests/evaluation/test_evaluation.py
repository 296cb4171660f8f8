"""Prediction-error evaluation: baselines, targets, the Kalman predictor and tuning."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.evaluation import (
    KalmanPredictor,
    Trajectory,
    evaluate_predictors,
    evaluate_recording,
    interpolate_poses,
    predict_kalman,
    predict_linear,
    scored_mask,
    tune_model,
)
from trackflow.filters import MotionModel
from trackflow.math import quat_angle, quat_exp, quat_multiply


def _smooth(n=1200, rate=120.0):
    t = np.arange(n) / rate
    p = np.stack([0.3 * np.sin(1.3 * t), 0.2 * np.cos(0.9 * t), 0.05 * t], axis=1)
    w = np.stack([np.sin(0.7 * t), 0.5 * np.cos(1.1 * t), 0.3 + 0 * t], axis=1)
    q = np.zeros((n, 4))
    q[0] = [0, 0, 0, 1]
    for k in range(1, n):
        q[k] = quat_multiply(q[k - 1], quat_exp(w[k - 1] / rate))
    return t, p, q


def _noisy(rng, n=1200, sp=5e-4, so=2e-3):
    t, p, q = _smooth(n)
    zp = p + rng.normal(0, sp, p.shape)
    zq = quat_multiply(q, quat_exp(rng.normal(0, so, (len(t), 3))))
    return t, p, q, zp, zq


def test_linear_extrapolation_is_exact_for_constant_velocity():
    t = np.arange(50) * 0.01
    p = np.outer(t, [1.0, -2.0, 0.5])
    q = quat_exp(np.outer(t, [0.0, 0.0, 2.0]))
    lp, lq = predict_linear(t, p, q, 0.1)
    tp, tq = p[1:] + np.array([1.0, -2.0, 0.5]) * 0.1, quat_exp(np.outer(t[1:] + 0.1, [0, 0, 2.0]))
    assert np.allclose(lp[1:], tp, atol=1e-12)
    assert np.allclose(quat_angle(lq[1:], tq), 0, atol=1e-9)


def test_scored_mask_skips_windows_across_gaps():
    t = np.r_[np.arange(10) * 0.01, 1.0 + np.arange(10) * 0.01]
    m = scored_mask(t, 0.02, 0.03)
    # windows [t[k-1], t[k] + 0.02] that touch the 0.09 -> 1.0 gap are not scored
    assert not m[0] and m[1] and not m[8] and not m[9] and not m[10] and m[11]
    assert not m[-1] and not m[-2]  # target beyond the end


def test_interpolation_handles_sign_flips():
    t, p, q = _smooth(50)
    flipped = q.copy()
    flipped[1::2] *= -1
    _, a = interpolate_poses(t, p, q, t[:-1] + 0.004)
    _, b = interpolate_poses(t, p, flipped, t[:-1] + 0.004)
    assert np.allclose(quat_angle(a, b), 0, atol=1e-9)


def test_kalman_beats_linear_on_noisy_smooth_motion(rng):
    t, p, q, zp, zq = _noisy(rng)
    model = MotionModel(2, 2, noise=(0, 0, 3.0, 0, 0, 3.0))
    kp, kq, _ = predict_kalman(
        Trajectory.check(t, zp, zq), KalmanPredictor(model, 5e-4, 2e-3), (0.05,)
    )
    lp, lq = predict_linear(t, zp, zq, 0.05)
    k = np.arange(200, len(t) - 6)
    e_k = np.linalg.norm(kp[0][k] - p[k + 6], axis=1)
    e_l = np.linalg.norm(lp[k] - p[k + 6], axis=1)
    assert np.sqrt(np.mean(e_k**2)) < 0.3 * np.sqrt(np.mean(e_l**2))
    o_k = quat_angle(kq[0][k], q[k + 6])
    o_l = quat_angle(lq[k], q[k + 6])
    assert np.sqrt(np.mean(o_k**2)) < 0.3 * np.sqrt(np.mean(o_l**2))


def test_parts_are_the_full_filter_without_a_gate(rng):
    # block-diagonal noise: position and orientation parts of the error-state filter decouple
    t, _, _, zp, zq = _noisy(rng, 600)
    full = KalmanPredictor(MotionModel(2, 2, noise=(1e-4, 0, 3.0, 1e-4, 0, 3.0)), 5e-4, 2e-3, None)
    fp, fq, _ = predict_kalman(Trajectory.check(t, zp, zq), full, (0.05, 0.1))
    pp, _, _ = predict_kalman(Trajectory.check(t, zp, zq), full.part("position"), (0.05, 0.1))
    _, pq, _ = predict_kalman(Trajectory.check(t, zp, zq), full.part("orientation"), (0.05, 0.1))
    assert np.allclose(fp, pp, rtol=0, atol=1e-12)
    assert quat_angle(fq, pq).max() < 1e-10


def test_gate_rejects_a_single_spike():
    t, p, q = _smooth(600)
    spiky = p.copy()
    spiky[300] += 0.05
    model = MotionModel(2, 1, noise=(0, 0, 3.0, 0, 3.0))
    gated = KalmanPredictor(model, 1e-4, 1e-3, gate_probability=0.999)
    kp, _, n_gated = predict_kalman(Trajectory.check(t, spiky, q), gated, (0.0,))
    lp, _, _ = predict_kalman(
        Trajectory.check(t, spiky, q), KalmanPredictor(model, 1e-4, 1e-3, None), (0.0,)
    )
    assert n_gated >= 1
    err = lambda x: np.abs(x[0][300:330] - p[300:330]).max()  # noqa: E731
    assert err(kp) < 0.2 * err(lp)


def test_tuning_improves_on_a_bad_start_and_reports_counts(rng):
    t, _, _, zp, zq = _noisy(rng, 900, 3e-4, 1e-3)
    bad = KalmanPredictor(MotionModel(2, 1, noise=(0, 0, 1e4, 0, 1e4)), 3e-4, 1e-3, None)
    res = tune_model(
        Trajectory.check(t, zp, zq), start=bad, pos_derivatives=(1, 2), max_evaluations=25
    )
    before = evaluate_predictors(Trajectory.check(t, zp, zq), bad, (0.05,))
    after = evaluate_predictors(Trajectory.check(t, zp, zq), res.predictor, (0.05,))
    assert after.stats["kalman"][50].pos_rms_mm < before.stats["kalman"][50].pos_rms_mm
    assert after.stats["kalman"][50].ori_rms_deg < before.stats["kalman"][50].ori_rms_deg
    assert res.cost_position < 1.0 and res.n_evaluations > 10
    assert set(res.candidates["position"]) == {"1", "2"}


def test_evaluate_recording_scores_only_the_second_part(rng):
    t, _, q, zp, _ = _noisy(rng, 1200, 3e-4)
    rep = evaluate_recording(Trajectory.check(t, zp, q), horizons=(0.02, 0.1), tune_fraction=0.5)
    d = rep.as_dict()
    assert d["scored_from_s"] == pytest.approx(t[-1] / 2)
    n = d["predictors"]["none"]["100"]["n"]
    assert 0 < n < 600
    assert set(d["predictors"]) == {"kalman", "linear", "none"}
    assert {"n_dp", "n_do", "noise", "pos_sigma"} <= set(d["motion_model"])


def test_bad_input_is_a_value_error():
    t, p, q = _smooth(20)
    pred = KalmanPredictor(MotionModel(), 1e-3, 1e-3)
    with pytest.raises(ValueError, match="increase"):
        evaluate_predictors(Trajectory.check(t[::-1], p, q), pred)
    with pytest.raises(ValueError, match="horizons"):
        evaluate_predictors(Trajectory.check(t, p, q), pred, horizons=(-0.1,))
    with pytest.raises(ValueError, match="pos_sigma"):
        KalmanPredictor(MotionModel(), 0.0, 1e-3)
    with pytest.raises(ValueError, match="part"):
        pred.part("velocity")
