"""Alignment, sensor noise and pivot calibration against synthetic truth; degenerate input."""

from __future__ import annotations

import numpy as np
import pytest
from _synth import X_TRUE, motion, perturb, two_trackers
from scipy import stats

from trackflow.calibration import (
    align_trajectories,
    fit_alignment,
    pivot_calibration,
    sensor_noise,
)
from trackflow.io import PoseStream
from trackflow.math import quat_conjugate, quat_exp, quat_log, quat_multiply, quat_rotate

T_TRUE = (np.array([0.5, -0.2, 1.0]), quat_exp(np.array([0.2, -0.4, 1.3])))


def _aligned_pair(seed, offset=0.12, sigma=1e-3, scale=1.0):
    rng = np.random.default_rng(seed)
    ta = np.arange(0, 30, 1 / 100) + rng.uniform(0, 0.01)
    tb = np.arange(0, 30, 1 / 60) + rng.uniform(0, 0.02)
    pa, qa = motion(ta, seed)
    pb_t, qb_t = motion(tb, seed)
    # b's world: p_b = (R^T (p_a - t)) / s ; orientation in b's world too
    pb = quat_rotate(quat_conjugate(T_TRUE[1]), pb_t - T_TRUE[0]) / scale
    qb = quat_multiply(quat_conjugate(T_TRUE[1]), qb_t)
    pa, qa = perturb(pa, qa, sigma, np.radians(0.1), rng)
    pb, qb = perturb(pb, qb, sigma, np.radians(0.1), rng)
    a = PoseStream.from_seconds("wa", "body", 1e9 + ta, pa, qa)
    b = PoseStream.from_seconds("wb", "body", 1e9 + tb - offset, pb, qb)
    return a, b


def _pose_err(T, true):
    return np.concatenate(
        [true[0] - T.position, quat_log(quat_multiply(quat_conjugate(T.quaternion), true[1]))]
    )


def test_alignment_is_consistent_and_finds_the_offset():
    nees, off = [], []
    for seed in range(6):
        a, b = _aligned_pair(seed)
        r = align_trajectories(a, b)
        e = _pose_err(r.T, T_TRUE)
        nees.append(e @ np.linalg.solve(r.T.covariance, e))
        off.append((r.offset_s - 0.12) / r.offset_sigma_s)
        assert abs(r.offset_s - 0.12) < 0.1 / 60
    lo, hi = stats.chi2.ppf([0.005, 0.995], 6 * len(nees))
    assert lo <= np.sum(nees) <= hi
    assert np.sum(np.square(off)) <= stats.chi2.ppf(0.999, len(off))


def test_alignment_with_scale():
    a, b = _aligned_pair(7, scale=2.5)
    r = align_trajectories(a, b, with_scale=True)
    assert abs(r.scale - 2.5) < 4 * r.scale_sigma + 1e-4
    # 3-D noise: sqrt(3 (1 mm^2 + (2.5 x 1 mm)^2)) = 4.7 mm
    assert r.residual_rmse_mm < 6.0


