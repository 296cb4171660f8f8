"""Smoke tests: every PoseTool subcommand on small real recordings.

The recordings shipped in ``tests/cli/data`` (TUM RGB-D excerpts, see the README there) make
these run everywhere, CI included; one more test uses the shared data when it is present.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from trackflow.cli.main import main
from trackflow.io import PoseStream, read_stream, write_stream
from trackflow.math import quat_angle

DATA = Path(__file__).parent / "data"
GT = DATA / "fr1_xyz_groundtruth_10s.txt"
SLAM = DATA / "fr1_xyz_rgbdslam_10s.txt"


@pytest.fixture
def small(tmp_path):
    stream, _ = read_stream(GT, format="tum")
    path = tmp_path / "small.tfrec"
    write_stream(path, stream)
    return path


def test_evaluate_json_interface(small, capsys):
    assert main(["evaluate", str(small), "--json", "--quiet", "--horizons", "20,50"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert set(d["predictors"]) == {"kalman", "linear", "none"}
    s = d["predictors"]["kalman"]["50"]
    assert set(s) == {"pos_avg_mm", "pos_rms_mm", "ori_avg_deg", "ori_rms_deg", "n"}
    assert s["n"] > 100 and s["pos_rms_mm"] >= s["pos_avg_mm"] > 0
    assert d["scored_from_s"] > 0 and d["motion_model"]["kind"] in (
        "white_noise",
        "thesis",
        "twist_ar",
        "partwise",
    )


@pytest.mark.parametrize("orders", ["none", "3"])
def test_tune_learned_orders_option(orders, capsys):
    assert main(["tune", str(GT), "--quiet", "--learned-orders", orders]) == 0
    d = json.loads(capsys.readouterr().out)
    tried = [k for k in d["candidates"].get("twist_ar", {}) if k != "excitation"]
    if orders == "none":
        assert d["motion_model"]["kind"] == "white_noise" and tried == []
    else:
        assert tried and all(k.split()[1] == "3" for k in tried)


def test_tune_learned_orders_rejects_garbage(capsys):
    assert main(["tune", str(GT), "--quiet", "--learned-orders", "three"]) == 1
    assert "comma-separated integers" in capsys.readouterr().err


def test_every_subcommand_runs(small, tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    assert main(["info", str(small), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["samples"] == 1000 and 90 < info["rate_hz"] < 110
    assert main(["convert", str(small), str(out / "a.txt")]) == 0
    assert main(["shift", str(out / "a.txt"), str(out / "b.tfrec"), "--offset", "0.5"]) == 0
    a, _ = read_stream(out / "a.txt")
    b, _ = read_stream(out / "b.tfrec")
    assert np.all(b.t_ns - a.t_ns == 500_000_000)
    assert main(["invert", str(small), str(out / "inv.tfrec")]) == 0
    assert main(["tune", str(small), "--quiet", "--pos-derivatives", "2", "--ori-derivatives",
                 "1"]) == 0  # fmt: skip
    assert "motion_model" in json.loads(capsys.readouterr().out)
    args = ["plot", str(small), "--out", str(out), "--length", "1", "--tune-fraction", "0"]
    assert main(args) == 0
    assert len(list(out.glob("*.png"))) == 2
    assert main(["filter", str(small), str(out / "f.tfrec"), "--horizon", "20"]) == 0
    assert main(["scale-cov", str(out / "f.tfrec"), str(out / "g.tfrec"), "--factor", "4"]) == 0
    f, _ = read_stream(out / "f.tfrec")
    g, _ = read_stream(out / "g.tfrec")
    assert len(f) == 1000 and np.allclose(g.covariance, 4 * f.covariance)


def test_filter_a_recording_that_never_moves(tmp_path):
    """A body at rest with no noise at all: NIS 0, nothing to calibrate the noise by; the
    filter still runs (it failed with "noise scale must be > 0, got 0.0")."""
    t = np.arange(200, dtype=np.int64) * 10_000_000
    still = PoseStream("w", "b", t, np.tile([1.0, 2.0, 0.5], (200, 1)),
                       np.tile([0.0, 0.0, 0.0, 1.0], (200, 1)))  # fmt: skip
    path = tmp_path / "still.tfrec"
    write_stream(path, still)
    assert main(["filter", str(path), str(tmp_path / "f.tfrec")]) == 0
    f, _ = read_stream(tmp_path / "f.tfrec")
    assert len(f) == 200 and np.allclose(f.position, [1.0, 2.0, 0.5])


def test_infer_aligns_two_recordings_by_filters(small, tmp_path):
    # T_world_body (100 Hz) chained with the inverse of its own 3x subsampled, shifted-clock
    # copy: the filters align them at the union of the timestamps, so the chain is ~identity
    gt, _ = read_stream(small)
    sub = gt[1::3].with_(t_ns=gt.t_ns[1::3] + 1_000_000)  # 1 ms off the first's clock
    write_stream(tmp_path / "sub.tfrec", sub)
    assert main(["invert", str(tmp_path / "sub.tfrec"), str(tmp_path / "inv.tfrec")]) == 0
    for extra, name in (([], "f.tfrec"), (["--interpolate"], "i.tfrec")):
        args = ["infer", str(small), str(tmp_path / "inv.tfrec"), str(tmp_path / name), *extra]
        assert main(args) == 0
    f, _ = read_stream(tmp_path / "f.tfrec")
    i, _ = read_stream(tmp_path / "i.tfrec")
    assert len(f) > len(i) > 900  # union of the timestamps vs the first's only
    assert f.source == "world" and f.target == "world"
    # the chain is the identity up to tracking noise, 1 ms of motion and the alignment error
    # (33 Hz against 100 Hz of fast handheld motion): within 2x of plain interpolation's
    ef, ei = (np.percentile(np.linalg.norm(s.position, axis=1), 95) for s in (f, i))
    assert ef < 2.0 * ei and ef < 0.015
    ident = np.array([0, 0, 0, 1.0])
    assert np.percentile(quat_angle(f.quaternion, ident), 95) < np.radians(0.5)
    assert f.covariance is not None and np.all(np.isfinite(f.covariance))


def test_infer_two_different_trackers(tmp_path):
    # SLAM estimate (~31 Hz, its own frame) vs motion capture: runs and overlaps in time
    assert main(["invert", str(GT), str(tmp_path / "inv.tfrec")]) == 0
    assert main(["infer", str(SLAM), str(tmp_path / "inv.tfrec"), str(tmp_path / "x.tfrec")]) == 0
    x, _ = read_stream(tmp_path / "x.tfrec")
    assert len(x) > 600 and x.covariance is not None


def test_errors_become_exit_code_1(small, tmp_path, capsys):
    assert main(["scale-cov", str(small), str(tmp_path / "x.tfrec"), "--factor", "2"]) == 1
    assert "no covariance" in capsys.readouterr().err
    assert main(["evaluate", str(tmp_path / "missing.txt"), "--quiet"]) == 1
    assert main(["infer", str(small), str(small), str(tmp_path / "y.tfrec")]) == 1
    assert "cannot chain" in capsys.readouterr().err


def test_evaluate_on_a_shared_recording(shared_data, capsys):
    src = shared_data / "tum_rgbd" / "freiburg1_xyz-groundtruth.txt"
    assert main(["evaluate", str(src), "--json", "--quiet", "--horizons", "50,100"]) == 0
    d = json.loads(capsys.readouterr().out)
    k, lin = d["predictors"]["kalman"], d["predictors"]["linear"]
    assert k["50"]["pos_rms_mm"] < lin["50"]["pos_rms_mm"]
