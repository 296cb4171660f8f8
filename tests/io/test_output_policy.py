"""The one output policy of every writer: atomic, no silent overwrite, nothing left behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from trackflow.io import (
    BROAD_RATE_HZ,
    PoseStream,
    atomic_output,
    read_stream,
    remove_stale_temporaries,
    write_stream,
)

SRC = Path(__file__).resolve().parents[2] / "src"


def _stream(n: int = 20) -> PoseStream:
    t = np.rint(np.arange(n) * (1e9 / BROAD_RATE_HZ)).astype(np.int64)  # on the BROAD grid
    ang = np.linspace(0, 1, n)
    q = np.stack([np.zeros(n), np.zeros(n), np.sin(ang / 2), np.cos(ang / 2)], axis=1)
    return PoseStream("world", "body", t, np.stack([ang, -ang, ang**2], axis=1), q)


# file name, format
TARGETS = [
    ("a.tfrec", "native"),
    ("a.txt", "tum"),
    ("a.euroc", "euroc"),
    ("a.csv", "csv"),
    ("a.quest", "quest"),
    ("a.mat", "broad"),
    ("a.kitti", "kitti"),
    ("a.bag", "rosbag"),
    ("a_ros2", "rosbag"),
]


def _leftovers(d: Path) -> list[str]:
    return [p.name for p in d.iterdir() if ".tftmp-" in p.name]


def _content(p: Path) -> bytes:
    if p.is_dir():
        return b"".join(f.read_bytes() for f in sorted(p.rglob("*")) if f.is_file())
    return p.read_bytes()


@pytest.mark.parametrize("name,fmt", TARGETS, ids=[t[0] for t in TARGETS])
def test_refuses_overwrite_then_replaces_with_overwrite(name, fmt, tmp_path):
    s = _stream()
    if fmt == "quest":
        s = s.with_(t_ns=s.t_ns - s.t_ns % 100 + np.arange(len(s)) * 100)
    path = tmp_path / name
    write_stream(path, s, format=fmt)
    first = _content(path)
    back, _ = read_stream(path, format=fmt)
    assert len(back) == len(s)
    with pytest.raises(FileExistsError, match="exists already"):
        write_stream(path, s[:5], format=fmt)
    assert _content(path) == first
    write_stream(path, s[:5], format=fmt, overwrite=True)
    back, _ = read_stream(path, format=fmt)
    assert len(back) == 5
    assert _leftovers(tmp_path) == []


def test_failed_write_leaves_nothing(tmp_path, monkeypatch):
    from trackflow.io import RecordingWriter

    def boom(self, stream):
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(RecordingWriter, "append", boom)
    (tmp_path / "keep.tfrec").write_bytes(b"old")
    for name, ow in (("new.tfrec", False), ("keep.tfrec", True)):
        with pytest.raises(OSError, match="disk full"):
            write_stream(tmp_path / name, _stream(), overwrite=ow)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.tfrec"]
    assert (tmp_path / "keep.tfrec").read_bytes() == b"old"


def test_failed_ros2_bag_leaves_no_directory(tmp_path, monkeypatch):
    from rosbags.rosbag2 import Writer

    def boom(self, *a, **k):
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(Writer, "write", boom)
    with pytest.raises(OSError, match="disk full"):
        write_stream(tmp_path / "bag", _stream(), format="rosbag")
    assert list(tmp_path.iterdir()) == []


def test_stale_temporaries_of_dead_processes_are_removed(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True).stdout.strip()  # fmt: skip
    stale = tmp_path / f".x.txt.tftmp-{dead}-0123abcd"
    stale.write_text("partial")
    mine = tmp_path / f".y.txt.tftmp-{os.getpid()}-0123abcd"
    mine.write_text("in progress")
    assert remove_stale_temporaries(tmp_path) == [stale]
    assert not stale.exists() and mine.exists()


def test_standard_output(capsys):
    write_stream("-", _stream(3))
    out = capsys.readouterr().out
    assert out.count("\n") == 5 and out.startswith("# trackflow: source=world target=body")


def test_atomic_output_refuses_directory_to_stdout():
    with pytest.raises(ValueError, match="standard output"):
        with atomic_output("-", directory=True):
            pass


_SLOW_CONVERT = textwrap.dedent(
    """
    import signal, sys, time
    from pathlib import Path
    from trackflow.cli.main import main

    # Ctrl-C raises KeyboardInterrupt even if the test runs with SIGINT ignored (inherited)
    signal.signal(signal.SIGINT, signal.default_int_handler)

    real = Path.write_text

    def slow(self, text, *a, **k):  # half the file, then wait to be killed
        with open(self, "w") as f:
            f.write(text[: len(text) // 2])
            f.flush()
        print("READY", flush=True)
        time.sleep(60)
        return real(self, text, *a, **k)

    Path.write_text = slow
    sys.exit(main(["convert", "in.txt", "out.txt", "--force", "--quiet"]))
    """
)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT, signal.SIGKILL])
def test_killed_convert_keeps_the_old_file(sig, tmp_path):
    """Killing ``convert`` mid-write never damages the existing output (issue: truncated to 0)."""
    s = _stream(50)
    write_stream(tmp_path / "in.txt", s)
    (tmp_path / "out.txt").write_text("precious\n")
    env = dict(os.environ, PYTHONPATH=str(SRC))
    proc = subprocess.Popen([sys.executable, "-c", _SLOW_CONVERT], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip
    try:
        assert proc.stdout.readline().strip() == b"READY"
        proc.send_signal(sig)
        proc.wait(timeout=30)
    finally:
        proc.kill()
        proc.wait(timeout=30)
    assert (tmp_path / "out.txt").read_text() == "precious\n"
    left = _leftovers(tmp_path)
    if sig == signal.SIGKILL:  # cannot be caught: the hidden temporary stays until next write
        assert len(left) == 1
        write_stream(tmp_path / "other.txt", s)
        assert _leftovers(tmp_path) == []
    else:
        assert proc.returncode in (130, 128 + sig)
        assert left == []
