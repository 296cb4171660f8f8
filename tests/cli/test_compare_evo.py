"""``trackflow compare``'s options against evo 1.3x, run as a library (issue 30, "evo's reach").

Every figure (per-pair errors and the six statistics) must equal evo's to 1e-6 on the TUM
RGB-D ``freiburg1_xyz`` ground truth and RGBD-SLAM estimate: alignments (``-s`` scale only,
``--n-to-align``), every ``--pose-relation``, ``--delta-unit`` f/m/d/r with and without
``--all-pairs``, and the processing options (``--downsample``, ``--motion-filter``,
``--transform-left/right``, ``--merge``, ``--full-check``'s figures, ``plot-traj --sync``).
evo is a dev extra, never a runtime dependency: these tests skip without it.
"""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from trackflow.cli.main import main
from trackflow.evaluation import check_stream, compare_trajectories, sync_streams
from trackflow.io import read_stream
from trackflow.math import Pose

evo = pytest.importorskip("evo", reason="evo (bench/dev extra) is the reference implementation")
from evo.core import metrics, sync  # noqa: E402
from evo.core import trajectory as evo_trajectory  # noqa: E402
from evo.tools import file_interface  # noqa: E402

STATS = ("rmse", "mean", "median", "std", "min", "max")
RELATIONS = {
    "full": metrics.PoseRelation.full_transformation,
    "trans_part": metrics.PoseRelation.translation_part,
    "rot_part": metrics.PoseRelation.rotation_part,
    "angle_deg": metrics.PoseRelation.rotation_angle_deg,
    "angle_rad": metrics.PoseRelation.rotation_angle_rad,
    "point_distance": metrics.PoseRelation.point_distance,
    "point_distance_error_ratio": metrics.PoseRelation.point_distance_error_ratio,
}
UNITS = {"f": metrics.Unit.frames, "m": metrics.Unit.meters, "d": metrics.Unit.degrees,
         "r": metrics.Unit.radians}  # fmt: skip


@pytest.fixture(scope="module")
def pair():
    """Paths of the TUM RGB-D pair; skips with the reason when the shared data is absent."""
    from conftest import shared_data_dir

    d = shared_data_dir() / "tum_rgbd"
    ref, est = d / "freiburg1_xyz-groundtruth.txt", d / "freiburg1_xyz-rgbdslam.txt"
    if not ref.is_file() or not est.is_file():
        pytest.skip(f"TUM RGB-D files not found in {d} (shared data; see its README.md)")
    return ref, est


@pytest.fixture(scope="module")
def loaded(pair):
    """``(ref, est)`` streams and ``(ref_e, est_e)`` evo trajectories of the pair, read once."""
    streams = tuple(read_stream(p)[0] for p in pair)
    return streams, tuple(file_interface.read_tum_trajectory_file(str(p)) for p in pair)


def _evo_metrics(
    ref_e,
    est_e,
    *,
    align="none",
    n=-1,
    relation="trans_part",
    delta=1,
    unit="f",
    all_pairs=False,
    tol=0.1,
    from_ref=False,
    offset=0.0,
    preprocess=None,
):
    """evo's APE and RPE (as evo_ape / evo_rpe compute them): {"ape": metric, "rpe": metric}."""
    ref_e, est_e = copy.deepcopy(ref_e), copy.deepcopy(est_e)
    if preprocess is not None:
        preprocess(ref_e, est_e)
    ref_e, est_e = sync.associate_trajectories(ref_e, est_e, max_diff=0.01, offset_2=offset)
    if align in ("se3", "sim3", "scale"):
        est_e.align(ref_e, correct_scale=align != "se3", correct_only_scale=align == "scale", n=n)
    elif align == "origin":
        est_e.align_origin(ref_e)
    out = {}
    if relation != "point_distance_error_ratio":
        out["ape"] = metrics.APE(RELATIONS[relation])
        out["ape"].process_data((ref_e, est_e))
    out["rpe"] = metrics.RPE(RELATIONS[relation], delta, UNITS[unit], tol, all_pairs, from_ref)
    out["rpe"].process_data((ref_e, est_e))
    return out


def _assert_agree(res, ev, relation="trans_part"):
    for kind, metric in ev.items():
        (series,) = [s for s in res.series.values() if s.kind == kind and s.relation == relation]
        assert series.error.shape == metric.error.shape, (kind, series.name)
        assert np.max(np.abs(series.error - metric.error)) < 1e-6, (kind, series.name)
        st = series.stats()
        for key in STATS:
            evo_value = metric.get_statistic(getattr(metrics.StatisticsType, key))
            assert abs(getattr(st, key) - evo_value) < 1e-6, (kind, series.name, key)


