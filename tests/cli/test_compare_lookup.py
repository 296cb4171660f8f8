"""``trackflow compare`` (checked against evo), ``lookup`` and the trajectory plots."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from trackflow.cli.main import main
from trackflow.evaluation import associate, compare_trajectories
from trackflow.io import PoseStream, read_stream, write_stream
from trackflow.math import quat_from_matrix, quat_to_matrix, umeyama

DATA = Path(__file__).parent / "data"
GT = DATA / "fr1_xyz_groundtruth_10s.txt"
SLAM = DATA / "fr1_xyz_rgbdslam_10s.txt"
SHARED = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "tum_rgbd"


def test_umeyama_recovers_a_similarity():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(50, 3))
    r = quat_to_matrix(np.array([0.2, -0.3, 0.5, 0.79]) / np.linalg.norm([0.2, -0.3, 0.5, 0.79]))
    y = 1.7 * x @ r.T + [1.0, -2.0, 0.5]
    fit = umeyama(y, x, with_scale=True)
    r_, t_, s_ = fit.rotation, fit.translation, fit.scale
    assert np.allclose(r_, r, atol=1e-12) and np.isclose(s_, 1.7) and np.allclose(t_, [1, -2, 0.5])
    fit = umeyama(y / 1.7, x, with_scale=False)
    r_, t_, s_ = fit.rotation, fit.translation, fit.scale
    assert s_ == 1.0 and np.allclose(r_, r, atol=1e-12)
    with pytest.raises(ValueError, match="collinear"):
        umeyama(np.outer(np.arange(5.0), [1, 0, 0]), np.outer(np.arange(5.0), [1, 1, 0]))


def test_association_nearest_within_tolerance():
    t_ref = np.array([0.0, 0.1, 0.2, 0.3])
    t_est = np.array([0.004, 0.2049, 0.305, 0.5, 0.6])  # the longer one
    i_ref, i_est = associate(t_ref, t_est, t_max_diff=0.01)
    assert i_ref.tolist() == [0, 2, 3] and i_est.tolist() == [0, 1, 2]
    i_ref, i_est = associate(t_ref, t_est, t_max_diff=0.01, t_offset=-0.2)
    assert i_ref.tolist() == [0, 1, 3] and i_est.tolist() == [1, 2, 3]


def test_rigidly_moved_copy_has_zero_error_after_se3_alignment():
    ref, _ = read_stream(GT)
    r = quat_to_matrix(np.array([0.0, 0.0, np.sin(0.4), np.cos(0.4)]))
    pos = ref.position @ r.T + [3.0, -1.0, 2.0]
    quat = quat_from_matrix(r @ quat_to_matrix(ref.quaternion))
    est = PoseStream("world", "body", ref.t_ns + 2_000_000, pos, quat)
    res = compare_trajectories(ref, est, align="se3")
    assert res.stats()["ape_trans_m"]["max"] < 1e-12
    assert res.stats()["ape_rot_deg"]["max"] < 1e-6
    assert res.stats()["rpe_trans_m"]["max"] < 1e-12
    raw = compare_trajectories(ref, est, align="none")
    assert raw.stats()["ape_trans_m"]["min"] > 1.0
    # relative errors do not depend on a rigid alignment
    assert np.allclose(raw.rpe_trans, res.rpe_trans, atol=1e-12)


def test_nees_from_estimate_covariance():
    ref, _ = read_stream(GT)
    rng = np.random.default_rng(1)
    sigma = 0.002
    pos = ref.position + rng.normal(scale=sigma, size=ref.position.shape)
    cov = np.broadcast_to(np.diag([sigma**2] * 3 + [1e-6] * 3), (len(ref), 6, 6))
    est = PoseStream("world", "body", ref.t_ns, pos, ref.quaternion, covariance=cov)
    st = compare_trajectories(ref, est).stats()["ape_position_nees"]
    assert 2.7 < st["mean"] < 3.3 and 0.92 < st["inside_95_percent"] < 0.98


@pytest.mark.parametrize("align", ["none", "se3", "sim3", "origin"])
@pytest.mark.parametrize("offset", [0.0, 0.015])
def test_agrees_with_evo(align, offset):
    """APE and RPE statistics equal evo's to 1e-6 m on the TUM RGB-D pair (issue bar)."""
    pytest.importorskip("evo", reason="evo (bench/dev extra) is the reference implementation")
    from evo.core import metrics, sync
    from evo.tools import file_interface

    ref_path = SHARED / "freiburg1_xyz-groundtruth.txt"
    est_path = SHARED / "freiburg1_xyz-rgbdslam.txt"
    if not ref_path.exists():
        ref_path, est_path = GT, SLAM  # the shipped excerpts of the same pair
    ref_e = file_interface.read_tum_trajectory_file(str(ref_path))
    est_e = file_interface.read_tum_trajectory_file(str(est_path))
    ref_e, est_e = sync.associate_trajectories(ref_e, est_e, max_diff=0.01, offset_2=offset)
    if align in ("se3", "sim3"):
        est_e.align(ref_e, correct_scale=align == "sim3")
    elif align == "origin":
        est_e.align_origin(ref_e)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref_e, est_e))
    rpe = metrics.RPE(metrics.PoseRelation.translation_part, 1, metrics.Unit.frames)
    rpe.process_data((ref_e, est_e))
    ref, _ = read_stream(ref_path)
    est, _ = read_stream(est_path)
    res = compare_trajectories(ref, est, t_max_diff=0.01, t_offset=offset, align=align)
    assert len(res.t) == len(ape.error)
    assert np.max(np.abs(res.ape_trans - ape.error)) < 1e-6
    assert np.max(np.abs(res.rpe_trans - rpe.error)) < 1e-6
    st = res.stats()
    for key in ("rmse", "mean", "median", "std", "min", "max"):
        kind = getattr(metrics.StatisticsType, key)
        assert abs(st["ape_trans_m"][key] - ape.get_statistic(kind)) < 1e-6
        assert abs(st["rpe_trans_m"][key] - rpe.get_statistic(kind)) < 1e-6


