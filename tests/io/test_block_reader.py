"""The block reader of text recordings (issue 12, ``info`` memory).

Text files are parsed a block of lines at a time into preallocated arrays. These tests check
that it gives exactly what the former reader (every line of the file in a list, frozen in
``_reference_reader.py``) gave: the same arrays bit for bit, the same read report and the same
errors, on the real recordings and on crafted files whose awkward lines sit at block
boundaries (tiny blocks), and that its peak memory stays near the size of its arrays.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from unittest import mock

import _reference_reader
import numpy as np
import pytest
from _io_helpers import write_big_tum
from hypothesis import given, settings
from hypothesis import strategies as st

import trackflow.io._devices as devices_mod
import trackflow.io._imu as imu_mod
import trackflow.io._kitti as kitti_mod
import trackflow.io._table as table_mod
import trackflow.io._text as text_mod
from trackflow.io import read_imu, read_stream

SHARED_TEXT = [
    ("tumvi/dataset-room1_512_16.txt", "tum"),
    ("tumvi/dataset-room2_512_16.txt", "tum"),
    ("tumvi/dataset-room3_512_16.txt", "tum"),
    ("ar_table/table_01.txt", "tum"),
    ("ar_table/table_02.txt", "tum"),
    ("ar_table/table_03.txt", "tum"),
    ("ar_table/table_04.txt", "tum"),
    ("euroc/V1_01_easy_groundtruth_200hz.txt", "tum"),
    ("tum_rgbd/freiburg1_xyz-groundtruth.txt", "tum"),
    ("tum_rgbd/freiburg1_xyz-rgbdslam.txt", "tum"),
    ("tum_rgbd/fr2_desk_groundtruth.txt", "tum"),
    ("quest_ur5e/quest2/robot_tcp_traj1.tum.txt", "tum"),
    ("quest_ur5e/quest2/robot_tcp_calib.tum.txt", "tum"),
    ("quest_ur5e/quest2/traj1.txt", "quest"),
    ("quest_ur5e/quest2/calib.txt", "quest"),
    ("quest_ur5e/optitrack_unity_example/opti.csv", "csv"),
    ("quest_ur5e/optitrack_unity_example/unity.csv", "csv"),
]


@contextmanager
def _reference():
    """Read with the former line-list parser in every text reader."""
    ref = _reference_reader.parse_rows
    with (
        mock.patch.object(text_mod, "parse_rows", ref),
        mock.patch.object(devices_mod, "parse_rows", ref),
        mock.patch.object(kitti_mod, "parse_rows", ref),
        mock.patch.object(imu_mod, "parse_rows", ref),
    ):
        yield


def _outcome(read, block_bytes: int | None):
    """``("ok", arrays, report dict)`` or ``("error", type, message)`` of ``read()``."""
    with mock.patch.object(table_mod, "BLOCK_BYTES", block_bytes or table_mod.BLOCK_BYTES):
        try:
            stream, report = read()
        except ValueError as exc:
            return ("error", type(exc).__name__, str(exc))
    names = ("t_ns", "position", "quaternion", "covariance", "confidence", "flags")
    names = [n for n in names if hasattr(stream, n)] or ["t_ns", "gyro", "accel"]
    arrays = {n: getattr(stream, n) for n in names}
    return ("ok", arrays, report.as_dict(), getattr(stream, "source", None))


def _assert_same(read, *blocks: int | None) -> tuple:
    """``read()`` with block sizes ``blocks`` (default: the default one) gives what the former
    reader gives; returns the outcome."""
    with _reference():
        old = _outcome(read, None)
    for block_bytes in blocks or (None,):
        new = _outcome(read, block_bytes)
        _compare(read, new, old)
    return new


def _compare(read, new: tuple, old: tuple) -> None:
    assert new[0] == old[0], (new, old)
    if new[0] == "error":
        assert new == old
        return
    if new[2] != old[2]:
        _only_extra_columns_note_differs(read, new[2], old[2])
    else:
        assert new[2] == old[2]  # the read report: counts, drops, lines, notes
    assert new[3] == old[3]
    for name, a in old[1].items():
        b = new[1][name]
        if a is None:
            assert b is None, name
            continue
        assert a.dtype == b.dtype and a.shape == b.shape, name
        # bit for bit (NaN-safe): the same bytes
        assert np.ascontiguousarray(a).tobytes() == np.ascontiguousarray(b).tobytes(), name


EXTRA = "ignored extra column(s) beyond the first"


def _only_extra_columns_note_differs(read, new: dict, old: dict) -> None:
    """The one intended change: the former reader noted ignored extra columns only when its
    first data row had them (unless some row was malformed); now any row with them counts."""
    assert {**new, "notes": []} == {**old, "notes": []}
    assert [n for n in new["notes"] if EXTRA not in n] == old["notes"]
    assert not any(EXTRA in n for n in old["notes"]) and any(EXTRA in n for n in new["notes"])
    path = read.args[0]
    rows = [ln.split() for ln in Path(path).read_text("utf-8-sig").splitlines()]
    rows = [r for r in rows if r and not r[0].startswith("#")]
    assert read.keywords.get("format") == "tum" and any(len(r) > 8 for r in rows)


@pytest.mark.parametrize("name, fmt", SHARED_TEXT)
@pytest.mark.parametrize("clean", [False, True])
def test_shared_recordings_read_as_before(shared_data, name, fmt, clean):
    path = shared_data / name
    out = _assert_same(partial(read_stream, path, format=fmt, clean=clean))
    if name.startswith("tum_rgbd/fr2_desk") and not clean:
        assert out[0] == "error" and "duplicated timestamp" in out[2]
    else:
        assert out[0] == "ok" and len(out[1]["t_ns"]) > 100


@pytest.mark.parametrize("block", [4096, 1 << 14])
def test_shared_recordings_in_small_blocks(shared_data, block):
    for name, fmt in SHARED_TEXT[3:4] + SHARED_TEXT[13:14] + SHARED_TEXT[15:16]:
        path = shared_data / name
        out = _assert_same(partial(read_stream, path, format=fmt), block)
        assert out[0] == "ok"


def test_euroc_imu_reads_as_before(shared_data):
    path = shared_data / "euroc" / "V1_01_easy_imu0.csv"
    out = _assert_same(partial(read_imu, path), 1 << 14)
    assert out[0] == "ok" and len(out[1]["t_ns"]) > 1000


# -- crafted files ---------------------------------------------------------------------------
GOOD = [f"{1.0 + k / 10:.1f} {k * 0.01:.2f} 0.5 -1e-3 0 0 0.6 0.8" for k in range(40)]


def _write(d: Path, lines: list[str], *, eol="\n", terminated=True, bom=False) -> Path:
    p = d / "f.txt"
    text = eol.join(lines) + (eol if terminated and lines else "")
    p.write_bytes((b"\xef\xbb\xbf" if bom else b"") + text.encode("utf-8"))
    return p


def _with(lines: list[str], at: int, line: str) -> list[str]:
    return lines[:at] + [line] + lines[at:]


BAD_LINES = [
    "2.15 0 0",  # short row
    "2.15 0 0 x 0 0 0 1",  # unparsable value
    "abc 0 0 0 0 0 0 1",  # unparsable time
    "2.15 nan 0 0 0 0 0 1",  # NaN
    "2.15 0 0 0 0 0 0 0",  # zero quaternion
    "2.15 0 0 0 0 0 0.61 0.8",  # non-unit beyond the printed digits
    "2.15 0 0 0 0 0 0.6001 0.8",  # non-unit within 2 units of the last digit
    "1.5 0 0 0 0 0 0.6 0.8",  # duplicated timestamp
    "1.25 0 0 0 0 0 0.6 0.8",  # back in time
    "2.15 0 0 0 0 0 0.6 0.8 9 9",  # extra columns
    "2.15 0 0 0 -0 -0 -0.6 -0.8",  # sign flip
    "# trackflow: source=map target=rig",
    "",
    "   ",
    "\t2.15 0 0 0 0 0 0.6 0.8  ",
    "2.15 1e-3 0 0 0 0 6e-1 8e-1",
    "2.15 0 0 0 0 0 0.59999999 0.80000001",
    "2.15000000000000000000000000000000000000000000000000001 0 0 0 0 0 0.6 0.8",  # long time
    "2.15e0 0 0 0 0 0 0.6 0.8",  # exponent notation in the time
]


@pytest.mark.parametrize("bad", BAD_LINES)
@pytest.mark.parametrize("clean", [False, True])
def test_awkward_line_at_every_block_position(tmp_path, bad, clean):
    """One awkward line at each position, blocks of a few lines: it falls at a block's first
    and last line and straddles block boundaries (a block ends only at a newline)."""
    for at in (0, 1, 6, 7, 39, 40):
        lines = _with(GOOD[:10] + [g.replace("1.", "2.", 1) for g in GOOD[10:]], at, bad)
        lines = sorted(lines[:at], key=_t) + lines[at:] if at else lines
        for terminated in (True, False):
            path = _write(tmp_path, lines, terminated=terminated)
            _assert_same(partial(read_stream, path, format="tum", clean=clean), 1, 37, 150)


def _t(line: str) -> float:
    try:
        return float(line.split()[0])
    except (ValueError, IndexError):
        return 0.0


@pytest.mark.parametrize("eol", ["\n", "\r\n"])
@pytest.mark.parametrize("bom", [False, True])
@pytest.mark.parametrize("terminated", [True, False])
def test_line_endings_bom_comments_and_tails(tmp_path, eol, bom, terminated):
    lines = ["# t x y z qx qy qz qw", "", *GOOD[:12], "# note", *GOOD[12:30]]
    for cut in (None, 5, 20):  # an unterminated last line cut off mid-number
        body = lines if cut is None else lines[:-1] + [lines[-1][:cut]]
        path = _write(tmp_path, body, eol=eol, terminated=terminated, bom=bom)
        for clean in (False, True):
            read = partial(read_stream, path, format="tum", clean=clean)
            _assert_same(read, 1, 50, 1 << 20)


def test_binary_and_invalid_utf8_errors_name_the_line(tmp_path):
    for bad in (b"1.0 0 0 0 0 0 0 \x001\n", b"1.0 0 0 0 0 0 0 \xff\n"):
        path = tmp_path / "b.txt"
        path.write_bytes(("\n".join(GOOD[:25]) + "\n").encode() + bad + b"9 0 0 0 0 0 0 1\n")
        out = _assert_same(partial(read_stream, path, format="tum"), 16, 1 << 20)
        assert out[0] == "error" and ":26: not" in out[2]


def test_csv_euroc_quest_kitti_as_before(tmp_path):
    csv = ["t,x,y,z,qx,qy,qz,qw,confidence"] + [
        f"{k}.5, {k}, 0, 0, 0, 0, 0.6, 0.8, 0.{k % 10}" for k in range(30)
    ]
    euroc = ["#timestamp [ns],x,y,z,qw,qx,qy,qz"] + [
        f"{k}000,{k},0,0,0.8,0,0,0.6,1,2" for k in range(1, 30)
    ]
    quest = [
        f"{637000000000000000 + k * 1000},{637000000000000000 + k * 1000},2020,1,1,0,0,0,0,"
        f"{k},1.5,2,0,0,0.6,0.8"
        for k in range(30)
    ]
    kitti = [f"1 0 0 {k} 0 1 0 0 0 0 1 0" for k in range(30)]
    cases = [("csv", csv), ("euroc", euroc), ("quest", quest), ("kitti", kitti)]
    for fmt, lines in cases:
        for bad_at in (None, 3, 17):
            body = lines if bad_at is None else _with(lines, bad_at, "1,2,oops")
            for terminated in (True, False):
                path = _write(tmp_path, body, terminated=terminated)
                for clean in (False, True):
                    read = partial(read_stream, path, format=fmt, clean=clean)
                    out = _assert_same(read, 1, 40, 1 << 20)
                    assert out[0] == ("error" if bad_at and not clean else "ok"), out


def test_stdin_reads_as_a_file(tmp_path, monkeypatch):
    path = _write(tmp_path, GOOD[:30] + ["2.15 0 0"], terminated=False)

    class _Stdin:
        buffer = open(path, "rb")

    monkeypatch.setattr(sys, "stdin", _Stdin)
    try:
        s, report = read_stream("-", format="tum")
    finally:
        _Stdin.buffer.close()
    assert len(s) == 30 and report.path == "<stdin>" and report.dropped == {"truncated tail": [31]}


# -- fuzzing ---------------------------------------------------------------------------------
_FIELD = st.sampled_from(["0", "0.5", "-1.25", "1e-3", "nan", "x", "0.60", "0.8", "", "-0"])
_LINE = st.one_of(
    st.sampled_from(GOOD),
    st.sampled_from(BAD_LINES),
    st.lists(_FIELD, min_size=0, max_size=10).map(" ".join),
    st.tuples(st.floats(0, 9, allow_nan=False), st.lists(_FIELD, min_size=7, max_size=8)).map(
        lambda t: f"{t[0]:.3f} " + " ".join(t[1])
    ),
)


@settings(max_examples=150, deadline=None)
@given(
    lines=st.lists(_LINE, max_size=30),
    eol=st.sampled_from(["\n", "\r\n"]),
    terminated=st.booleans(),
    bom=st.booleans(),
    block=st.integers(1, 200),
    clean=st.booleans(),
)
def test_fuzzed_files_read_as_before(lines, eol, terminated, bom, block, clean):
    with tempfile.TemporaryDirectory() as d:
        path = _write(Path(d), lines, eol=eol, terminated=terminated, bom=bom)
        _assert_same(partial(read_stream, path, format="tum", clean=clean), block)


# -- memory ----------------------------------------------------------------------------------
_CHILD = """
import json, sys
import trackflow.evaluation, trackflow.io