@pytest.mark.parametrize(
    "align,n", [("scale", None), ("scale", 50), ("se3", 3), ("se3", 100), ("sim3", 300)]
)
def test_alignments_agree_with_evo(loaded, align, n):
    (ref, est), (ref_e, est_e) = loaded
    res = compare_trajectories(ref, est, align=align, n_to_align=n)
    _assert_agree(res, _evo_metrics(ref_e, est_e, align=align, n=-1 if n is None else n))
    assert res.alignment["n_aligned"] == (len(res.t) if n is None else n)


@pytest.mark.parametrize("align", ["none", "sim3", "origin"])
def test_pose_relations_agree_with_evo(loaded, align):
    (ref, est), (ref_e, est_e) = loaded
    res = compare_trajectories(
        ref, est, align=align, pose_relations=tuple(RELATIONS), t_offset=0.005
    )
    for relation in RELATIONS:
        ev = _evo_metrics(ref_e, est_e, align=align, relation=relation, offset=0.005)
        _assert_agree(res, ev, relation)


@pytest.mark.parametrize(
    "delta,unit,all_pairs,extra",
    [
        (10, "f", False, {}),
        (7, "f", True, {}),
        (0.05, "m", False, {}),
        (0.1, "m", True, {}),
        (0.1, "m", True, {"delta_tol": 0.3, "pairs_from_reference": True}),
        (5, "d", False, {}),
        (3, "d", True, {}),
        (0.05, "r", False, {"pairs_from_reference": True}),
        (0.1, "r", True, {"delta_tol": 0.05}),
    ],
)
def test_delta_units_agree_with_evo(loaded, delta, unit, all_pairs, extra):
    (ref, est), (ref_e, est_e) = loaded
    res = compare_trajectories(
        ref, est, align="se3", delta=delta, delta_unit=unit, all_pairs=all_pairs, **extra
    )
    ev = _evo_metrics(
        ref_e,
        est_e,
        align="se3",
        delta=delta,
        unit=unit,
        all_pairs=all_pairs,
        tol=extra.get("delta_tol", 0.1),
        from_ref=extra.get("pairs_from_reference", False),
    )
    _assert_agree(res, {"rpe": ev["rpe"]})  # the same pairs: the same errors, in order
    assert len(res.rpe_t) == len(ev["rpe"].delta_ids)


def _printed(out: str, name: str) -> list[float]:
    (line,) = [r for r in out.splitlines() if r.startswith(name + " ")]
    return [float(v) for v in line.split()[1:]]


def test_cli_prints_evos_figures_to_six_decimals(pair, loaded, capsys):
    """The table on standard output: every printed figure equals evo's rounded to 6 decimals."""
    argv = [
        "compare",
        *map(str, pair),
        "-s",
        "--n-to-align",
        "200",
        "--pose-relation",
        "full,angle_rad,point_distance_error_ratio",
        "--delta",
        "0.2",
        "--delta-unit",
        "m",
        "--all-pairs",
        "--delta-tol",
        "0.2",
    ]
    assert main(argv) == 0
    out = capsys.readouterr().out
    ref_e, est_e = loaded[1]
    for rel, names in (
        ("full", ("ape_full", "rpe_full")),
        ("angle_rad", ("ape_rot_rad", "rpe_rot_rad")),
        ("point_distance_error_ratio", (None, "rpe_dist_ratio_pct")),
    ):
        ev = _evo_metrics(
            ref_e,
            est_e,
            align="scale",
            n=200,
            relation=rel,
            delta=0.2,
            unit="m",
            all_pairs=True,
            tol=0.2,
        )
        for name, kind in zip(names, ("ape", "rpe")):
            if name is None:
                continue
            want = [
                round(ev[kind].get_statistic(getattr(metrics.StatisticsType, k)), 6) for k in STATS
            ]
            assert _printed(out, name) == pytest.approx(want, abs=1.1e-6)


def _est_transformed(est_e, left, right):
    est_e.transform(left.as_matrix())
    est_e.transform(right.as_matrix(), right_mul=True)


