"""What tests/test_readme.py and tests/test_doc_pages.py do with each documented command
(tests/_doc_commands.py finds them): the tables RUN, SERVED, SCRIPTS, SYNOPSES and EXEMPT, and
the checks of the commands that run.

Every documented command is in exactly one table: RUN (run as written, then checked: against
the output the doc quotes after it, and/or by its check here, which compares with the figures
the docs state), SERVED (a page served until Ctrl-C: started as written, its page fetched,
then interrupted), SCRIPTS (consecutive commands that work only together: one script),
SYNOPSES (a usage line with placeholders: every option and choice it names is
in the command's --help), EXEMPT (cannot run in a test, with the reason and the test that
covers it).
"""

from __future__ import annotations

import contextlib
import json
import re
import socket
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import yaml

import _doc_inputs as inputs
from _doc_commands import (
    DocCommand,
    Ran,
    assert_as_documented,
    block_before,
    doc_states,
    documented_commands,
    half_ulp,
    quoted_output_mismatch,
    run_command,
)
from conftest import REPO_ROOT, shared_data_dir

# -- checks of what a command printed or wrote -------------------------------------------------


def _json(r: Ran, name: str | None = None) -> dict:
    return json.loads((r.cwd / name).read_text() if name else r.stdout)


def _rows(path: Path) -> list[str]:
    return [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]


def check_info_room1(r: Ran) -> None:
    """The sample count and duration are the file's (counted here, not by trackflow)."""
    rows = _rows(shared_data_dir() / "tumvi" / "dataset-room1_512_16.txt")
    info = dict(ln.split(None, 1) for ln in r.stdout.splitlines() if ln.strip())
    assert int(info["samples"]) == len(rows)
    duration = float(rows[-1].split()[0]) - float(rows[0].split()[0])
    assert abs(float(info["duration_s"]) - duration) < 1e-3


def _evaluate_table(text: str, section: str) -> dict[str, list[str]]:
    """The rms columns per predictor (10, 20, 50, 100, 200 ms) of one section of the table."""
    block = text.split(section, 1)[1].split("\n\n", 1)[0]
    rows = {}
    for ln in block.splitlines()[2:]:
        name, *values = ln.split()
        rows[name] = values[1::2]
    return rows


def ratio_matches(num: str, den: str, stated: str) -> bool:
    """num/den of printed values covers the stated ratio, each within its printed rounding."""
    a, b, s = float(num), float(den), float(stated)
    ha, hb, hs = half_ulp(num), half_ulp(den), half_ulp(stated)
    lo, hi = (a - ha) / (b + hb), (a + ha) / (b - hb)
    return lo <= s + hs and s - hs <= hi


def check_evaluate_ar_table_01(r: Ran) -> None:
    """Kalman / linear RMS at 50 and 100 ms as docs/posetool.md's table states for ar_table 01."""
    stated = doc_states(
        "docs/posetool.md",
        r"\| ar_table 01 \| (\S+) \| (\S+) \| (\S+) \| (\S+) \| \S+ \| (\d+) \|",
    )
    pos = _evaluate_table(r.stdout, "position error (mm)")
    ori = _evaluate_table(r.stdout, "orientation error (deg)")
    got = [(pos, 2), (ori, 2), (pos, 3), (ori, 3)]
    for (table, k), s in zip(got, stated[:4], strict=True):
        assert ratio_matches(table["kalman"][k], table["linear"][k], s), (table, k, s)
    n_50 = re.search(r"50 ms: (\d+)", r.stdout).group(1)
    assert n_50 == stated[4]


def check_plan_p_to_m(r: Ran) -> None:
    """The path joins P to M through every sensor and static of the setup, each once."""
    setup = yaml.safe_load((r.cwd / "examples" / "demo_setup.yaml").read_text())
    edges = setup["sensors"] + setup["statics"]
    path = re.search(r"path 1 \(score [^)]*\): (.*)", r.stdout).group(1)
    (into_m,) = [e["name"] for e in edges if e["target"] == "M"]
    assert path.startswith("P->") and path.endswith(f"M[{into_m}]")
    for edge in edges:
        assert path.count(f"[{edge['name']}]") == 1, (edge["name"], path)
        assert f"  {'src_' if edge in setup['sensors'] else 'static_'}{edge['name']}:" in r.stdout


def _quoted_by(doc: str, needle: str) -> str:
    (cmd,) = [c for c in documented_commands() if c.doc == doc and needle in c.text]
    return cmd.expected