def status(key):  # kB, of this process's own memory map (not inherited from the parent)
    with open("/proc/self/status") as f:
        return next(int(ln.split()[1]) for ln in f if ln.startswith(key + ":"))


rss0 = status("VmRSS")
with open("/proc/self/clear_refs", "w") as f:
    f.write("5")  # reset the high-water mark: the peak of what follows, not of the imports
stream, _ = trackflow.io.read_stream(sys.argv[1])
trackflow.evaluation.stream_info(stream)
print(json.dumps({"rss0": rss0, "peak": status("VmHWM")}))
"""


def _peak_above_imports(path: Path) -> int:
    """Peak resident memory [bytes] of reading and summarising ``path`` in a fresh
    interpreter, above its resident memory once the modules are imported."""
    out = subprocess.run(
        [sys.executable, "-c", _CHILD, str(path)], capture_output=True, text=True, timeout=300
    )
    if "clear_refs" in out.stderr:
        pytest.skip("this kernel cannot reset a process's peak memory (/proc/self/clear_refs)")
    assert out.returncode == 0, out.stderr
    kb = json.loads(out.stdout)
    return (kb["peak"] - kb["rss0"]) * 1024


@pytest.mark.slow
@pytest.mark.skipif(sys.platform != "linux", reason="ru_maxrss units and page accounting")
def test_peak_memory_stays_near_the_arrays(tmp_path):
    """Reading and summarising a 39 MB TUM file (like ``trackflow info``) peaks at less than
    twice the file's size above the memory of the imported modules (measured 1.56 times; the
    former reader 5.63 times; the stream's arrays alone are 0.98 times)."""
    path = tmp_path / "big.txt"
    write_big_tum(path, 500_000)
    size = path.stat().st_size
    assert size > 35e6
    used = _peak_above_imports(path)
    assert used < 2.0 * size, f"{used / 1e6:.0f} MB for a {size / 1e6:.0f} MB file"


def test_row_bound_holds_and_growth_is_exact(tmp_path):
    """The preallocation bound from the file size is never exceeded by a real file (densest
    rows possible), and if it were, the arrays grow without changing a bit."""
    dense = ["1 0 0 0 0 0 0 1", "2 0 0 0 0 0 0 1", "3 0 0 0 0 0 0 1"]
    path = _write(tmp_path, dense, terminated=False)
    size = path.stat().st_size
    assert table_mod._max_rows(3, size, None, 8, 8) == 3
    csv = _write(tmp_path, ["1,,,,,,,,0,0,0,0,0,0,1,0"], terminated=False)  # quest-like, empty
    assert table_mod._max_rows(1, csv.stat().st_size, ",", 16, 8) == 1
    lines = GOOD[:30] + ["# c", "2.15 0 0"] + [g.replace("1.", "5.", 1) for g in GOOD[:5]]
    path = _write(tmp_path, lines)
    with mock.patch.object(table_mod, "_max_rows", lambda *a: 1):
        out = _assert_same(partial(read_stream, path, format="tum", clean=True), 40, 1 << 20)
        assert out[0] == "ok" and len(out[1]["t_ns"]) == 35