def test_processing_options_agree_with_evo(pair, loaded, tmp_path, capsys):
    """--downsample and --motion-filter (both inputs, before the association, as evo_ape),
    --transform-left/right (the estimate, as evo_traj) and --merge (evo's merge)."""
    ref_path, est_path = pair
    ref_e, est_e = loaded[1]
    left = Pose([0.3, -0.2, 0.1], [0.1, 0.2, -0.1, 0.97], normalize=True)
    right = Pose([0.0, 0.05, -0.02], [0.0, 0.1, 0.0, 0.995], normalize=True)
    (tmp_path / "left.json").write_text(json.dumps(left.as_matrix().tolist()))
    (tmp_path / "calib.json").write_text(
        json.dumps(
            {"X": {"position": right.position.tolist(), "quaternion": right.quaternion.tolist()}}
        )
    )
    lines = est_path.read_text().splitlines()
    data = [x for x in lines if x and not x.startswith("#")]
    (tmp_path / "a.txt").write_text("\n".join(data[::2]) + "\n")
    (tmp_path / "b.txt").write_text("\n".join(data[1::2]) + "\n")

    def both(fn):
        def pre(r, e):
            fn(r)
            fn(e)

        return pre

    cases = [
        (["--downsample", "700"], both(lambda t: t.downsample(700))),
        (["--motion-filter", "0.01", "1.5"], both(lambda t: t.motion_filter(0.01, 1.5, True))),
        (
            [
                "--transform-left",
                str(tmp_path / "left.json"),
                "--transform-right",
                f"{tmp_path / 'calib.json'}#X",
            ],
            lambda r, e: _est_transformed(e, left, right),
        ),
    ]
    for flags, pre in cases:
        save = tmp_path / "r.json"
        argv = [
            "compare",
            str(ref_path),
            str(est_path),
            "--align",
            "none",
            "--pose-relation",
            "trans_part,angle_deg",
            "--save-results",
            str(save),
            "--force",
            *flags,
        ]
        assert main(argv) == 0, flags
        d = json.loads(save.read_text())
        for rel, name in (("trans_part", "trans_m"), ("angle_deg", "rot_deg")):
            ev = _evo_metrics(ref_e, est_e, relation=rel, preprocess=pre)
            for kind in ("ape", "rpe"):
                ours = np.asarray(d["arrays"][f"{kind}_{name}"])
                assert ours.shape == ev[kind].error.shape, (flags, kind)
                assert np.max(np.abs(ours - ev[kind].error)) < 1e-6, (flags, kind, rel)
    # merge: two halves of the estimate are the estimate
    merged = evo_trajectory.merge(
        [file_interface.read_tum_trajectory_file(str(tmp_path / f)) for f in ("a.txt", "b.txt")]
    )
    ev = _evo_metrics(ref_e, merged, align="se3")
    save = tmp_path / "m.json"
    argv = [
        "compare",
        str(ref_path),
        str(tmp_path / "a.txt"),
        str(tmp_path / "b.txt"),
        "--merge",
        "--align",
        "se3",
        "--save-results",
        str(save),
        "--force",
    ]
    assert main(argv) == 0
    d = json.loads(save.read_text())
    assert np.max(np.abs(np.asarray(d["arrays"]["ape_trans_m"]) - ev["ape"].error)) < 1e-6
    assert np.max(np.abs(np.asarray(d["arrays"]["rpe_trans_m"]) - ev["rpe"].error)) < 1e-6
    capsys.readouterr()


def test_full_check_figures_agree_with_evo(pair):
    """evo_traj --full_check's infos and stats; times are exact here (integer nanoseconds),
    evo's float seconds since 1970 resolve 0.24 us, so speeds agree to that (relative 1e-4)."""
    for path in pair:
        stream, report = read_stream(path)
        c = check_stream(stream, report)
        traj = file_interface.read_tum_trajectory_file(str(path))
        infos, stats = traj.get_infos(), traj.get_statistics()
        valid, details = traj.check()
        assert c["valid"]
        if not valid:  # evo: |q| within 1e-5; trackflow: within the rounding of the digits
            assert [k for k, v in details.items() if "invalid" in v] == ["quaternions"]
            assert any("normalised" in v for v in c["checks"].values())
        assert c["samples"] == infos["nr. of poses"]
        assert abs(c["path_length_m"] - infos["path length (m)"]) < 1e-6
        assert abs(c["duration_s"] - infos["duration (s)"]) < 1e-6
        assert abs(c["t_start_s"] - infos["t_start (s)"]) < 1e-6
        assert np.allclose(c["position_start_m"], infos["pos_start (m)"], atol=1e-12)
        assert np.allclose(c["position_end_m"], infos["pos_end (m)"], atol=1e-12)
        for ours, theirs in (("max", "max"), ("min", "min"), ("mean", "avg")):
            assert abs(c["dt_s"][ours] - stats[f"dt_{theirs} (s)"]) < 1e-6
            v = stats[f"v_{theirs} (m/s)"]
            assert abs(c["speed_m_s"][ours] - v) <= 1e-4 * v


def test_sync_agrees_with_evo(loaded):
    (ref, est), (ref_e, est_e) = loaded
    for offset in (0.0, -0.012):
        r, e = sync_streams(ref, est, 0.01, offset)
        r_e, e_e = sync.associate_trajectories(ref_e, est_e, max_diff=0.01, offset_2=offset)
        # evo repeats a sample paired twice; a stream holds it once
        assert np.allclose(r.t_ns * 1e-9, np.unique(r_e.timestamps), atol=1e-6, rtol=0)
        assert np.allclose(e.t_ns * 1e-9, np.unique(e_e.timestamps), atol=1e-6, rtol=0)
