"""`trackflow run` / `simulate`: clear errors through the CLI's one error boundary."""

from __future__ import annotations

from trackflow.cli.main import main

SETUP = """frames: [W, B]
sensors:
  - {name: head, source: W, target: B}
queries:
  - {name: q, source: W, target: B, mode: push, rate_hz: 60}
"""


def test_run_without_inputs_says_which_sensor(tmp_path, capsys):
    p = tmp_path / "s.yaml"
    p.write_text(SETUP)
    assert main(["run", str(p), "--duration", "0.1"]) == 1
    err = capsys.readouterr().err
    assert "sensor(s) ['head'] have no 'input:'" in err


def test_run_needs_a_push_query(tmp_path, capsys):
    p = tmp_path / "s.yaml"
    p.write_text(SETUP.replace("mode: push, rate_hz: 60", "mode: pull"))
    assert main(["run", str(p)]) == 1
    assert "must be a push query" in capsys.readouterr().err


def test_replay_of_a_missing_recording(tmp_path, capsys):
    p = tmp_path / "s.yaml"
    p.write_text(SETUP.replace("target: B}", "target: B, input: {dtrack: {body: 1}}}"))
    assert main(["run", str(p), "--replay", str(tmp_path / "none.tfrec")]) == 1
    assert "none.tfrec" in capsys.readouterr().err


def test_simulate_rejects_bad_options(tmp_path, capsys):
    rec = tmp_path / "r.txt"
    rec.write_text("0.0 0 0 0 0 0 0 1\n0.01 0 0 0 0 0 0 1\n")
    assert main(["simulate", "natnet", str(rec), "--natnet-version", "x"]) == 1
    assert "--natnet-version" in capsys.readouterr().err
    assert main(["simulate", "natnet", str(rec), "--port", "0", "--natnet-version", "5.0"]) == 1
    assert "not supported" in capsys.readouterr().err
    assert main(["simulate", "dtrack", str(rec), "--port", "9", "--loss", "1.5"]) == 1
    assert "loss" in capsys.readouterr().err
