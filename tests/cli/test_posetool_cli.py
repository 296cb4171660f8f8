"""Smoke tests: every PoseTool subcommand on a small real recording."""

from __future__ import annotations

import json

import numpy as np
import pytest

from trackflow.cli.main import main
from trackflow.io import read_stream


@pytest.fixture
def small(shared_data, tmp_path):
    src = shared_data / "tum_rgbd" / "freiburg1_xyz-groundtruth.txt"
    stream, _ = read_stream(src, format="tum")
    path = tmp_path / "small.tfrec"
    from trackflow.io import write_stream

    write_stream(path, stream[:1200])
    return path


def test_evaluate_json_interface(small, capsys):
    assert main(["evaluate", str(small), "--json", "--quiet", "--horizons", "20,50"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert set(d["predictors"]) == {"kalman", "linear", "none"}
    s = d["predictors"]["kalman"]["50"]
    assert set(s) == {"pos_avg_mm", "pos_rms_mm", "ori_avg_deg", "ori_rms_deg", "n"}
    assert s["n"] > 100 and s["pos_rms_mm"] >= s["pos_avg_mm"] > 0
    assert d["scored_from_s"] > 0 and "noise" in d["motion_model"]


def test_every_subcommand_runs(small, tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    assert main(["info", str(small), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["samples"] == 1200 and 90 < info["rate_hz"] < 110
    assert main(["convert", str(small), str(out / "a.txt")]) == 0
    assert main(["shift", str(out / "a.txt"), str(out / "b.tfrec"), "--offset", "0.5"]) == 0
    a, _ = read_stream(out / "a.txt")
    b, _ = read_stream(out / "b.tfrec")
    assert np.all(b.t_ns - a.t_ns == 500_000_000)
    assert main(["invert", str(small), str(out / "inv.tfrec")]) == 0
    assert main(["infer", str(small), str(out / "inv.tfrec"), str(out / "id.tfrec")]) == 0
    ident, _ = read_stream(out / "id.tfrec")
    assert np.abs(ident.position).max() < 1e-9
    assert main(["tune", str(small), "--quiet", "--derivatives", "2"]) == 0
    assert "motion_model" in json.loads(capsys.readouterr().out)
    assert main(["plot", str(small), "--out", str(out), "--length", "1", "--tune-fraction", "0"]) == 0
    assert len(list(out.glob("*.png"))) == 2
    rc = main(["filter", str(small), str(out / "f.tfrec")])
    if rc == 0:
        assert main(["scale-cov", str(out / "f.tfrec"), str(out / "g.tfrec"), "--factor", "4"]) == 0
        f, _ = read_stream(out / "f.tfrec")
        g, _ = read_stream(out / "g.tfrec")
        assert np.allclose(g.covariance, 4 * f.covariance)


def test_errors_become_exit_code_1(small, tmp_path, capsys):
    assert main(["scale-cov", str(small), str(tmp_path / "x.tfrec"), "--factor", "2"]) == 1
    assert "no covariance" in capsys.readouterr().err
    assert main(["evaluate", str(tmp_path / "missing.txt"), "--quiet"]) == 1
