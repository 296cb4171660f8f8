"""``trackflow evaluate --imu``: IMU-aided prediction scored like the PoseTool."""

from __future__ import annotations

import json

import numpy as np
import pytest

from trackflow.cli.main import main
from trackflow.evaluation import (
    LinearPredictor,
    NoPredictor,
    TrackerTrajectory,
    Trajectory,
    predict_from_last_pose,
    predict_linear,
    thin_poses,
)
from trackflow.math import quat_angle, quat_exp


@pytest.fixture
def broad_slice(shared_data, tmp_path):
    from scipy.io import loadmat, savemat

    src = shared_data / "broad" / "06_undisturbed_fast_rotation_A.mat"
    if not src.is_file():
        pytest.skip(f"{src} not present")
    m = loadmat(src)
    keep = slice(20000, 20000 + 20 * 286)  # 20 s of fast rotation
    out = tmp_path / "fast_rotation_20s.mat"
    savemat(out, {k: m[k][keep] for k in ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "opt_pos")})
    return out


@pytest.mark.slow
@pytest.mark.parametrize("origins", ["poses", "anytime"])
def test_evaluate_imu_scores_both_predictors(broad_slice, capsys, origins):
    args = ["evaluate", str(broad_slice), "--imu", str(broad_slice), "--pose-rate", "60",
            "--horizons", "20,50", "--learned-orders", "none", "--json", "--quiet",
            "--origins", origins]  # fmt: skip
    assert main(args) == 0
    d = json.loads(capsys.readouterr().out)
    assert set(d["predictors"]) == {"kalman", "kalman_imu", "linear", "none"}
    keys = {"pos_avg_mm", "pos_rms_mm", "ori_avg_deg", "ori_rms_deg", "n"}
    for per in d["predictors"].values():
        assert set(per) == {"20", "50"} and all(set(s) == keys for s in per.values())
    k, ki, none = (d["predictors"][n]["50"] for n in ("kalman", "kalman_imu", "none"))
    # all predictors are scored on the same origins: 10 s at 60 Hz or at 285.7 Hz
    assert ki["n"] == k["n"] == none["n"] > (500 if origins == "poses" else 2500)
    # the gyro knows the current angular velocity: far better than 60 Hz poses alone
    assert ki["ori_rms_deg"] < 0.7 * k["ori_rms_deg"] < none["ori_rms_deg"]
    imu = d["tuning"]["imu"]
    assert -0.01 < imu["clock_offset_s"] < 0.0  # BROAD's optical reference lags the IMU
    assert all(0 <= v <= 1 for v in imu["shrinkage"]["orientation"])
    assert d["tuning"]["pose_rate_hz"] == 60.0 and d["tuning"]["origins"] == origins


def test_pose_rate_without_imu_is_an_error(broad_slice, capsys):
    assert main(["evaluate", str(broad_slice), "--pose-rate", "60", "--quiet"]) == 1
    assert "--pose-rate needs --imu" in capsys.readouterr().err


def test_an_imu_recording_of_another_session_is_an_error(broad_slice, shared_data, capsys):
    other = shared_data / "euroc" / "V1_01_easy_imu0.csv"  # nanosecond stamps of 2014
    if not other.is_file():
        pytest.skip(f"{other} not present")
    assert main(["evaluate", str(broad_slice), "--imu", str(other), "--quiet"]) == 1
    assert "overlap" in capsys.readouterr().err


def test_thin_poses_picks_one_sample_per_tick():
    t = np.arange(0, 1.0, 1 / 285.714)
    idx = thin_poses(t, 60.0)
    assert abs(len(idx) - 60) <= 1
    assert np.all(np.diff(t[idx]) > 1 / 60 - 1 / 285)
    assert thin_poses(t, None).tolist() == list(range(len(t)))
    with pytest.raises(ValueError, match="positive"):
        thin_poses(t, -1.0)


def _truth(n=2000, rate=200.0, gap_at=None):
    t = np.arange(n) / rate
    if gap_at is not None:
        t[gap_at:] += 0.5  # a dropout of the full-rate recording
    p = np.stack([np.sin(t), np.cos(1.3 * t), 0.1 * t], 1)
    q = quat_exp(np.stack([0.5 * np.sin(2 * t), 0.3 * t, 0 * t], 1))
    return Trajectory.check(t, p, q)


def test_tracker_trajectory_targets_are_the_full_rate_truth():
    truth = _truth(gap_at=1200)
    thin = TrackerTrajectory.thinned(truth, 20.0)
    assert len(thin) < len(truth) / 9 and thin.gap_s >= truth.gap_s
    h = 0.02  # between two 20 Hz poses: the thinned poses' own interpolation would differ
    tp, tq = thin.target(h)
    i = np.searchsorted(truth.t, thin.t)
    exact = np.isin(np.round((thin.t + h) * 200), np.round(truth.t * 200))
    assert np.allclose(tp[exact], truth.position[i[exact] + 4], atol=1e-12)
    assert np.max(quat_angle(tq[exact], truth.quaternion[i[exact] + 4])) < 1e-9
    # no target inside the truth's dropout, none past the end; a selection keeps the truth
    m = thin.scored(0.1)
    t_gap = truth.t[1199]
    assert not np.any(m & (thin.t + 0.1 > t_gap) & (thin.t + 0.1 < t_gap + 0.5))
    sub = thin.select(slice(0, 30))
    assert sub.truth is truth and np.allclose(sub.target(h)[0], tp[:30])


def test_queries_between_poses_extrapolate_over_the_pose_age():
    truth = _truth(600)
    thin = TrackerTrajectory.thinned(truth, 20.0)
    tau = truth.t[20:500]
    k = np.searchsorted(thin.t, tau, side="right") - 1
    age = tau - thin.t[k]
    h = np.array([0.02, 0.05])
    lin = predict_from_last_pose(LinearPredictor(), thin, k, age, h, truth.step)
    hold = predict_from_last_pose(NoPredictor(), thin, k, age, h, truth.step)
    for i, hv in enumerate(h):
        for a in np.unique(np.round(age, 6)):  # linear extrapolation is exact on the grid
            rows = np.flatnonzero(np.isclose(age, a))
            want_p, want_q = predict_linear(thin.t, thin.position, thin.quaternion, hv + a)
            np.testing.assert_allclose(lin.position[i, rows], want_p[k[rows]], atol=1e-12)
            assert np.max(quat_angle(lin.quaternion[i, rows], want_q[k[rows]])) < 1e-9
        np.testing.assert_allclose(hold.position[i], thin.position[k])