def check_readme_compare(r: Ran) -> None:
    """The README's compare prints the table docs/cli.md quotes for the same comparison."""
    quoted = _quoted_by("docs/cli.md", "--align se3 --plot docs/cli").splitlines()
    table = "\n".join(ln for ln in quoted if not ln.endswith(".png"))  # the plots' names
    miss = quoted_output_mismatch(table, r.stdout)
    assert miss is None, f"{miss}\n{r.describe()}"


def check_quest_links(r: Ran) -> None:
    for name in ("robot_tcp_calib.tum.txt", "calib.txt", "robot_tcp_traj1.tum.txt", "traj1.txt"):
        assert (r.cwd / name).is_file() and _rows(r.cwd / name)


CALIB = "docs/calibration.md"


def check_hand_eye_calib(r: Ran) -> None:
    """The keys calibration.md lists, and its figures of the default form on `calib`."""
    d = _json(r, "calib.json")
    keys = doc_states(CALIB, r"`hand-eye --json` prints exactly `\{([^}]*)\}`")[0]
    assert set(d) == set(re.findall(r'"(\w+)"', keys))
    offset = doc_states(CALIB, r"\| offset `t_robot = t_quest \+ offset` \| (\S+) \+- (\S+) ms \|")
    assert_as_documented(offset[:1], [d["offset_s"] * 1e3], "offset [ms]")
    x = doc_states(CALIB, r"\| X = T_tool_headset \[mm\] \| \((\S+), (\S+), (\S+)\) \|")
    assert_as_documented(x, np.array(d["X"]["position"]) * 1e3, "X [mm]")
    sig = doc_states(CALIB, r"\| `X_sigma_mm`, `X_sigma_deg` \| (\S+), (\S+) \|")
    assert_as_documented(sig, [d["X_sigma_mm"], d["X_sigma_deg"]], "X sigma")


def check_use_on_traj1(r: Ran) -> None:
    """`calib` as stored, on `traj1`: the residuals of calibration.md's reuse table."""
    d = _json(r)
    every = doc_states(
        CALIB,
        r"over every sample \(`--use` of each result\) \|[^|]*\|[^|]*\|"
        r"[^|]*\| (\S+) mm, (\S+) deg \|",
    )
    pairs = doc_states(
        CALIB,
        r"\| `pair_residual_\*` \(motion pairs\) \|[^|]*\|[^|]*\|"
        r"[^|]*\| (\S+) mm, (\S+) deg \|",
    )
    assert_as_documented(every, [d["residual_pos_mm"], d["residual_ori_deg"]], "residual")
    assert_as_documented(pairs, [d["pair_residual_pos_mm"], d["pair_residual_ori_deg"]], "pairs")


def _check_refit(d: dict, calib: dict) -> None:
    offset = doc_states(
        CALIB,
        r"\| offset `t_robot = t_quest \+ offset` \| \S+ \+- \S+ ms \| "
        r"(\S+) \+- \S+ ms \| \S+ ms apart",
    )
    assert_as_documented(offset, [d["offset_s"] * 1e3], "refitted offset [ms]")
    res = doc_states(
        CALIB,
        r"\| `residual_\*` \(`A X = Z B`, solvers' inliers\) \|[^|]*\| "
        r"(\S+) mm, (\S+) deg \(",
    )
    assert_as_documented(res, [d["residual_pos_mm"], d["residual_ori_deg"]], "residual")
    pairs = doc_states(
        CALIB,
        r"\| `pair_residual_\*` \(motion pairs\) \|[^|]*\| "
        r"(\S+) mm, (\S+) deg \(",
    )
    assert_as_documented(pairs, [d["pair_residual_pos_mm"], d["pair_residual_ori_deg"]], "pairs")
    assert d["X"] == calib["X"]  # X kept as stored, its covariance too


def check_refit_with_fragment(r: Ran) -> None:
    _check_refit(_json(r, "traj1_session.json"), _json(r, "calib.json"))
    frag = yaml.safe_load((r.cwd / "traj1_session.yaml").read_text())
    (x,) = [s for s in frag["statics"] if s["name"] == "hand_eye_X"]
    assert x["position"] == _json(r, "calib.json")["X"]["position"]


def check_refit(r: Ran) -> None:
    _check_refit(_json(r, "traj1_session.json"), _json(r, "calib.json"))


