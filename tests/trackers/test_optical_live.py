"""The optical tracker as a live input of `trackflow run` (``input: {optical: ...}``): the
spec and its bad input, and end to end through the real command line on frames rendered
from real recordings: a run paced in real time is recorded, its replay reproduces the
answers bit for bit, and the recorded poses match the rendered truth."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from trackflow.dataflow import load_setup, parse_input, register_feed
from trackflow.io import read_stream
from trackflow.math import quat_angle

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"


def test_optical_spec_resolves_the_config_next_to_the_setup(tmp_path):
    spec = parse_input({"optical": {"config": "optical.yaml", "body": "wand"}}, tmp_path)
    assert spec.protocol == "optical"
    assert spec.options == {"config": str(tmp_path / "optical.yaml"), "body": "wand"}
    assert spec.unit_scale == 1.0 and spec.up == "z"
    absolute = parse_input({"optical": {"config": "/x/o.yaml", "body": "a"}}, tmp_path)
    assert absolute.options["config"] == "/x/o.yaml"
    setup = load_setup(EXAMPLES / "optical_live.yaml")
    assert setup.inputs["tracker_tool"].options == {
        "config": str(EXAMPLES / "optical.yaml"),
        "body": "tool",
    }


@pytest.mark.parametrize(
    ("doc", "message"),
    [
        ({"optical": {"body": "wand"}}, "input.optical: missing key 'config'"),
        ({"optical": {"config": "o.yaml"}}, "input.optical: missing key 'body'"),
        ({"optical": {"config": "o.yaml", "body": 3}}, "input.optical.body: expected"),
        ({"optical": {"config": "  ", "body": "a"}}, "input.optical.config: empty path"),
        ({"optical": {"config": "o.yaml", "body": "a", "port": 1}}, "unknown keys ['port']"),
        ({"optical": "o.yaml"}, "input.optical must be a mapping"),
    ],
)
def test_bad_optical_specs_name_the_key(doc, message):
    with pytest.raises(ValueError) as err:
        parse_input(doc)
    assert message in str(err.value)


def test_only_feed_protocols_can_be_registered():
    with pytest.raises(ValueError, match="'natnet' is not a feed protocol"):
        register_feed("natnet", lambda options: None)


def _optical_config(tmp_path: Path, shared_data: Path, duration_s: float) -> Path:
    """examples/optical.yaml with absolute paths (shared recordings, setup, calibration)."""
    doc = yaml.safe_load((EXAMPLES / "optical.yaml").read_text())
    for traj in doc["render"]["trajectories"].values():
        rec = shared_data / "ar_table" / Path(traj["recording"]).name
        if not rec.exists():
            pytest.skip(f"{rec} not present")
        traj["recording"] = str(rec)
    doc["setup"] = str(EXAMPLES / doc["setup"])
    doc["calibration"] = str(EXAMPLES / doc["calibration"])
    doc["render"]["duration_s"] = duration_s
    path = tmp_path / "optical.yaml"
    path.write_text(yaml.safe_dump(doc))
    live = yaml.safe_load((EXAMPLES / "optical_live.yaml").read_text())
    (tmp_path / "live.yaml").write_text(yaml.safe_dump(live))  # config: optical.yaml, beside
    return path


def test_a_body_the_tracker_does_not_know_is_named(tmp_path, shared_data):
    import trackflow.optical  # noqa: F401  (registers the feed)
    from trackflow.trackers.inputs import make_input

    cfg = _optical_config(tmp_path, shared_data, 0.2)
    spec = parse_input({"optical": {"config": str(cfg), "body": "spoon"}})
    with pytest.raises(ValueError, match="sensor 'hand': input.optical.body 'spoon' is not"):
        make_input("hand", spec, np.eye(6))
    missing = parse_input({"optical": {"config": str(tmp_path / "none.yaml"), "body": "a"}})
    with pytest.raises(ValueError, match="input.optical.config: .*none.yaml is not a file"):
        make_input("hand", missing, np.eye(6))


def _trackflow(*args, timeout: float) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    return subprocess.run(
        [sys.executable, "-m", "trackflow.cli.main", *map(str, args)],
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.mark.slow
def test_run_records_and_replays_the_optical_tracker(tmp_path, shared_data):
    from ._lines import read_lines, stop_when_stale, wait_line
    from .test_live_e2e import _trackflow as _start

    cfg = _optical_config(tmp_path, shared_data, duration_s=3.0)
    setup, record = tmp_path / "live.yaml", tmp_path / "out.tfrec"
    run = _start("run", setup, "--record", record, "--json")
    try:  # until both bodies are stale: the tracker has rendered its last frame
        lines = read_lines(run.stderr)
        wait_line(lines, "tracker_wand (optical):", 240)  # the status line per sensor
        summary = json.loads(stop_when_stale(run, lines, 2, timeout_s=120))
    finally:
        if run.poll() is None:
            run.kill()
            run.communicate()
    assert run.returncode == 0
    # how many frames are processed depends on the machine: a tracker that cannot keep up
    # drops camera frames (its dropouts), and a body is lost more often across the gaps (15
    # measurements of a body beside two test suites and two burners). What must hold
    # whatever the load: enough measurements for the accuracy check below, and every
    # processed frame accounted for
    assert summary["answers"] >= 5
    for name in ("tracker_wand", "tracker_tool"):
        st = summary["sensors"][name]
        assert st["protocol"] == "optical"
        assert st["measurements"] >= 5, st
        # every processed frame is a measurement or a counted rejection of this body
        assert st["measurements"] + sum(st["rejections"].values()) == st["packets"], st
        assert set(st["rejections"]) <= {"not tracked"}, st
    again = _trackflow("run", setup, "--replay", record, "--json", timeout=120)
    assert again.returncode == 0, again.stdout + again.stderr
    assert json.loads(again.stdout)["identical"] is True

    # the recorded poses against the rendered truth: exposure times are frame times on the
    # host clock, so the frame of a sample is (t - t_first) * rate + k0 for the first
    # recorded frame k0, searched over every frame (a loaded machine drops the first ones)
    from trackflow.optical import load_optical_setup

    opt = load_optical_setup(cfg)
    frames = opt.run.frames
    rate = 1e9 / float(frames.t_ns[1] - frames.t_ns[0])
    for name, body in (("tracker_wand", "wand"), ("tracker_tool", "tool")):
        got, _ = read_stream(tmp_path / f"out.{name}.tfrec", format="native")
        step = (got.t_ns - got.t_ns[0]) * 1e-9 * rate
        rel = np.round(step).astype(int)
        assert np.allclose(step, rel, atol=1e-3)  # stamped on the frame grid
        truth = frames.renderer.trajectories[body]
        best = None
        for k0 in range(len(frames.times_s) - int(rel.max())):
            idx = rel + k0
            ok = idx < len(frames.times_s)
            true = [truth(float(frames.times_s[i])) for i in idx[ok]]
            dp = np.linalg.norm(got.position[ok] - np.array([p.position for p in true]), axis=1)
            err = float(np.sqrt(np.mean(dp**2)))
            if best is None or err < best[0]:
                qs = np.array([p.quaternion for p in true])
                best = (
                    err,
                    float(np.degrees(np.sqrt(np.mean(quat_angle(got.quaternion[ok], qs) ** 2)))),
                )
        pos_m, ori_deg = best
        print(f"{name}: {len(got)} poses, {pos_m * 1e3:.3f} mm, {ori_deg:.3f} deg RMS")
        assert pos_m < 1e-3 and ori_deg < 0.5, best
        sd = np.sqrt(np.einsum("nii->ni", got.covariance[:, :3, :3]))
        assert np.all((sd > 1e-5) & (sd < 1e-2))  # the pipeline's covariance, not a nominal
