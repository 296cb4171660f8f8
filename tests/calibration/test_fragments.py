"""Calibration results as setup fragments: written, included by load_setup, checked."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from _synth import X_TRUE, Z_TRUE, two_trackers
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from trackflow.calibration import sensor_update, solve_hand_eye, static_edge, write_fragment
from trackflow.cli.main import main
from trackflow.dataflow import load_setup
from trackflow.io import write_stream
from trackflow.math import Pose, UncertainPose

SETUP = {
    "sensors": [
        {"name": "quest", "source": "W", "target": "H", "rate_hz": 72, "sigma_pos_mm": 1.0,
         "sigma_ori_deg": 0.1},
        {"name": "robot", "source": "B", "target": "T", "rate_hz": 30},
    ],
    "include": ["calib.yaml"],
}  # fmt: skip


def test_fragment_is_included_by_load_setup(tmp_path):
    C = np.diag([1e-6, 2e-6, 3e-6, 1e-5, 2e-5, 3e-5])
    X = UncertainPose(Pose([0.0, 0.1, 0.2], [0.0, 0.0, 0.0, 1.0]), C)
    cov = np.diag([4e-8] * 3 + [1e-6] * 3)
    write_fragment(
        tmp_path / "calib.yaml",
        statics=[static_edge("X", "T", "H", X)],
        sensors=[sensor_update("quest", clock_offset_s=0.25, covariance=cov)],
    )
    (tmp_path / "setup.yaml").write_text(yaml.safe_dump(SETUP))
    setup = load_setup(tmp_path / "setup.yaml")
    edges = {e.name: e for e in setup.graph.edges}
    assert edges["X"].kind == "static"
    np.testing.assert_allclose(edges["X"].covariance, C)
    np.testing.assert_allclose(edges["X"].pose.position, [0.0, 0.1, 0.2])
    assert edges["quest"].stamp_offset_s == pytest.approx(-0.25)
    np.testing.assert_allclose(edges["quest"].covariance, cov)


@pytest.mark.parametrize(
    "fragment, match",
    [
        ({"sensors": [{"name": "nope", "stamp_offset_ms": 1}]}, "no sensor named"),
        ({"sensors": [{"name": "quest", "source": "X"}]}, "cannot be set"),
        ({"queries": []}, "a fragment is a mapping"),
    ],
)
def test_bad_fragments_are_clear_errors(tmp_path, fragment, match):
    (tmp_path / "calib.yaml").write_text(yaml.safe_dump(fragment))
    (tmp_path / "setup.yaml").write_text(yaml.safe_dump(SETUP))
    with pytest.raises(ValueError, match=match):
        load_setup(tmp_path / "setup.yaml")


def test_missing_fragment_names_the_file(tmp_path):
    (tmp_path / "setup.yaml").write_text(yaml.safe_dump(SETUP))
    with pytest.raises(ValueError, match="calib.yaml not found"):
        load_setup(tmp_path / "setup.yaml")


def test_cli_hand_eye_json_use_and_fragment(tmp_path, capsys):
    a, b = two_trackers(3, duration=20.0)
    write_stream(tmp_path / "robot.txt", a)
    write_stream(tmp_path / "sensor.txt", b)
    args = [str(tmp_path / "robot.txt"), str(tmp_path / "sensor.txt")]
    # TUM files carry no frame names: force the robot-world form
    extra = ["--fragment", str(tmp_path / "frag.yaml"), "--report", str(tmp_path / "rep")]
    rc = main(["calibrate", "hand-eye", *args, "--form", "robot-world", "--json", *extra])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert list(out) == KEYS
    ref = solve_hand_eye(a, b)
    assert out["offset_s"] == pytest.approx(ref.offset_s, abs=1e-4)
    np.testing.assert_allclose(out["X"]["position"], ref.X.position, atol=1e-4)
    assert (tmp_path / "rep" / "residuals.png").stat().st_size > 1000
    frag = yaml.safe_load((tmp_path / "frag.yaml").read_text())
    assert {s["name"] for s in frag["statics"]} == {"hand_eye_X", "hand_eye_Z"}
    (tmp_path / "calib.json").write_text(json.dumps(out))
    rc = main(["calibrate", "hand-eye", *args, "--use", str(tmp_path / "calib.json"), "--json"])
    assert rc == 0
    used = json.loads(capsys.readouterr().out)
    assert used["residual_pos_mm"] == pytest.approx(out["residual_pos_mm"], rel=0.3)
    assert used["offset_s"] == out["offset_s"]
    # the world-independent residual of the stored X, as the solve reported it
    assert used["pair_residual_pos_mm"] == pytest.approx(out["pair_residual_pos_mm"], rel=0.1)
    assert used["pair_residual_ori_deg"] == pytest.approx(out["pair_residual_ori_deg"], rel=0.1)


KEYS = ["X", "Z", "offset_s", "offset_sigma_s", "residual_pos_mm", "residual_ori_deg",
        "pair_residual_pos_mm", "pair_residual_ori_deg", "X_sigma_mm", "X_sigma_deg"]  # fmt: skip


def test_cli_use_refit_world_keeps_X_and_refits_the_world(tmp_path, capsys):
    from trackflow.math import quat_exp, quat_multiply

    # session 1 calibrates; session 2 has another world frame and clock offset
    a1, b1 = two_trackers(3, duration=20.0)
    Z2 = (Z_TRUE[0] + np.array([0.3, 0.1, -0.2]), quat_multiply(Z_TRUE[1], quat_exp(
        np.array([0.2, -0.5, 0.4]))))  # fmt: skip
    a2, b2 = two_trackers(4, duration=20.0, offset=0.18, Z=Z2)
    for name, s in (("r1", a1), ("s1", b1), ("r2", a2), ("s2", b2)):
        write_stream(tmp_path / f"{name}.txt", s)
    rc = main(["calibrate", "hand-eye", str(tmp_path / "r1.txt"), str(tmp_path / "s1.txt"),
               "--form", "robot-world", "--json"])  # fmt: skip
    assert rc == 0
    (tmp_path / "calib.json").write_text(capsys.readouterr().out)
    stored = json.loads((tmp_path / "calib.json").read_text())
    session2 = [str(tmp_path / "r2.txt"), str(tmp_path / "s2.txt"), "--use",
                str(tmp_path / "calib.json")]  # fmt: skip
    # the stored world is wrong here, X is not (at this session's offset: the stored one is
    # 70 ms off and spoils the motion pairs too)
    assert main(["calibrate", "hand-eye", *session2, "--offset", "0.18", "--json"]) == 0
    used = json.loads(capsys.readouterr().out)
    assert used["residual_pos_mm"] > 100 * stored["residual_pos_mm"]
    assert used["pair_residual_pos_mm"] < 3 * stored["pair_residual_pos_mm"]
    extra = ["--fragment", str(tmp_path / "frag.yaml"), "--report", str(tmp_path / "rep")]
    assert main(["calibrate", "hand-eye", *session2, "--refit", "world", "--json", *extra]) == 0
    out = json.loads(capsys.readouterr().out)
    assert list(out) == KEYS
    assert out["X"] == stored["X"]  # kept, covariance and all
    np.testing.assert_allclose(out["Z"]["position"], Z2[0], atol=2e-3)
    assert abs(out["offset_s"] - 0.18) < 0.1 / 30
    assert out["residual_pos_mm"] < 2 * stored["residual_pos_mm"]
    frag = yaml.safe_load((tmp_path / "frag.yaml").read_text())
    statics = {s["name"]: s for s in frag["statics"]}
    np.testing.assert_allclose(statics["hand_eye_Z"]["position"], out["Z"]["position"])
    np.testing.assert_allclose(statics["hand_eye_X"]["position"], X_TRUE[0], atol=2e-3)
    report = json.loads((tmp_path / "rep" / "report.json").read_text())
    assert report["form"] == "refit-world" and report["n_pairs"] > 100


@pytest.mark.parametrize(
    "args, message",
    [
        (["--refit", "X"], "cannot refit 'X': allowed: 'world'"),
        (["--refit", "offset"], "cannot refit 'offset': allowed: 'world'"),
        (["--refit", "world", "--drift"], "--form and --drift do not apply"),
        (["--refit", "world", "--form", "hand-eye"], "--form and --drift do not apply"),
    ],
)
def test_cli_refit_refuses_what_it_cannot_do(tmp_path, capsys, args, message):
    (tmp_path / "calib.json").write_text("{}")  # refused before the file is read
    rc = main(["calibrate", "hand-eye", str(tmp_path / "r.txt"), str(tmp_path / "s.txt"),
               "--use", str(tmp_path / "calib.json"), *args])  # fmt: skip
    assert rc == 1
    assert message in capsys.readouterr().err


def test_cli_refit_needs_use(tmp_path, capsys):
    rc = main(["calibrate", "hand-eye", str(tmp_path / "r.txt"), str(tmp_path / "s.txt"),
               "--refit", "world"])  # fmt: skip
    assert rc == 1
    assert "--refit needs --use" in capsys.readouterr().err


def test_cli_reports_bad_input_without_traceback(tmp_path, capsys):
    a, b = two_trackers(3, duration=20.0, rot_amp=0.0)
    write_stream(tmp_path / "robot.txt", a)
    write_stream(tmp_path / "sensor.txt", b.with_(position=np.zeros(b.position.shape)))
    still = a.with_(position=np.zeros(a.position.shape))
    write_stream(tmp_path / "robot.txt", still, overwrite=True)
    rc = main(["calibrate", "clock-offset", str(tmp_path / "robot.txt"),
               str(tmp_path / "sensor.txt")])  # fmt: skip
    assert rc == 1
    assert "no motion" in capsys.readouterr().err
    (tmp_path / "bad.json").write_text("{}")
    rc = main(["calibrate", "hand-eye", str(tmp_path / "robot.txt"), str(tmp_path / "sensor.txt"),
               "--use", str(tmp_path / "bad.json")])  # fmt: skip
    assert rc == 1
    assert "bad.json" in capsys.readouterr().err


@given(
    position=st.lists(st.floats(-10, 10), min_size=3, max_size=3),
    rotvec=st.lists(st.floats(-3, 3), min_size=3, max_size=3),
    sigmas=st.lists(st.floats(1e-6, 1e-1), min_size=6, max_size=6),
    offset=st.floats(-5, 5),
)
@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
def test_fragment_round_trip(tmp_path, position, rotvec, sigmas, offset):
    from trackflow.math import quat_exp

    C = np.diag(np.square(sigmas))
    X = UncertainPose(Pose(position, quat_exp(np.array(rotvec))), C)
    write_fragment(tmp_path / "calib.yaml", statics=[static_edge("X", "T", "H", X)], overwrite=True,
                   sensors=[sensor_update("quest", clock_offset_s=offset)])  # fmt: skip
    (tmp_path / "setup.yaml").write_text(yaml.safe_dump(SETUP))
    edges = {e.name: e for e in load_setup(tmp_path / "setup.yaml").graph.edges}
    np.testing.assert_array_equal(edges["X"].pose.position, X.position)
    np.testing.assert_allclose(edges["X"].pose.quaternion, X.quaternion, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(edges["X"].covariance, C)
    assert edges["quest"].stamp_offset_s == pytest.approx(-offset, abs=1e-12)