def check_clock_offset_calib(r: Ran) -> None:
    """The rate-based offset of calibration.md's window table (200 ms, the default)."""
    stated = doc_states(CALIB, r"\| `calib` offset \[ms\] \|[^|]*\|[^|]*\|[^|]*\| \*\*(\S+)\*\* \|")
    offset = float(re.search(r"^offset_s\s+(\S+)", r.stdout, re.M).group(1))
    assert_as_documented(stated, [offset * 1e3], "offset [ms]")
    report = _json(r, "out/report.json")
    assert (
        abs(report["offset_s"] - offset) < 1e-12 and (r.cwd / "out" / "correlation.png").is_file()
    )


def check_noise_calib(r: Ran) -> None:
    """Static noise of the headset as calibration.md's noise table states, and its fragment."""
    stated = doc_states(
        CALIB,
        r"\| Quest 2 \(`calib.txt`\) \| static \| (\S+), (\S+), (\S+) \| (\S+), (\S+), (\S+) \|",
    )
    out = dict(ln.split(None, 1) for ln in r.stdout.splitlines() if ln.strip())
    got = json.loads(out["sigma_pos_mm"]) + json.loads(out["sigma_ori_deg"])
    assert_as_documented(stated, got, "sigma")
    (sensor,) = yaml.safe_load((r.cwd / "quest_noise.yaml").read_text())["sensors"]
    assert sensor["name"] == "quest"
    assert np.allclose(np.sqrt(np.diag(sensor["covariance"]))[:3] * 1e3, got[:3])


def check_tune(r: Ran) -> None:
    """The model file holds the tuned predictor it printed, of one of the families named."""
    from trackflow.evaluation import load_model

    printed = json.loads(r.stdout)["motion_model"]["family"]
    assert printed in {"derivative", "twist_ar", "partwise"}  # twist_ar: the learned model
    assert _json(r, "model.json")["predictor"]["family"] == printed
    load_model(r.cwd / "model.json")


def _summary_shape(line: str) -> str:
    line = re.sub(r"\(\w+ model\)", "(MODEL model)", line)
    return re.sub(r"#(?:, #)+", "#", re.sub(r"\d+(?:\.\d+)?", "#", line))


def _check_filter_summary(r: Ran, out: str) -> None:
    """The summary has the shape of the one docs/cli.md quotes, counts rec.txt's rows, and its
    mean NIS lies in the band it names; the output holds every sample, with covariances."""
    from trackflow.io import read_stream

    text = (REPO_ROOT / "docs" / "cli.md").read_text().splitlines()
    quoted = next(ln for ln in text if ln.startswith("filtered "))
    (line,) = [ln for ln in r.stderr.splitlines() if ln.startswith("filtered ")]
    assert _summary_shape(line) == _summary_shape(quoted), (line, quoted)
    n = int(re.search(r"filtered (\d+) samples", line).group(1))
    nis, lo, hi = map(
        float,
        re.search(r"NIS ([\d.]+) \(inside the 99 % band ([\d.]+)\.\.([\d.]+)\)", line).groups(),
    )
    assert n == len(_rows(r.cwd / "rec.txt")) and lo <= nis <= hi
    stream, _ = read_stream(r.cwd / out)
    assert len(stream) == n and stream.covariance is not None


def check_filter_with_model(r: Ran) -> None:
    _check_filter_summary(r, "out.tfrec")


def check_filter_tuning_first(r: Ran) -> None:
    _check_filter_summary(r, "tuned.tfrec")


def _inertial_table(recording: str) -> dict[str, list[str]]:
    """docs/inertial.md's rows of one recording (none, kalman, kalman_imu) as printed:
    position and orientation RMS 50 ms ahead, then 10 ms ahead."""
    fig = r"\**([\d.]+)\**(?: \([\d.]+x\))?"
    row = r" \| ".join([fig] * 4)
    stated = doc_states(
        "docs/inertial.md",
        rf"\| {re.escape(recording)} \| none \(hold\) \| {row} \| "
        rf"\| \| kalman[^|]* \| {row} \| \| \| kalman_imu \| {row} \|",
    )
    return {"none": stated[:4], "kalman": stated[4:8], "kalman_imu": stated[8:]}


def _scored_origins(recording: str) -> int:
    """The origins scored 50 ms ahead that docs/inertial.md states for a recording."""
    return int("".join(doc_states("docs/inertial.md", rf"{recording} (\d+) (\d+)")))


