"""The malformed-input suite: every bad input through the command line.

Each case writes its input files into a fresh directory, runs ``trackflow`` (the real entry
point, ``trackflow.cli.main.main``) and requires exit code 1, one ``trackflow: error:`` line
naming the file (and the line where there is one), no traceback, and every file that existed
before the run byte-for-byte unchanged with no temporary left behind. ``test_subprocess_*``
repeat a few cases in a separate process to cover the interpreter's own output.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from trackflow.cli.main import main

DATA = Path(__file__).parent / "data"
GT = (DATA / "fr1_xyz_groundtruth_10s.txt").read_text()
GT_LINES = GT.splitlines(keepends=True)
SRC = Path(__file__).resolve().parents[2] / "src"

TUM_OK = "".join(f"{1 + k * 0.01:.2f} {k * 0.001} 0 0 0 0 0 1\n" for k in range(40))


def tum(*rows: str) -> str:
    return "".join(r + "\n" for r in rows)


# (id, {file: content}, argv, substrings the error must contain)
CASES = [
    # text formats: malformed rows name file:line
    (
        "tum-short-row",
        {"a.txt": tum("1 0 0 0 0 0 0 1", "2 0 0 0")},
        ["info", "a.txt"],
        ["a.txt:2", "short row"],
    ),
    (
        "tum-unparsable",
        {"a.txt": tum("1 0 0 0 0 0 0 1", "2 0 x 0 0 0 0 1")},
        ["info", "a.txt"],
        ["a.txt:2", "unparsable"],
    ),
    (
        "tum-nan",
        {"a.txt": tum("1 0 0 0 0 0 0 1", "2 nan 0 0 0 0 0 1")},
        ["info", "a.txt"],
        ["a.txt:2", "NaN"],
    ),
    (
        "tum-inf-time",
        {"a.txt": tum("1 0 0 0 0 0 0 1", "inf 0 0 0 0 0 0 1")},
        ["info", "a.txt"],
        ["a.txt:2"],
    ),
    (
        "tum-non-unit-quaternion",
        {"a.txt": tum("1 0 0 0 0 0 0 1", "2 0 0 0 0 0 1 1")},
        ["info", "a.txt"],
        ["a.txt:2", "not unit"],
    ),
    (
        "tum-zero-quaternion",
        {"a.txt": tum("1 0 0 0 0 0 0 1", "2 0 0 0 0 0 0 0")},
        ["info", "a.txt"],
        ["a.txt:2", "zero"],
    ),
    (
        "tum-duplicate-time",
        {"a.txt": tum("1 0 0 0 0 0 0 1", "1 0 0 0 0 0 0 1")},
        ["info", "a.txt"],
        ["a.txt:2"],
    ),
    (
        "tum-backward-time",
        {"a.txt": tum("2 0 0 0 0 0 0 1", "1 0 0 0 0 0 0 1")},
        ["info", "a.txt"],
        ["a.txt:2"],
    ),
    (
        "tum-huge-position",
        {"a.txt": tum("1 0 0 0 0 0 0 1", "2 1e308 0 0 0 0 0 1")},
        ["info", "a.txt"],
        ["a.txt:2", "beyond"],
    ),
    (
        "tum-huge-time",
        {"a.txt": tum("1 0 0 0 0 0 0 1", "1e30 0 0 0 0 0 0 1")},
        ["info", "a.txt"],
        ["a.txt:2"],
    ),
    (
        "not-utf8",
        {"a.txt": b"1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 \xff\n"},
        ["info", "a.txt"],
        ["a.txt:2", "UTF-8"],
    ),
    ("all-zero-bytes", {"a.txt": b"\0" * 200_000}, ["info", "a.txt"], ["a.txt:1", "NUL"]),
    (
        "zero-bytes-after-data",
        {"a.txt": TUM_OK.encode() + b"\0" * 1000},
        ["info", "a.txt", "--format", "tum"],
        ["a.txt:41", "NUL"],
    ),
    ("empty-file", {"a.txt": ""}, ["info", "a.txt"], ["a.txt"]),
    (
        "comments-only",
        {"a.txt": "# nothing\n"},
        ["info", "a.txt", "--format", "tum"],
        ["a.txt", "0 pose samples"],
    ),
    (
        "csv-header-only",
        {"a.csv": "t,x,y,z,qx,qy,qz,qw\n"},
        ["info", "a.csv"],
        ["a.csv", "0 pose samples"],
    ),
    (
        "clean-drops-everything",
        {"a.txt": tum("1 nan 0 0 0 0 0 1", "2 nan 0 0 0 0 0 1")},
        ["info", "a.txt", "--clean"],
        ["a.txt", "0 pose samples", "NaN"],
    ),
    (
        "csv-header-only-filter",
        {"a.csv": "t,x,y,z,qx,qy,qz,qw\n"},
        ["filter", "a.csv", "o.txt"],
        ["a.csv", "0 pose samples"],
    ),
    (
        "csv-header-only-evaluate",
        {"a.csv": "t,x,y,z,qx,qy,qz,qw\n"},
        ["evaluate", "a.csv"],
        ["a.csv", "0 pose samples"],
    ),
    (
        "csv-header-only-tune",
        {"a.csv": "t,x,y,z,qx,qy,qz,qw\n"},
        ["tune", "a.csv"],
        ["a.csv", "0 pose samples"],
    ),
    (
        "csv-header-only-plot",
        {"a.csv": "t,x,y,z,qx,qy,qz,qw\n"},
        ["plot", "a.csv"],
        ["a.csv", "0 pose samples"],
    ),
    (
        "two-samples-evaluate",
        {"a.txt": tum("1 0 0 0 0 0 0 1", "2 0 0 0 0 0 0 1")},
        ["evaluate", "a.txt"],
        ["a.txt", "2 pose samples", "at least"],
    ),
    (
        "csv-missing-column",
        {"a.csv": "t,x,y,z,qx,qy,qz\n1,0,0,0,0,0,0\n"},
        ["info", "a.csv"],
        ["a.csv", "qw"],
    ),
    (
        "csv-bad-columns-flag",
        {"a.csv": "t,x,y,z,qx,qy,qz,qw\n1,0,0,0,0,0,0,1\n"},
        ["info", "a.csv", "--columns", "t=time"],
        ["a.csv", "time"],
    ),
    (
        "csv-columns-syntax",
        {"a.csv": "t,x,y,z,qx,qy,qz,qw\n1,0,0,0,0,0,0,1\n"},
        ["info", "a.csv", "--columns", "t"],
        ["--columns"],
    ),
    (
        "euroc-short-row",
        {"e.csv": "#timestamp,x\n1403636580838555648,4.6,-1.7\n"},
        ["info", "e.csv", "--format", "euroc"],
        ["e.csv:2", "short row"],
    ),
    (
        "quest-bad-row",
        {
            "q.txt": "638423032246286760,638423032246286780,2024,1,31,13,7,4,628,"
            "0.1,1.7,0.1,0.0,0.0,0.0,x\n"
        },
        ["info", "q.txt", "--format", "quest"],
        ["q.txt:1"],
    ),
    (
        "kitti-not-orthonormal",
        {"k.kitti": "1 0 0 0 0 1 0 0 0 0 1 0\n2 0 0 0 0 1 0 0 0 0 1 0\n"},
        ["info", "k.kitti"],
        ["k.kitti:2", "orthonormal"],
    ),
    (
        "kitti-times-mismatch",
        {"k.kitti": "1 0 0 0 0 1 0 0 0 0 1 0\n", "t.txt": "0\n1\n"},
        ["info", "k.kitti"],
        [],
    ),  # placeholder replaced below (reader option not a flag)
    # binary formats
    (
        "native-corrupt-header",
        {"a.tfrec": b"\x89TFREC\r\n" + b"\1" * 100},
        ["info", "a.tfrec"],
        ["a.tfrec"],
    ),
    ("garbage-bag", {"g.bag": bytes(range(256)) * 20}, ["info", "g.bag"], ["g.bag", "ROS bag"]),
    ("garbage-mat", {"g.mat": b"MATLAB 5.0 garbage" * 20}, ["info", "g.mat"], ["g.mat"]),
    ("tum-as-mat", {"a.mat": TUM_OK}, ["info", "a.mat"], ["a.mat"]),
    # files and flags
    ("missing-file", {}, ["info", "nope.txt"], ["nope.txt"]),
    ("directory-as-file", {"d/x.txt": TUM_OK}, ["info", "d", "--format", "tum"], ["d"]),
    (
        "unknown-extension-out",
        {"a.txt": TUM_OK},
        ["convert", "a.txt", "o.xyz"],
        ["o.xyz", "--format"],
    ),
    ("topic-on-tum", {"a.txt": TUM_OK}, ["info", "a.txt", "--topic", "/x"], ["--topic"]),
    ("missing-output-dir", {"a.txt": TUM_OK}, ["convert", "a.txt", "nodir/o.txt"], ["nodir"]),
    (
        "output-exists",
        {"a.txt": TUM_OK, "o.txt": "precious\n"},
        ["convert", "a.txt", "o.txt"],
        ["o.txt", "exists", "--force"],
    ),
    (
        "bag-output-exists",
        {"a.txt": TUM_OK, "o.bag": "precious\n"},
        ["convert", "a.txt", "o.bag"],
        ["o.bag", "exists", "--force"],
    ),
    (
        "shift-wraps",
        {"a.txt": "".join(GT_LINES[:40])},
        ["shift", "a.txt", "o.txt", "--offset", "9e9"],
        ["int64"],
    ),
    (
        "shift-overflow",
        {"a.txt": TUM_OK},
        ["shift", "a.txt", "o.txt", "--offset", "1e30"],
        ["int64"],
    ),
    ("shift-nan", {"a.txt": TUM_OK}, ["shift", "a.txt", "o.txt", "--offset", "nan"], ["finite"]),
    (
        "unix-time-to-mat",
        {"a.txt": tum("1305031098.6659 0 0 0 0 0 0 1", "1305031098.6759 0 0 0 0 0 0 1")},
        ["convert", "a.txt", "o.mat"],
        ["BROAD", "shift"],
    ),
    (
        "scale-cov-no-covariance",
        {"a.txt": TUM_OK},
        ["scale-cov", "a.txt", "o.txt", "--factor", "2"],
        ["covariance"],
    ),
    (
        "scale-cov-negative",
        {"a.txt": TUM_OK},
        ["scale-cov", "a.txt", "o.txt", "--factor", "-2"],
        ["positive"],
    ),
    (
        "horizons-garbage",
        {"a.txt": TUM_OK},
        ["evaluate", "a.txt", "--horizons", "ten"],
        ["horizons"],
    ),
    (
        "horizons-negative",
        {"a.txt": TUM_OK},
        ["evaluate", "a.txt", "--horizons", "-10"],
        ["horizons"],
    ),
    (
        "learned-orders-garbage",
        {"a.txt": TUM_OK},
        ["tune", "a.txt", "--learned-orders", "x"],
        ["integers"],
    ),
    (
        "plot-window-outside",
        {"a.txt": TUM_OK},
        ["plot", "a.txt", "--start", "1000", "--out", "p"],
        ["a.txt", "window", "1000"],
    ),
    (
        "infer-frames-mismatch",
        {"a.txt": TUM_OK, "b.txt": TUM_OK},
        ["infer", "a.txt", "b.txt", "o.txt"],
        ["cannot chain", "--source"],
    ),
    (
        "infer-no-overlap",
        {"a.txt": TUM_OK, "b.txt": TUM_OK.replace("1.", "9.")},
        ["infer", "a.txt", "b.txt", "o.txt", "--target", "x", "--source2", "x"],
        ["overlap"],
    ),
    (
        "model-not-json",
        {"a.txt": TUM_OK, "m.json": "{nope"},
        ["filter", "a.txt", "o.txt", "--model", "m.json"],
        ["m.json:1", "JSON"],
    ),
    (
        "model-wrong-doc",
        {"a.txt": TUM_OK, "m.json": '{"a": 1}'},
        ["filter", "a.txt", "o.txt", "--model", "m.json"],
        ["m.json", "tune --output"],
    ),
    (
        "model-bad-field",
        {
            "a.txt": TUM_OK,
            "m.json": '{"trackflow_model": 1, "predictor": '
            '{"family": "derivative", "n_dp": 2, "n_do": 1, "noise": [1], '
            '"pos_sigma": 0.001, "ori_sigma": 0.01}}',
        },
        ["filter", "a.txt", "o.txt", "--model", "m.json"],
        ["m.json", "noise"],
    ),
    (
        "model-n-dp-7",
        {
            "a.txt": TUM_OK,
            "m.json": '{"trackflow_model": 1, "predictor": {"family": '
            '"derivative", "n_dp": 7, "n_do": 1, "noise": [1, 1, 1, 1, 1, 1, 1, 1, 1, 1], '
            '"pos_sigma": 0.001, "ori_sigma": 0.01}}',
        },
        ["filter", "a.txt", "o.txt", "--model", "m.json"],
        ["m.json", "n_dp", "-1..3"],
    ),
    (
        "model-missing-file",
        {"a.txt": TUM_OK},
        ["filter", "a.txt", "o.txt", "--model", "m.json"],
        ["m.json"],
    ),
    (
        "lookup-unknown-frame",
        {"s.yaml": "sensors:\n  - {name: a, source: A, target: B}\n"},
        ["lookup", "s.yaml", "--from", "A", "--to", "Z"],
        ["s.yaml", "Z"],
    ),
    # setups
    (
        "setup-undeclared-frame",
        {"s.yaml": "frames: [A, T]\nsensors:\n  - {name: a, source: A, target: X}\n"},
        ["plan", "s.yaml", "--from", "A", "--to", "T"],
        ["s.yaml:3", "'X'", "not declared"],
    ),
    (
        "setup-frames-string",
        {"s.yaml": 'frames: "P A T"\n'},
        ["plan", "s.yaml"],
        ["s.yaml:1", "list"],
    ),
    (
        "setup-duplicate-key",
        {"s.yaml": "sensors:\n  - {name: a, source: A, target: B, rate_hz: 1, rate_hz: 2}\n"},
        ["plan", "s.yaml"],
        ["s.yaml:2", "duplicate key 'rate_hz'"],
    ),
    (
        "setup-null-name",
        {"s.yaml": "sensors:\n  - {name: null, source: A, target: B}\n"},
        ["plan", "s.yaml"],
        ["s.yaml:2", "name"],
    ),
    (
        "setup-blank-frame",
        {"s.yaml": "sensors:\n  - {name: a, source: ' ', target: B}\n"},
        ["plan", "s.yaml"],
        ["s.yaml:2", "source"],
    ),
    (
        "setup-negative-sigma",
        {"s.yaml": "sensors:\n  - {name: a, source: A, target: B, sigma_pos_mm: -1}\n"},
        ["plan", "s.yaml"],
        ["s.yaml:2", "sigma_pos_mm"],
    ),
    (
        "setup-non-unit-quaternion",
        {"s.yaml": "statics:\n  - {name: a, source: A, target: B, quaternion: [0, 0, 1, 1]}\n"},
        ["plan", "s.yaml"],
        ["s.yaml:2", "not unit"],
    ),
    (
        "setup-noise-length",
        {
            "s.yaml": "sensors:\n  - {name: a, source: A, target: B, motion: "
            "{n_dp: 1, n_do: 1, noise: [1, 2, 3]}}\n"
        },
        ["plan", "s.yaml"],
        ["s.yaml:2", "noise", "got 3"],
    ),
    (
        "setup-unknown-key",
        {"s.yaml": "sensors:\n  - {name: a, source: A, target: B, rte: 1}\n"},
        ["plan", "s.yaml"],
        ["s.yaml:2", "rte"],
    ),
    ("setup-invalid-yaml", {"s.yaml": "sensors: [\n"}, ["plan", "s.yaml"], ["s.yaml:2"]),
    (
        "setup-no-path",
        {
            "s.yaml": "sensors:\n  - {name: a, source: A, target: B}\n"
            "  - {name: b, source: C, target: D}\n"
        },
        ["plan", "s.yaml", "--from", "A", "--to", "D"],
        ["s.yaml", "path"],
    ),
]
# KITTI times come from a reader option the command line does not expose; drop that case
CASES = [c for c in CASES if c[0] != "kitti-times-mismatch"]


def _write(d: Path, files: dict) -> None:
    for name, content in files.items():
        p = d / name
        p.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            p.write_bytes(content)
        else:
            p.write_text(content)


def _snapshot(d: Path) -> dict:
    return {p.relative_to(d): p.read_bytes() for p in d.rglob("*") if p.is_file()}


@pytest.mark.parametrize("files,argv,needles", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_malformed_input(files, argv, needles, tmp_path, monkeypatch, capsys):
    _write(tmp_path, files)
    before = _snapshot(tmp_path)
    monkeypatch.chdir(tmp_path)
    code = main(argv + (["--quiet"] if argv[0] in ("evaluate", "tune", "filter") else []))
    out, err = capsys.readouterr()
    assert code == 1, (out, err)
    lines = [ln for ln in err.splitlines() if ln.startswith("trackflow: error:")]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for s in needles:
        assert s in lines[0], (s, lines[0])
    assert _snapshot(tmp_path) == before, "a file was created, changed or left behind"


def test_every_case_id_is_unique():
    ids = [c[0] for c in CASES]
    assert len(ids) == len(set(ids)) and len(ids) >= 60


def _cli(*args, stdin: bytes | None = None, cwd=None, timeout=120):
    env = dict(os.environ, PYTHONPATH=str(SRC))
    return subprocess.run(
        [sys.executable, "-m", "trackflow.cli.main", *args], input=stdin, capture_output=True,
        cwd=cwd, env=env, timeout=timeout,
    )  # fmt: skip


def test_subprocess_error_has_no_traceback(tmp_path):
    (tmp_path / "a.txt").write_bytes(b"\0" * 100_000)
    r = _cli("info", "a.txt", cwd=tmp_path)
    assert r.returncode == 1
    assert r.stderr.decode().startswith("trackflow: error: a.txt:1:")
    assert b"Traceback" not in r.stderr


def test_subprocess_stdin_error_names_stdin(tmp_path):
    r = _cli("info", "-", stdin=b"1 0 0 0 0 0 0 1\n2 0 0\n", cwd=tmp_path)
    assert r.returncode == 1 and b"<stdin>:2" in r.stderr and b"Traceback" not in r.stderr


def test_utf8_bom_is_not_an_error(tmp_path, capsys):
    (tmp_path / "a.txt").write_bytes(b"\xef\xbb\xbf" + TUM_OK.encode())
    assert main(["info", str(tmp_path / "a.txt"), "--json"]) == 0
    assert '"samples": 40' in capsys.readouterr().out


def test_read_report_shown_without_clean(tmp_path, capsys):
    """Dropped truncated tails and ignored columns are reported on stderr, not only --clean."""
    (tmp_path / "a.txt").write_text(TUM_OK.replace("\n", " 9\n", 1) + "5 0 0")
    assert main(["info", str(tmp_path / "a.txt")]) == 0
    err = capsys.readouterr().err
    assert "40 of 41 rows kept" in err and "ignored extra column" in err
    assert "format guessed" in err and "incomplete" in err