def test_compare_cli_results_and_plots(tmp_path, capsys):
    res_path = tmp_path / "r.json"
    argv = ["compare", str(GT), str(SLAM), "--align", "sim3", "--save-results", str(res_path),
            "--plot", str(tmp_path), "--t-max-diff", "0.02", "--t-offset", "-0.001"]  # fmt: skip
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "ape_trans_m" in out and "alignment sim3" in out
    d = json.loads(res_path.read_text())
    assert d["settings"]["t_max_diff_s"] == 0.02 and d["alignment"]["method"] == "sim3"
    assert len(d["arrays"]["ape_trans_m"]) == d["pairs"] > 100
    pngs = sorted(p.name for p in tmp_path.glob("*.png"))
    assert len(pngs) == 2 and all(p.startswith("fr1_xyz_rgbdslam_10s_vs_") for p in pngs)
    assert main(argv) == 1  # results exist: refused without --force
    assert "--force" in capsys.readouterr().err


def test_a_delta_beyond_the_pairs_is_refused(capsys):
    """evo refuses an RPE step longer than the trajectory; a table of NaN is no answer."""
    assert main(["compare", str(GT), str(SLAM), "--t-max-diff", "0.02", "--delta", "100000"]) == 1
    err = capsys.readouterr().err
    assert "delta 100000 needs more than 100000 associated poses; there are" in err


def test_plot_traj_several_files(tmp_path, capsys):
    out = tmp_path / "t.png"
    argv = ["plot-traj", str(GT), str(SLAM), "--out", str(out), "--views", "top,side,3d"]
    assert main(argv) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(argv[:-2] + ["--views", "diagonal"]) == 1
    assert "views must be" in capsys.readouterr().err


def _setup(tmp_path) -> Path:
    s, _ = read_stream(GT)
    write_stream(tmp_path / "art.tfrec", s)
    (tmp_path / "s.yaml").write_text(
        "frames: [P, A, T]\nsensors:\n  - {name: art, source: A, target: T, rate_hz: 100, "
        "sigma_pos_mm: 1, sigma_ori_deg: 0.5, recording: art.tfrec}\nstatics:\n"
        "  - {name: proj, source: P, target: A, position: [0, 0, 1], sigma_pos_mm: 0.1}\n"
    )
    return tmp_path / "s.yaml"


@pytest.mark.slow
def test_lookup_between_samples(tmp_path, capsys):
    setup = _setup(tmp_path)
    s, _ = read_stream(GT)
    k = 500
    t = int(s.t_ns[k])
    assert main(["lookup", str(setup), "--from", "P", "--to", "T", "--at", f"{t * 1e-9:.9f}",
                 "--json"]) == 0  # fmt: skip
    d = json.loads(capsys.readouterr().out)
    assert abs(d["t_s"] - t * 1e-9) < 1e-6
    # P->A is a 1 m shift along z; the filtered pose stays within a few mm of the sample
    assert np.allclose(d["position_m"], s.position[k] + [0, 0, 1], atol=5e-3)
    assert 0 < d["sigma_position_mm"][0] < 1.5 and d["age_ms"] >= 0
    assert d["path"] == "P->A[proj] . A->T[art]"
    assert main(["lookup", str(setup), "--from", "P", "--to", "T"]) == 0
    text = capsys.readouterr().out
    assert "RPY (degree)" in text and "Age of the newest measurement" in text


def test_lookup_without_recording_names_the_sensor(tmp_path, capsys):
    (tmp_path / "s.yaml").write_text("sensors:\n  - {name: art, source: A, target: T}\n")
    assert main(["lookup", str(tmp_path / "s.yaml"), "--from", "A", "--to", "T"]) == 1
    err = capsys.readouterr().err
    assert "s.yaml" in err and "'art'" in err and "recording" in err