def check_evaluate_imu_broad_fast_rotation(r: Ran) -> None:
    """The table of docs/inertial.md for BROAD fast rotation at 60 Hz, anytime origins: the
    three predictors' RMS 50 and 10 ms ahead (both printed rounded: equal within both
    roundings), and the origins scored."""
    pos = _evaluate_table(r.stdout, "position error (mm)")
    ori = _evaluate_table(r.stdout, "orientation error (deg)")
    for name, stated in _inertial_table("BROAD fast rotation (60 Hz), anytime").items():
        printed = [pos[name][2], ori[name][2], pos[name][0], ori[name][0]]
        for s, p in zip(stated, printed, strict=True):
            slack = (half_ulp(s) + half_ulp(p)) * (1 + 1e-9)
            assert abs(float(s) - float(p)) <= slack, (name, stated, printed)
    assert f"50 ms: {_scored_origins('Scored origins at 50 ms: BROAD')}," in r.stdout


def check_evaluate_imu_euroc(r: Ran) -> None:
    """The table of docs/inertial.md for EuRoC V1_01 at 20 Hz, anytime origins, from the JSON:
    the three predictors' RMS 50 and 10 ms ahead, and the origins scored."""
    predictors = _json(r)["predictors"]
    for name, stated in _inertial_table("EuRoC V1_01 (20 Hz), anytime").items():
        p50, p10 = predictors[name]["50"], predictors[name]["10"]
        got = [p50["pos_rms_mm"], p50["ori_rms_deg"], p10["pos_rms_mm"], p10["ori_rms_deg"]]
        assert_as_documented(stated, got, f"EuRoC {name}")
    assert predictors["kalman_imu"]["50"]["n"] == _scored_origins(r"\(poses\); EuRoC")


def check_lists_demo_realm_and_prints_the_docs_commands(r: Ran) -> None:
    """The files the agents need, and the start commands exactly as docs/distributed.md's
    block goes on (so the doc's commands are the ones the demo prints)."""
    names = {"app.yaml", "art.tfrec", "artoolkit.tfrec", "camera.yaml", "tracker.yaml"}
    assert {p.name for p in (r.cwd / "demo_realm").iterdir()} == names
    cmds = documented_commands()
    k = next(i for i, c in enumerate(cmds) if c.key == r.command.key)
    rest = [c.key for c in cmds[k + 1 : k + 6]]
    assert list(rest) == list(SCRIPTS["the demo realm"].keys)
    printed = [" ".join(ln.split()) for ln in r.stdout.splitlines()]
    for line in rest:
        assert line in printed, (line, printed)


def check_realm_init(r: Ran) -> None:
    """A CA, a certificate and key and a Zenoh file per agent and observer; each agent listens
    on the endpoint given for it, over TLS."""
    realm = r.cwd / "realm"
    for name in ("ca", "tracker", "camera", "app", "monitor"):
        assert (realm / f"{name}.pem").read_text().startswith("-----BEGIN CERTIFICATE-----")
        assert (realm / f"{name}.key").is_file()
    for name, host in (("tracker", 11), ("camera", 12), ("app", 13)):
        assert f"tls/192.168.10.{host}:7447" in (realm / f"{name}.json5").read_text()
    assert (realm / "monitor.json5").is_file()


def check_plan_default_query(r: Ran) -> None:
    """Without --from/--to the setup's first query is planned, as its YAML declares it."""
    (q, *_) = yaml.safe_load((r.cwd / "examples" / "demo_setup.yaml").read_text())["queries"]
    assert f"query {q['name']}: T_{q['source']}_{q['target']}, {q['mode']} delivery" in r.stdout
    assert f"at {q['rate_hz']} Hz" in r.stdout


def check_plan_dot(r: Ran) -> None:
    """The DOT file draws every component the explanation lists, inversion included."""
    dot = (r.cwd / "plan.dot").read_text()
    assert dot.lstrip().startswith("digraph")
    names = re.findall(r"^  (\w+): ", r.stdout, re.M)
    assert "inv_inference_path" in names
    for name in names:
        assert name in dot, name


def check_optical(r: Ran) -> None:
    """The answers it counts are the ones it wrote, with covariances; every frame reached each
    sensor, which passed it on or counted why not."""
    from trackflow.io import read_stream

    d = _json(r)
    stream, _ = read_stream(r.cwd / "out" / "wand_in_tool.tfrec")
    assert len(stream) == d["results"] > 0 and stream.covariance is not None
    for name, sensor in d["sensors"].items():
        assert sensor["events_in"] == d["frames"], name
        assert sensor["events_out"] + sum(sensor["rejections"].values()) == d["frames"], name


