"""The command line's one error boundary: a user's mistake is one line, a bug a traceback."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from trackflow.cli.main import main

SRC = Path(__file__).resolve().parents[2] / "src"
DUPLICATE = "sensors:\n  - {name: a, source: A, target: B, rate_hz: 1, rate_hz: 2}\n"


def test_a_typed_error_is_one_line(tmp_path, capsys):
    (tmp_path / "s.yaml").write_text(DUPLICATE)
    assert main(["plan", str(tmp_path / "s.yaml")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("trackflow: error: ")
    assert f"{tmp_path / 's.yaml'}:2" in err and "Traceback" not in err


def test_debug_shows_the_traceback_of_a_typed_error(tmp_path, capsys):
    (tmp_path / "s.yaml").write_text(DUPLICATE)
    assert main(["--debug", "plan", str(tmp_path / "s.yaml")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("Traceback") and "ConfigError" in err
    assert err.rstrip().splitlines()[-1].startswith("trackflow: error: ")


def _bug(*args, **kwargs):
    raise KeyError("an injected bug")


def test_a_bug_is_not_turned_into_an_error_line(tmp_path, monkeypatch, capsys):
    import trackflow.io

    (tmp_path / "a.txt").write_text("1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 1\n")
    monkeypatch.setattr(trackflow.io, "read_stream", _bug)
    with pytest.raises(KeyError, match="an injected bug"):
        main(["info", str(tmp_path / "a.txt")])
    assert "trackflow: error" not in capsys.readouterr().err


def test_a_bug_shows_its_traceback_in_a_process(tmp_path):
    (tmp_path / "a.txt").write_text("1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 1\n")
    code = (
        "import sys, trackflow.io\n"
        "def bug(*a, **k):\n"
        "    raise RuntimeError('an injected bug')\n"
        "trackflow.io.read_stream = bug\n"
        "from trackflow.cli.main import main\n"
        f"sys.exit(main(['info', {str(tmp_path / 'a.txt')!r}]))\n"
    )
    env = dict(os.environ, PYTHONPATH=str(SRC))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert r.returncode == 1
    assert "Traceback" in r.stderr and "RuntimeError: an injected bug" in r.stderr
    assert "trackflow: error" not in r.stderr


def test_a_missing_file_is_one_line(tmp_path, capsys):
    assert main(["info", str(tmp_path / "nope.txt")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nope.txt" in err and "Traceback" not in err
