"""Malformed input: ValueError naming file and line, or clean=True with a complete report."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackflow.io import read_stream
from trackflow.io._clean import _longest_increasing

DATA = Path(__file__).parent / "data"

GOOD = "0 0 0 0 0 0 0 1"


def _tum(tmp_path, lines: list[str], terminated: bool = True) -> Path:
    p = tmp_path / "m.txt"
    p.write_text("# t x y z qx qy qz qw\n" + "\n".join(lines) + ("\n" if terminated else ""))
    return p


def _row(t: str, rest: str = "0 0 0 0 0 0 1") -> str:
    return f"{t} {rest}"


CASES = [
    # (problem line content at file line 4, expected message part, report reason)
    (_row("1.2", "0 0"), "short row: 3 columns", "short row"),
    (_row("1.2", "0 0 x 0 0 0 1"), "unparsable value", "unparsable value"),
    (_row("abc"), "not a number", "unparsable value"),
    (_row("1.2", "nan 0 0 0 0 0 1"), "NaN or inf", "NaN or inf value"),
    (_row("1.2", "0 0 inf 0 0 0 1"), "NaN or inf", "NaN or inf value"),
    (_row("1.2", "0 0 0 0 0 0 0"), "quaternion is zero", "zero quaternion"),
    (_row("1.1"), "duplicated timestamp", "duplicated timestamp"),
    (_row("1.05"), "goes back in time", "non-increasing timestamp"),
]


@pytest.mark.parametrize("bad, message, reason", CASES)
def test_error_names_file_and_line(tmp_path, bad, message, reason):
    # file line 1 is the header comment, lines 2-3 are good, line 4 is bad, line 5 good
    path = _tum(tmp_path, [_row("1.0"), _row("1.1"), bad, _row("1.3")])
    with pytest.raises(ValueError, match=rf"m\.txt:4: .*{message}"):
        read_stream(path)
    stream, report = read_stream(path, clean=True)
    assert len(stream) == 3
    assert report.dropped == {reason: [4]}
    assert report.rows_read == 4 and report.rows_kept == 3 and report.changed


def test_unnormalised_quaternion(tmp_path):
    path = _tum(tmp_path, [_row("1.0"), _row("1.1", "0 0 0 0 0 0.1 1.0"), _row("1.2")])
    with pytest.raises(ValueError, match=r"m\.txt:3: quaternion .* not unit"):
        read_stream(path)
    s, report = read_stream(path, clean=True)
    assert report.normalized == [3] and not report.dropped
    assert s.quaternion[1] == pytest.approx(np.array([0, 0, 0.1, 1.0]) / np.sqrt(1.01))
    # rounding of printed digits is not an error: 0.7071 twice has |q| - 1 = -1.1e-5
    ok = _tum(tmp_path, [_row("1.0", "0 0 0 0.7071 0 0 0.7071")])
    s, report = read_stream(ok)
    assert np.linalg.norm(s.quaternion[0]) == pytest.approx(1.0, abs=1e-15)
    assert report.normalized == [] and "within the rounding" in report.notes[0]


def test_sign_flips_reported_and_fixed(tmp_path):
    rows = [_row("1.0"), _row("1.1", "0 0 0 0 0 0 -1"), _row("1.2", "0 0 0 0 0 0 -1")]
    path = _tum(tmp_path, rows + [_row("1.3")])
    s, report = read_stream(path)  # q and -q are the same rotation: not an error
    assert report.sign_flips == [3, 5] and not report.signs_fixed
    assert s.quaternion[:, 3].tolist() == [1, -1, -1, 1]
    s, report = read_stream(path, clean=True)
    assert report.sign_flips == [3, 5] and report.signs_fixed and report.changed
    assert s.quaternion[:, 3].tolist() == [1, 1, 1, 1]


def test_one_wild_timestamp_costs_one_row(tmp_path):
    times = ["1.0", "1.1", "9.9", "1.2", "1.3", "1.4"]
    path = _tum(tmp_path, [_row(t) for t in times])
    s, report = read_stream(path, clean=True)
    assert report.dropped == {"non-increasing timestamp": [4]}  # the 9.9 line
    assert len(s) == 5


def test_truncated_last_line_is_reported_not_an_error(tmp_path):
    path = _tum(tmp_path, [_row("1.0"), _row("1.1"), "1.2 0.5 0.2"], terminated=False)
    s, report = read_stream(path)
    assert len(s) == 2 and report.truncated
    assert report.dropped == {"truncated tail": [4]}
    assert report.truncated_bytes == len("1.2 0.5 0.2")
    # a cut inside the last number still parses but leaves a non-unit quaternion
    cut = _tum(
        tmp_path,
        [_row("1.0"), _row("1.1", "0 0 0 0 0 0.6 0.8"), "1.2 0 0 0 0 0 0.6 0.8"[:-1]],
        terminated=False,
    )
    s, report = read_stream(cut)
    assert len(s) == 2 and report.dropped == {"truncated tail": [4]}
    # the same content in a terminated last line is an ordinary error
    with pytest.raises(ValueError, match=r"m\.txt:3: short row"):
        read_stream(_tum(tmp_path, [_row("1.0"), "1.2 0.5 0.2"]))


def test_shipped_malformed_fixture():
    path = DATA / "malformed.tum"
    with pytest.raises(ValueError, match=r"malformed\.tum:4: short row"):
        read_stream(path)
    s, report = read_stream(path, clean=True)
    assert report.rows_read == 11 and report.rows_kept == 7 == len(s)
    assert report.dropped == {
        "short row": [4],
        "NaN or inf value": [5],
        "duplicated timestamp": [7],
        "non-increasing timestamp": [8],
    }
    assert report.normalized == [9]
    assert report.sign_flips == [10, 12] and report.signs_fixed
    assert s.t_ns.tolist() == [1_000_000_000 + k * 10_000_000 for k in (0, 1, 4, 5, 6, 7, 8)]
    assert np.all(np.sum(s.quaternion[1:] * s.quaternion[:-1], axis=1) > 0)
    text = report.summary()
    assert "short row" in text and "line 4" in text
    d = report.as_dict()
    assert d["rows_dropped"] == 4


def test_csv_and_euroc_errors_name_lines(tmp_path):
    p = tmp_path / "a.csv"
    p.write_text("t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n1,0,0,0,0,0,0\n")
    with pytest.raises(ValueError, match=r"a\.csv:3: short row"):
        read_stream(p)
    e = tmp_path / "e.csv"
    e.write_text("#timestamp, x, y, z, qw, qx, qy, qz\n10,0,0,0,1,0,0,0\n10,0,0,0,1,0,0,0\n")
    with pytest.raises(ValueError, match=r"e\.csv:3: duplicated timestamp"):
        read_stream(e)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(0, 12), max_size=14))
def test_longest_increasing_subsequence_is_longest(values):
    t = np.array(values, dtype=np.int64)
    idx = _longest_increasing(t)
    assert np.all(np.diff(idx) > 0) and np.all(np.diff(t[idx]) > 0)
    # O(n^2) reference length
    best = [1] * len(values)
    for i in range(len(values)):
        for j in range(i):
            if values[j] < values[i]:
                best[i] = max(best[i], best[j] + 1)
    assert len(idx) == max(best, default=0)