def check_optical_record(r: Ran) -> None:
    from trackflow.io import read_stream

    stream, _ = read_stream(r.cwd / "out" / "optical.tfrec")
    assert len(stream) > 0 and stream.covariance is not None


def check_replay_bit_for_bit(r: Ran) -> None:
    """Every recorded answer again, identical (the exit code says so too)."""
    out = dict(ln.split(": ", 1) for ln in r.stdout.splitlines() if ln.strip())
    assert out["identical"] == "True"
    assert int(out["answers"]) == int(out["recorded"]) > 0


@dataclass(frozen=True)
class Run:
    """How a documented command is run: inputs made first, then its checks."""

    check: Callable[[Ran], None] | None = None  # None: the output the doc quotes is the check
    prepare: Callable[[Path], None] | None = None


#: Run as written, in this order per page (a page's commands share one working directory;
#: a command repeated verbatim on a page runs once). ``Run()``: the output the doc quotes
#: after the command is its check.
RUN: dict[str, Run] = {
    # README.md
    ".venv/bin/trackflow info ../shared/data/tumvi/dataset-room1_512_16.txt": Run(check_info_room1),
    ".venv/bin/trackflow evaluate ../shared/data/ar_table/table_01.txt --tune-fraction 0.5": Run(
        check_evaluate_ar_table_01
    ),
    ".venv/bin/trackflow plan examples/demo_setup.yaml --from P --to M --explain": Run(
        check_plan_p_to_m
    ),
    ".venv/bin/trackflow compare ../shared/data/tum_rgbd/freiburg1_xyz-groundtruth.txt "
    "../shared/data/tum_rgbd/freiburg1_xyz-rgbdslam.txt --align se3": Run(check_readme_compare),
    # docs/calibration.md
    "ln -sf ../shared/data/quest_ur5e/quest2/* . # the Quest 2 / UR5e recordings, here": Run(
        check_quest_links
    ),
    "trackflow calibrate hand-eye robot_tcp_calib.tum.txt calib.txt --clean --json > calib.json": (
        Run(check_hand_eye_calib)
    ),
    "trackflow calibrate hand-eye robot_tcp_traj1.tum.txt traj1.txt --clean --use calib.json "
    "--json": Run(check_use_on_traj1),
    "trackflow calibrate hand-eye robot_tcp_traj1.tum.txt traj1.txt --clean --use calib.json "
    "--refit world --json --fragment traj1_session.yaml > traj1_session.json": Run(
        check_refit_with_fragment
    ),
    "trackflow calibrate clock-offset robot_tcp_calib.tum.txt calib.txt --clean --report out/": (
        Run(check_clock_offset_calib)
    ),
    "trackflow calibrate noise calib.txt --clean --fragment quest_noise.yaml --sensor-name quest": (
        Run(check_noise_calib)
    ),
    "trackflow calibrate hand-eye robot_tcp_traj1.tum.txt traj1.txt --clean --use calib.json "
    "--refit world --json > traj1_session.json # X from calib.json": Run(check_refit),
    # docs/cli.md
    "trackflow tune rec.txt --output model.json # any family: derivative, learned, partwise": Run(
        check_tune, inputs.recording_as_rec_txt
    ),
    "trackflow filter rec.txt out.tfrec --model model.json": Run(check_filter_with_model),
    "trackflow filter rec.txt tuned.tfrec # no model: tunes on the recording first": Run(
        check_filter_tuning_first
    ),
    "trackflow compare ../shared/data/tum_rgbd/freiburg1_xyz-groundtruth.txt "
    "../shared/data/tum_rgbd/freiburg1_xyz-rgbdslam.txt --align se3 --plot docs/cli --force": Run(),
    "trackflow compare ../shared/data/tum_rgbd/freiburg1_xyz-groundtruth.txt "
    "../shared/data/tum_rgbd/freiburg1_xyz-rgbdslam.txt -s --pose-relation "
    "full,rot_part,point_distance_error_ratio --delta 0.1 --delta-unit m --all-pairs": Run(),
    "trackflow compare-results se3.json sim3.json": Run(prepare=inputs.saved_comparisons),
    "trackflow lookup examples/lookup_setup.yaml --from P --to T --at 1305031100": Run(),
    # docs/dataflow.md
    "trackflow plan examples/demo_setup.yaml --explain": Run(check_plan_default_query),
    "trackflow plan examples/demo_setup.yaml --from M --to P --explain --dot plan.dot": Run(
        check_plan_dot
    ),
    # docs/distributed.md
    "trackflow demo --realm demo_realm": Run(check_lists_demo_realm_and_prints_the_docs_commands),
    "trackflow realm init tracker.yaml camera.yaml app.yaml --out realm/ --endpoint "
    "tracker=192.168.10.11:7447 --endpoint camera=192.168.10.12:7447 --endpoint "
    "app=192.168.10.13:7447 --observer monitor": Run(check_realm_init, inputs.agent_files),
    # docs/formats.md
    "trackflow convert fr1_xyz.txt out.mcap --to rosbag": Run(prepare=inputs.fr1_xyz_txt),
    "trackflow info robot_bag --source world --target gripper": Run(prepare=inputs.robot_bag),
    "trackflow info robot_bag --source world --target cam": Run(),
    # docs/optical.md
    "trackflow optical examples/optical.yaml --out out/wand_in_tool.tfrec": Run(check_optical),
    "trackflow run examples/optical_live.yaml --duration 5 --record out/optical.tfrec": Run(
        check_optical_record
    ),
    "trackflow run examples/optical_live.yaml --replay out/optical.tfrec # bit for bit": Run(
        check_replay_bit_for_bit
    ),
    # docs/inertial.md
    "trackflow evaluate ../shared/data/broad/06_undisturbed_fast_rotation_A.mat --imu "
    "../shared/data/broad/06_undisturbed_fast_rotation_A.mat --pose-rate 60 --origins anytime": (
        Run(check_evaluate_imu_broad_fast_rotation)
    ),
    "trackflow evaluate ../shared/data/euroc/V1_01_easy_groundtruth_200hz.txt --imu "
    "../shared/data/euroc/V1_01_easy_imu0.csv --pose-rate 20 --origins anytime --json": Run(
        check_evaluate_imu_euroc
    ),
}