def test_lever_arm_gain_matches_finite_differences():
    a, b = two_trackers(3, duration=15.0, offset=0.1)
    lever = X_TRUE[0]
    r = align_trajectories(a, b, lever_arm=lever)
    assert r.lever_arm_gain.shape == (7, 3) and r.covariance.shape == (7, 7)
    # With the offset fixed the residual's Jacobian is exact and so is the gain. (The offset's
    # column is the sensor velocity smoothed over +-2 samples, the slope of the expected
    # motion, so with the offset estimated the gain is that of the expected objective, which
    # a difference quotient through the noisy interpolation does not reproduce.)
    fixed = align_trajectories(a, b, offset_s=0.1, estimate_offset=False, lever_arm=lever)
    assert fixed.lever_arm_gain.shape == (6, 3)
    # a's positions are linear in the lever arm, the robust solver's rejections and scale
    # re-estimation are not (the +-h runs reject different blocks): differences of 1 cm, and
    # 0.025 m/m or rad/m of tolerance on gains of order 1 (the quotients scatter by up to
    # 0.011 on these data; a wrong sign or frame would be off by about 1)
    h = 1e-2
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        rp, rm = (
            align_trajectories(a, b, offset_s=0.1, estimate_offset=False, lever_arm=lever + s * d)
            for s in (1, -1)
        )
        dt = (rp.T.position - rm.T.position) / (2 * h)
        dth = quat_log(quat_multiply(quat_conjugate(rm.T.quaternion), rp.T.quaternion)) / (2 * h)
        np.testing.assert_allclose(fixed.lever_arm_gain[:, k], np.r_[dt, dth], rtol=0, atol=0.025)
    # a lever arm is the same as moving a's positions to the point by hand
    moved = a.with_(position=a.position + quat_rotate(a.quaternion, lever))
    ref = align_trajectories(moved, b, offset_s=r.offset_s, estimate_offset=False)
    same = align_trajectories(a, b, offset_s=r.offset_s, estimate_offset=False, lever_arm=lever)
    np.testing.assert_allclose(same.T.position, ref.T.position, atol=1e-9)
    np.testing.assert_allclose(same.T.covariance, ref.T.covariance, rtol=1e-6, atol=1e-18)


def test_lever_arm_input_is_checked():
    a, b = two_trackers(3, duration=10.0)
    with pytest.raises(ValueError, match=r"shape \(3,\)"):
        align_trajectories(a, b, lever_arm=np.zeros(2))
    with pytest.raises(ValueError, match="needs a lever_arm"):
        align_trajectories(a, b, lever_arm_covariance=np.eye(3))


def test_fit_alignment_rejects_reflections_and_lines():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(50, 3))
    with pytest.raises(ValueError, match="handedness"):
        fit_alignment(p, p * np.array([1, 1, -1]))
    line = np.outer(np.linspace(0, 1, 50), [1.0, 2.0, 0.5])
    with pytest.raises(ValueError, match="line"):
        fit_alignment(line, line)


def _static_stream(seed, sigma_p, sigma_r, n_rest=3):
    """Rest segments of 2 s at 100 Hz separated by 1 s moves; white noise of known sigma."""
    rng = np.random.default_rng(seed)
    ts, ps, qs = [], [], []
    t0 = 0.0
    for k in range(n_rest):
        t = t0 + np.arange(0, 2, 0.01)
        p0 = rng.normal(0, 0.3, 3)
        q0 = quat_exp(rng.normal(0, 1, 3))
        p, q = perturb(np.tile(p0, (len(t), 1)), np.tile(q0, (len(t), 1)), sigma_p, sigma_r, rng)
        ts.append(t)
        ps.append(p)
        qs.append(q)
        tm = t0 + 2 + np.arange(0, 1, 0.01)
        pm, qm = motion(tm, seed + k)
        ts.append(tm)
        ps.append(pm)
        qs.append(qm)
        t0 += 3
    return PoseStream.from_seconds(
        "w", "b", np.concatenate(ts), np.concatenate(ps), np.concatenate(qs)
    )


def test_static_noise_recovers_the_sigma():
    s = _static_stream(1, sigma_p=2e-4, sigma_r=np.radians(0.05))
    r = sensor_noise(s, "static")
    assert r.n_segments == 3
    np.testing.assert_allclose(r.sigma_pos_mm, 0.2, rtol=0.15)
    np.testing.assert_allclose(r.sigma_ori_deg, 0.05, rtol=0.15)


def test_dynamic_noise_recovers_the_sigma():
    rng = np.random.default_rng(2)
    t = np.arange(0, 30, 0.01)
    p, q = motion(t, 2)
    p, q = perturb(p, q, 3e-4, np.radians(0.1), rng)
    r = sensor_noise(PoseStream.from_seconds("w", "b", t, p, q), "dynamic")
    np.testing.assert_allclose(r.sigma_pos_mm, 0.3, rtol=0.15)
    np.testing.assert_allclose(r.sigma_ori_deg, 0.1, rtol=0.15)


