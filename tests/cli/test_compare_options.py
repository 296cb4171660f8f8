"""``compare``'s settings, processing options and ``compare-results``: refusals with typed
errors, round trips, and the pair kernels on both backends (issue 30)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from trackflow.cli import cmd_compare
from trackflow.cli.main import main
from trackflow.errors import ConfigError, InputError
from trackflow.evaluation import (
    ALIGNMENTS,
    DELTA_UNITS,
    POSE_RELATIONS,
    CompareResult,
    CompareSettings,
    compare_results,
    compare_trajectories,
    load_transform,
    merge_streams,
    rpe_pairs,
)
from trackflow.evaluation._pairs import motion_filter_ids
from trackflow.io import read_stream
from trackflow.math import numba_available, use_backend

DATA = Path(__file__).parent / "data"
GT = DATA / "fr1_xyz_groundtruth_10s.txt"
SLAM = DATA / "fr1_xyz_rgbdslam_10s.txt"


def test_mirrored_names_match_the_library():
    assert cmd_compare.ALIGNMENTS == ALIGNMENTS
    assert cmd_compare.POSE_RELATIONS == POSE_RELATIONS
    assert cmd_compare.DELTA_UNITS == DELTA_UNITS


@pytest.mark.parametrize(
    "bad",
    [
        {"delta": 0},
        {"delta": -1},
        {"delta": 1.5},
        {"delta": float("nan")},
        {"delta": 181, "delta_unit": "d"},
        {"delta": 3.2, "delta_unit": "r"},
        {"delta_unit": "s"},
        {"delta_tol": -0.1},
        {"n_to_align": 2, "align": "se3"},
        {"n_to_align": 10},
        {"n_to_align": 10, "align": "origin"},
        {"n_to_align": 10.5, "align": "sim3"},
        {"pose_relations": ()},
        {"pose_relations": ("trans_part", "trans_part")},
        {"pose_relations": ("translation",)},
        {"align": "affine"},
        {"t_max_diff": -0.01},
        {"t_offset": float("inf")},
    ],
)
def test_bad_settings_are_refused_with_typed_errors(bad):
    with pytest.raises(InputError):
        CompareSettings(**bad)


def test_refusals_that_need_the_data():
    ref, _ = read_stream(GT)
    est, _ = read_stream(SLAM)
    with pytest.raises(InputError, match="n_to_align 5000 exceeds the"):
        compare_trajectories(ref, est, t_max_diff=0.02, align="se3", n_to_align=5000)
    with pytest.raises(InputError, match="gives no pose pairs"):
        compare_trajectories(ref, est, t_max_diff=0.02, delta=100, delta_unit="m")
    with pytest.raises(InputError, match="needs more than 100000"):
        compare_trajectories(ref, est, t_max_diff=0.02, delta=100000)
    with pytest.raises(InputError, match="unexpected keyword"):
        compare_trajectories(ref, est, delta_units="m")
    with pytest.raises(InputError, match="same time"):
        merge_streams([est, est])
    with pytest.raises(InputError, match="different relationships"):
        merge_streams([est, est.with_(source="map")])


def test_result_round_trip_and_version_1_files(tmp_path):
    ref, _ = read_stream(GT)
    est, _ = read_stream(SLAM)
    res = compare_trajectories(
        ref,
        est,
        t_max_diff=0.02,
        align="sim3",
        pose_relations=POSE_RELATIONS,
        delta=0.05,
        delta_unit="m",
    )
    d = json.loads(json.dumps(res.as_dict(arrays=True)))
    back = CompareResult.from_dict(d)
    assert back.stats() == res.stats() and back.table() == res.table()
    # a file of the former format (no "format", "metrics", "labels") still loads
    old = {k: v for k, v in d.items() if k not in ("format", "version", "metrics", "labels")}
    old["stats"] = {k: v for k, v in d["stats"].items() if k in (
        "ape_trans_m", "ape_rot_deg", "rpe_trans_m", "rpe_rot_deg", "ape_x_m")}  # fmt: skip
    v1 = CompareResult.from_dict(old)
    assert list(v1.series) == list(old["stats"])
    assert v1.series["ape_trans_m"].stats().rmse == res.series["ape_trans_m"].stats().rmse
    with pytest.raises(InputError, match="statistics only"):
        CompareResult.from_dict(res.as_dict())
    with pytest.raises(InputError, match="not a saved comparison"):
        CompareResult.from_dict({"pairs": 3})


def test_compare_results_cli(tmp_path, capsys):
    files = []
    for align in ("se3", "sim3"):
        f = tmp_path / f"{align}.json"
        argv = [
            "compare",
            str(GT),
            str(SLAM),
            "--t-max-diff",
            "0.02",
            "--align",
            align,
            "--save-results",
            str(f),
        ]
        assert main(argv) == 0
        files.append(str(f))
    capsys.readouterr()
    assert main(["compare-results", *files, "--plot", str(tmp_path / "p"), "--names", "A,B"]) == 0
    out = capsys.readouterr().out
    assert "note: they differ in align: A se3, B sim3" in out
    assert "ape_trans_m [m]" in out and "\nA " in out and "\nB " in out
    assert len(list((tmp_path / "p").glob("results_*.png"))) == 4
    assert main(["compare-results", *files, "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["differences"] == {"align": ["se3", "sim3"]}
    assert set(d["metrics"]["rpe_rot_deg"]) == {"se3", "sim3"}
    # refusals: statistics-only JSON, not JSON, names that do not fit
    (tmp_path / "stats.json").write_text(
        json.dumps(json.loads(Path(files[0]).read_text()) | {"arrays": None})
    )
    (tmp_path / "junk.json").write_text("{not json")
    for argv, what in (
        (["compare-results", str(tmp_path / "stats.json")], "statistics only"),
        (["compare-results", str(tmp_path / "junk.json")], "not JSON"),
        (["compare-results", *files, "--names", "A"], "--names needs 2"),
        (["compare-results", str(tmp_path / "none.json")], "No such file"),
    ):
        assert main(argv) == 1
        assert what in capsys.readouterr().err


def test_no_common_metric_is_refused():
    ref, _ = read_stream(GT)
    est, _ = read_stream(SLAM)
    a = compare_trajectories(ref, est, t_max_diff=0.02, pose_relations=("full",))
    b = compare_trajectories(ref, est, t_max_diff=0.02, pose_relations=("rot_part",))
    with pytest.raises(InputError, match="no metric in common"):
        compare_results([a, b])
    c = compare_results(
        [a, compare_trajectories(ref, est, t_max_diff=0.02, pose_relations=("full", "angle_rad"))]
    )
    assert c.metrics == ("ape_full", "rpe_full") and "ape_rot_rad" in c.missing


@pytest.mark.parametrize(
    "flags,message",
    [
        (["-s", "--align", "origin"], "-s/--correct-scale goes with"),
        (["--n-to-align", "10"], "n_to_align needs align"),
        (["--delta-tol", "0.2"], "--delta-tol applies to --all-pairs"),
        (["--delta", "2.5"], "integer >= 1"),
        (["--delta", "200", "--delta-unit", "d"], "at most 180 deg"),
        (["--downsample", "0"], "downsample needs"),
        (["--motion-filter", "-1", "5"], "motion filter distance"),
        (["--motion-filter", "0.1", "nan"], "motion filter angle"),
        ([str(SLAM)], "give --merge"),
        ([str(SLAM), "--merge"], "same time"),
    ],
)
def test_cli_refuses_bad_values(flags, message, capsys):
    files = [f for f in flags if not f.startswith("-") and f.endswith(".txt")]
    flags = [f for f in flags if f not in files]
    assert main(["compare", str(GT), str(SLAM), *files, "--t-max-diff", "0.02", *flags]) == 1
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_pose_relation_names_are_checked_by_the_parser(capsys):
    with pytest.raises(SystemExit) as e:
        main(["compare", str(GT), str(SLAM), "--pose-relation", "trans_part,translation"])
    assert e.value.code == 2 and "pose relations must be some of" in capsys.readouterr().err


def test_transform_files(tmp_path):
    ok = {"m.json": [[0, -1, 0, 1], [1, 0, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]],
          "w.json": {"matrix": np.eye(4).tolist()},
          "c.json": {"X": {"position": [0, 0, 0.1], "quaternion": [0, 0, 0, 2]}}}  # fmt: skip
    for name, body in ok.items():
        (tmp_path / name).write_text(json.dumps(body))
    m = load_transform(tmp_path / "m.json")
    assert np.allclose(m.position, [1, 2, 3]) and np.allclose(m.quaternion[2], np.sqrt(0.5))
    assert np.allclose(load_transform(f"{tmp_path / 'c.json'}#X").quaternion, [0, 0, 0, 1])
    bad = {
        "reflect.json": ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]], "reflection"),
        "shape.json": ([[1, 0, 0], [0, 1, 0], [0, 0, 1]], "4x4"),
        "row.json": ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [1, 0, 0, 1]], "last row"),
        "scaled.json": ((2 * np.eye(4)).tolist(), "not a rotation"),
    }
    for name, (body, what) in bad.items():
        (tmp_path / name).write_text(json.dumps(body))
        with pytest.raises(ConfigError, match=what) as e:
            load_transform(tmp_path / name)
        assert name in str(e.value)
    (tmp_path / "junk.json").write_text("[1, 2")
    with pytest.raises(ConfigError, match="not JSON"):
        load_transform(tmp_path / "junk.json")
    with pytest.raises(ConfigError, match="no entry 'Z'"):
        load_transform(f"{tmp_path / 'c.json'}#Z")


def test_plot_traj_processing(tmp_path, capsys):
    out = str(tmp_path / "t.png")
    (tmp_path / "l.json").write_text(json.dumps(np.eye(4).tolist()))
    argv = [
        "plot-traj",
        str(SLAM),
        "--ref",
        str(GT),
        "--sync",
        "--t-max-diff",
        "0.02",
        "--transform-left",
        str(tmp_path / "l.json"),
        "--downsample",
        "200",
        "--full-check",
        "--out",
        out,
    ]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert f"full check of {GT}: valid" in text and "path_length_m" in text
    assert Path(out).read_bytes()[:4] == b"\x89PNG"
    for argv, what in (
        (["plot-traj", str(SLAM), "--sync", "--out", out], "give --ref"),
        (["plot-traj", str(SLAM), "--t-offset", "0.1", "--out", out], "apply to --sync"),
        (["plot-traj", str(SLAM), str(SLAM), "--merge", "--out", out], "same time"),
    ):
        assert main(argv) == 1
        assert what in capsys.readouterr().err


@pytest.mark.skipif(not numba_available(), reason="numba is not installed")
def test_pair_kernels_agree_on_both_backends():
    rng = np.random.default_rng(4)
    p = np.cumsum(rng.normal(0, 0.01, (400, 3)), axis=0)
    q = np.cumsum(rng.normal(0, 0.05, (400, 4)), axis=0) + [0, 0, 0, 3.0]
    q /= np.linalg.norm(q, axis=1)[:, None]
    out = {}
    for backend in ("numpy", "numba"):
        with use_backend(backend):
            out[backend] = [
                *(
                    rpe_pairs(p, q, d, u, all_pairs=a)
                    for d, u in ((0.05, "m"), (4, "d"))
                    for a in (False, True)
                ),
                motion_filter_ids(p, q, 0.02, 3.0),
            ]
    for a, b in zip(out["numpy"], out["numba"], strict=True):
        for x, y in zip(a if isinstance(a, tuple) else (a,), b if isinstance(b, tuple) else (b,)):
            assert np.array_equal(x, y)