#: Usage lines with placeholders (SETUP.yaml, RECORDING, [optional] parts, {choices}): every
#: option and choice they name must be in the command's --help.
SYNOPSES = {
    "trackflow run SETUP.yaml [--query Q] [--duration S] [--record out.tfrec] [--vrpn-port 3883]",
    "trackflow run SETUP.yaml --replay out.tfrec # exit 0 when bit for bit identical",
    "trackflow run SETUP.yaml --view [--view-port 8080] # the run in the browser (docs/viewer.md)",
    "trackflow simulate {natnet,dtrack,vrpn} RECORDING --port P [--latency-ms 5] "
    "[--clock-offset-s 0] [--drift-ppm 0] [--loss 0] [--jitter-ms 0] [--speed 1] [--start 0] "
    "[--duration S] [--bodies 1] [--natnet-version 4.1] [--multicast GROUP --data-port P] "
    "[--command-port P] [--truth truth.tfrec] [--outage A:B ...] [--freeze A:B ...] "
    "[--noise-mm 0] [--noise-deg 0] [--change T:latency_ms=30,noise_mm=2 ...]",
    "trackflow view RECORDING --snapshot out.png --at 12.5 [--offset-ms 100] [--sigma 2]",
    "trackflow view RECORDING --snapshot out.png --camera 0,-3,2.5 --look-at 0,0,1 --no-panel",
}

_BENCH = "a benchmark that writes the docs' figures"
_ROS2 = "the ROS 2 side: needs a ROS 2 installation, which this machine does not have"

