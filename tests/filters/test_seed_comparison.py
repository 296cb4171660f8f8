"""The comparison of the seed filters with the pose KF (experiments/compare_seed_filters.py).

Runs the script's quick mode once (sim + two recordings, two virtual trackers, about 25 s) and
checks properties that follow from how the filters work, not numbers copied from a run:

* the measurements carry their true covariance (mean NEES near 6, they are independent);
* the pose KF and Ude's filter filter: their pose error is below the measurement's wherever the
  sensor noise dominates the motion-model error (the simulation, and the noisy single camera);
* feature-level (Ude) and pose-level (KF) fusion agree when the single-frame pose estimate is
  well determined (the four-camera tracker): to first order they use the same information;
* the relative-motion EKF does not filter the pose (its state has no pose): its filtered pose
  is about as good as the measurement;
* every 50 ms prediction is worse than the filtered pose and, where the sensor noise is small
  against 50 ms of motion, better than holding the last measurement;
* NEES and timings are finite and positive.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
FILTERS = ("pose KF", "Ude GN", "D-U EKF")
POSE_FILTERS = ("pose KF", "Ude GN")  # the two with the pose in their state


def _load():
    path = REPO / "experiments" / "compare_seed_filters.py"
    spec = importlib.util.spec_from_file_location("compare_seed_filters", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["compare_seed_filters"] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def result():
    from conftest import shared_data_dir

    data = shared_data_dir()
    if not (data / "README.md").is_file():
        pytest.skip(f"shared recordings not found at {data}")
    return _load().compare(quick=True, seed=0, data=data)


def _scenarios(result, sensor=None, motion=None):
    out = []
    for name, sc in result["scenarios"].items():
        m, s = name.split(", ")
        if (sensor is None or s == sensor) and (motion is None or m == motion):
            out.append((name, sc))
    assert out, (sensor, motion)
    return out


def test_all_scenarios_and_filters_present(result):
    names = set(result["scenarios"])
    for motion in ("sim", "ar_table", "tumvi"):
        for sensor in ("mocap", "1 camera"):
            assert f"{motion}, {sensor}" in names
    for _, sc in result["scenarios"].items():
        assert set(sc["filters"]) == set(FILTERS)
        assert sc["frames"] > 100


def test_metrics_finite_and_positive(result):
    for name, sc in result["scenarios"].items():
        for fname, r in sc["filters"].items():
            for part in ("filtered", "predicted_50ms"):
                for key, v in r[part].items():
                    assert math.isfinite(v) and v > 0, (name, fname, part, key, v)
            assert math.isfinite(r["nees_mean"]) and r["nees_mean"] > 0, (name, fname)
            assert math.isfinite(r["nees_pred_mean"]) and r["nees_pred_mean"] > 0
            lo, hi = r["nees_band_95"]
            assert 0 < lo < 6 < hi
            assert math.isfinite(r["step_us"]) and r["step_us"] > 0, (name, fname)


def test_measurement_covariance_is_consistent(result):
    # Independent frames with their own (first-order) covariance: mean NEES ~ 6. The band
    # allows for the nonlinearity of the single-camera pose estimate.
    for name, sc in result["scenarios"].items():
        assert 4.5 < sc["baseline"]["measurement_nees_mean"] < 7.5, name


def test_pose_filters_beat_the_measurement_where_noise_dominates(result):
    cases = _scenarios(result, motion="sim") + _scenarios(result, sensor="1 camera")
    for name, sc in cases:
        m = sc["baseline"]["measurement"]
        for fname in POSE_FILTERS:
            f = sc["filters"][fname]["filtered"]
            assert f["pos_rms_mm"] < m["pos_rms_mm"], (name, fname)
            assert f["ori_rms_deg"] < m["ori_rms_deg"], (name, fname)


def test_single_camera_filtering_gain_is_large(result):
    # Depth from one camera is noisy frame by frame; a motion model averages it.
    for name, sc in _scenarios(result, sensor="1 camera"):
        m = sc["baseline"]["measurement"]["pos_rms_mm"]
        for fname in POSE_FILTERS:
            assert sc["filters"][fname]["filtered"]["pos_rms_mm"] < 0.8 * m, (name, fname)


def test_feature_and_pose_fusion_agree_with_a_well_determined_pose(result):
    for name, sc in _scenarios(result, sensor="mocap"):
        kf, ude = sc["filters"]["pose KF"], sc["filters"]["Ude GN"]
        for part in ("filtered", "predicted_50ms"):
            for key in ("pos_rms_mm", "ori_rms_deg"):
                a, b = kf[part][key], ude[part][key]
                assert abs(a - b) < 0.05 * max(a, b), (name, part, key, a, b)


def test_relative_motion_ekf_does_not_filter_the_pose(result):
    for name, sc in result["scenarios"].items():
        m = sc["baseline"]["measurement"]["pos_rms_mm"]
        f = sc["filters"]["D-U EKF"]["filtered"]["pos_rms_mm"]
        assert 0.7 * m < f < 1.5 * m, (name, f, m)


def test_prediction_error_grows_with_horizon(result):
    for name, sc in result["scenarios"].items():
        for fname, r in sc["filters"].items():
            assert r["predicted_50ms"]["pos_rms_mm"] > r["filtered"]["pos_rms_mm"], (name, fname)
            assert r["predicted_50ms"]["ori_rms_deg"] > r["filtered"]["ori_rms_deg"], (name, fname)


def test_prediction_beats_holding_the_pose(result):
    for name, sc in result["scenarios"].items():
        hold = sc["baseline"]["hold_50ms"]["pos_rms_mm"]
        fnames = FILTERS if name.endswith("mocap") else POSE_FILTERS
        for fname in fnames:
            pred = sc["filters"][fname]["predicted_50ms"]["pos_rms_mm"]
            assert pred < hold, (name, fname, pred, hold)