@pytest.mark.slow
def test_innovation_noise_of_a_tuned_filter():
    rng = np.random.default_rng(2)
    t = np.arange(0, 30, 0.01)
    p, q = motion(t, 2)
    p, q = perturb(p, q, 3e-4, np.radians(0.1), rng)
    s = PoseStream.from_seconds("w", "b", t, p, q)
    r = sensor_noise(s, "innovation")
    # Mehra's E[nu nu^T] = P^- + R holds for the optimal filter only: position to 10 %,
    # orientation (whose tuned model is further from the truth) to 30 %
    np.testing.assert_allclose(r.sigma_pos_mm, 0.3, rtol=0.1)
    np.testing.assert_allclose(r.sigma_ori_deg, 0.1, rtol=0.3)
    with pytest.raises(ValueError, match="motion model does not fit"):
        sensor_noise(s, "innovation", tune=False)


def test_noise_without_rest_is_a_clear_error():
    t = np.arange(0, 10, 0.01)
    p, q = motion(t, 3)
    with pytest.raises(ValueError, match="no static segment"):
        sensor_noise(PoseStream.from_seconds("w", "b", t, p, q), "static")


def _pivot_stream(seed, tip, pivot, sigma, axes=(1, 1, 0)):
    rng = np.random.default_rng(seed)
    t = np.arange(0, 20, 0.01)
    rv = np.stack([a * 0.5 * np.sin(2 * np.pi * f * t) for a, f in zip(axes, (0.2, 0.31, 0.17))])
    q = quat_exp(rv.T)
    p = pivot - quat_rotate(q, tip) + rng.normal(0, sigma, (len(t), 3))
    return PoseStream.from_seconds("w", "tool", t, p, q)


def test_pivot_recovers_tip_and_pivot():
    tip, piv = np.array([0.01, -0.02, 0.15]), np.array([0.3, 0.1, -0.2])
    errs = []
    for seed in range(5):
        r = pivot_calibration(_pivot_stream(seed, tip, piv, 5e-4))
        e = np.concatenate([r.tip - tip, r.pivot - piv])
        errs.append(e @ np.linalg.solve(r.covariance, e))
        assert np.linalg.norm(r.tip - tip) < 1e-3
    assert np.sum(errs) <= stats.chi2.ppf(0.999, 6 * len(errs))


def test_pivot_single_axis_is_a_clear_error():
    with pytest.raises(ValueError, match="one axis"):
        pivot_calibration(_pivot_stream(0, np.array([0, 0, 0.1]), np.zeros(3), 1e-4, (1, 0, 0)))


def test_cli_pivot_and_noise_write_reports_and_fragments(tmp_path, capsys):
    import json

    import yaml

    from trackflow.cli.main import main
    from trackflow.io import write_stream

    tip, piv = np.array([0.01, -0.02, 0.15]), np.array([0.3, 0.1, -0.2])
    write_stream(tmp_path / "pivot.txt", _pivot_stream(0, tip, piv, 5e-4))
    extra = ["--report", str(tmp_path / "rep"), "--fragment", str(tmp_path / "tip.yaml")]
    rc = main(["calibrate", "pivot", str(tmp_path / "pivot.txt"), "--json", *extra])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    np.testing.assert_allclose(out["tip"], tip, atol=1e-3)
    assert (tmp_path / "rep" / "residuals.png").is_file()
    frag = yaml.safe_load((tmp_path / "tip.yaml").read_text())
    np.testing.assert_allclose(frag["statics"][0]["position"], out["tip"])
    write_stream(tmp_path / "rest.txt", _static_stream(1, 2e-4, np.radians(0.05)))
    rc = main(["calibrate", "noise", str(tmp_path / "rest.txt"), "--json", "--sensor-name",
               "art", "--fragment", str(tmp_path / "noise.yaml"),
               "--report", str(tmp_path / "nrep")])  # fmt: skip
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    sensors = yaml.safe_load((tmp_path / "noise.yaml").read_text())["sensors"]
    assert sensors[0]["name"] == "art"
    np.testing.assert_allclose(sensors[0]["covariance"], out["covariance"])
    assert (tmp_path / "nrep" / "residuals.png").is_file()