#: Documented commands no test runs as written, each with the reason (and the test that
#: covers what it does).
EXEMPT = {
    "make demo # creates .venv, installs trackflow, runs the main job (trackflow demo)": (
        "creates .venv and installs into it, then the 60 s live demo; trackflow demo: "
        "tests/demo/test_demo.py, the live demo: tests/trackers/test_live_e2e.py"
    ),
    "make test # creates .venv, installs trackflow + dev tools, runs ruff and the test suite": (
        "runs this suite"
    ),
    "PYTHONPATH=src .venv/bin/python -m pytest -q tests/calibration -p no:xdist # ~2 min loaded": (
        "runs tests of this suite"
    ),
    "PYTHONPATH=src .venv/bin/python bench/calibration.py --json": (
        f"{_BENCH}: 53 s of CPU, 110 s at load 9; tests/calibration/test_quest_ur5e.py"
    ),
    "PYTHONPATH=src .venv/bin/python experiments/calibration_chapter9.py # figures + summary": (
        "remakes every figure of docs/calibration and its summary.json: minutes (its part "
        "bench/calibration.py alone takes 53 s of CPU); tests/calibration/"
    ),
    "ros2 bag info out # or: trackflow info out.mcap, out/ or out/out.mcap": (
        f"{_ROS2}; tests/io/test_rosbag_tf.py reads the bags back with rosbags"
    ),
    ".venv/bin/pip install -e '.[bench]' # imufusion and vqf (bench extra only)": (
        "installs packages"
    ),
    "PYTHONPATH=src .venv/bin/python bench/imu_orientation.py --plot docs/inertial_imu_only.png": (
        f"{_BENCH} (6.5 min, docs/inertial.md)"
    ),
    "PYTHONPATH=src .venv/bin/python bench/imu_orientation.py --json "
    "# ratios and per-trial RMSEs": (f"{_BENCH} (6.5 min, docs/inertial.md)"),
    "PYTHONPATH=src .venv/bin/python -m pytest -q tests/filters/test_inertial.py "
    "tests/filters/test_inertial_queries.py tests/io/test_imu.py "
    "tests/evaluation/test_inertial_evaluation.py tests/evaluation/test_shrinkage.py "
    "tests/dataflow/test_inertial_dataflow.py tests/filters/test_imu_orientation.py": (
        "runs tests of this suite"
    ),
    "PYTHONPATH=src .venv/bin/python bench/inertial.py --json # the issue's keys": (
        f"{_BENCH} (10-12 min, docs/inertial.md)"
    ),
    "PYTHONPATH=src .venv/bin/python bench/inertial.py --plot --out r.json "
    "# + both origins, figure": (f"{_BENCH} (10-12 min, docs/inertial.md)"),
    "PYTHONPATH=src .venv/bin/python bench/inertial.py --peers --out r.json # + IMU-only ratios": (
        f"{_BENCH} (10-12 min, docs/inertial.md)"
    ),
    "PYTHONPATH=src .venv/bin/python bench/imu_orientation.py --json "
    "# IMU-only vs vqf, imufusion": (f"{_BENCH} (6.5 min, docs/inertial.md)"),
    "python experiments/optical_pipeline.py # figures above, JSON on stdout (about 5 min)": (
        "about 5 min (docs/optical.md)"
    ),
    "python bench/optical.py [--json] # the speed goal": (
        "a speed benchmark (frames per second: no timing in tests); tests/optical/test_pipeline.py"
    ),
    "export RMW_IMPLEMENTATION=rmw_zenoh_cpp": _ROS2,
    "ros2 run rmw_zenoh_cpp rmw_zenohd # the Zenoh router, listening on tcp/[::]:7447": _ROS2,
    "ros2 run my_mocap_driver driver # publishes /mocap/head (geometry_msgs/PoseStamped)": _ROS2,
    "ros2 topic echo /trackflow/head # on the ROS 2 side": _ROS2,
}


def _demo_realm_files(repo: Path) -> None:
    """The demo realm's agent files, written by the command docs/distributed.md gives."""
    r = run_command(DocCommand("prepare", 0, "trackflow demo --realm demo_realm"), repo)
    assert r.returncode == 0, r.describe()


@contextlib.contextmanager
def _ros2_router(cmd: DocCommand, repo: Path):
    """The setup file the command names (the doc's yaml block before it) and a Zenoh router
    standing in for ``rmw_zenohd`` where trackflow looks for it by default,
    tcp/127.0.0.1:7447 (skipped when another process holds that port)."""
    pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (.[distributed])")
    pytest.importorskip("rosbags", reason="rosbags is not installed (.[ros])")
    with socket.socket() as probe:
        try:
            probe.bind(("127.0.0.1", 7447))
        except OSError:
            pytest.skip("tcp/127.0.0.1:7447, where the documented command connects, is taken")
    sys.path.insert(0, str(REPO_ROOT / "tests" / "ros2"))  # (when run without the ROS 2 tests)
    from _ros2live import Router

    (repo / "setup.yaml").write_text(block_before(cmd, "yaml"))
    router = Router(7447)
    try:
        yield
    finally:
        router.close()


@dataclass(frozen=True)
class Serve:
    """A documented command that serves until interrupted: inputs made first (``prepare``), a
    context around it (``around``: what it talks to); it is started as written, its page
    fetched (or, with ``ready``, a line matching that expression awaited), then stopped with
    Ctrl-C (``serve_command``)."""

    prepare: Callable[[Path], None] | None = None
    ready: str | None = None
    around: Callable[[DocCommand, Path], contextlib.AbstractContextManager] | None = None


#: Commands that serve until Ctrl-C: run as written (``serve_command``); each must print its
#: page's address and serve viser's page there (or print its ``ready`` line), and end on
#: Ctrl-C without a traceback.
SERVED: dict[str, Serve] = {
    # docs/ros2.md: the setup above it, reading and publishing ROS 2 topics through the router
    "trackflow run setup.yaml": Serve(ready=r"\bhead\b", around=_ros2_router),
    # README.md: the live network of the demo setup
    ".venv/bin/trackflow view examples/demo_setup.yaml # open http://127.0.0.1:8080": Serve(),
    # docs/viewer.md: the realm's page (read-only; with no agent running it shows none)
    "trackflow view --realm demo --connect tcp/127.0.0.1:7451 --connect tcp/127.0.0.1:7453": (
        Serve()
    ),
    # docs/viewer.md (the live demo's inputs wait for their trackers)
    "trackflow run examples/live_demo.yaml --view # live trackers, in the browser": Serve(),
    "trackflow view examples/demo_setup.yaml # live: the setup's network runs": Serve(),
    "trackflow view ../shared/data/tumvi/dataset-room1_512_16.txt # a recording, timeline": (
        Serve()
    ),
    "trackflow view ../shared/data/ar_table/table_01.txt --posetool # PoseTool page": Serve(),
    "trackflow view examples/fusion_setup.yaml --anchor A # draw the scene in frame A": Serve(),
    "trackflow view demo_realm/tracker.yaml demo_realm/camera.yaml demo_realm/app.yaml": Serve(
        _demo_realm_files
    ),
}


def check_the_demo_realm_answered(r: Ran) -> None:
    """The application agent ended by itself (its --duration) with the query answered over the
    tracker's and the camera's sensors: at least a second's worth of a 60 Hz query."""
    q = json.loads((r.cwd / "status.json").read_text())["queries"]["sheep"]
    assert q["state"] == "running", q
    assert any("art" in p and "artoolkit" in p for p in q["paths"]), q
    assert q["published"] >= 60, q


@dataclass(frozen=True)
class Script:
    """Consecutive commands of one block that work only together (a shell variable, background
    jobs): run as one bash script, as written and in the doc's order, then checked."""

    keys: tuple[str, ...]
    check: Callable[[Ran], None]
    prepare: Callable[[Path], None] | None = None


#: Run as one script each (tests/test_doc_scripts.py).
SCRIPTS: dict[str, Script] = {
    # docs/distributed.md: the three agents of `trackflow demo --realm demo_realm` (RUN above)
    "the demo realm": Script(
        (
            "start=$(( $(date +%s%N) + 5000000000 )) # recording time 0 on the agents' clock",
            "trackflow agent demo_realm/tracker.yaml --start-ns $start &",
            "trackflow agent demo_realm/camera.yaml --start-ns $start &",
            "trackflow agent demo_realm/app.yaml --duration 20 --status status.json",
            "kill %1 %2 # the tracker and camera agents run until stopped",
        ),
        check_the_demo_realm_answered,
        prepare=_demo_realm_files,
    ),
}


def run_page(doc: str, repo: Path) -> None:
    """Every RUN command of the page, in the page's order, in the workspace ``repo``: exit 0 (1
    where the doc quotes an error), the output the doc quotes, and the command's check."""
    done: set[str] = set()
    for cmd in documented_commands():
        if cmd.doc != doc or cmd.key not in RUN or cmd.key in done:
            continue
        done.add(cmd.key)
        how = RUN[cmd.key]
        if how.prepare:
            how.prepare(repo)
        r = run_command(cmd, repo)
        fails = "trackflow: error:" in cmd.expected
        assert r.returncode == (1 if fails else 0), r.describe()
        if cmd.expected:
            miss = quoted_output_mismatch(cmd.expected, r.output)
            assert miss is None, f"{miss}\n{r.describe()}"
        if how.check:
            how.check(r)


def pages() -> list[str]:
    """The docs with commands to run, in order."""
    return list(dict.fromkeys(c.doc for c in documented_commands() if c.key in RUN))


#: The pages tests/test_readme.py runs; tests/test_doc_pages.py runs the others (two files, so
#: the two workers of `make test` (--dist loadfile) share the work: about 70 s of CPU each).
README_PAGES = ("README.md", "docs/calibration.md")
