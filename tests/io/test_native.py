"""Native .tfrec recordings: round trips, crash safety (truncation, killed writer), corruption."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from _io_helpers import random_stream

from trackflow.io import (
    FLAG_CONFIDENCE,
    PoseStream,
    RecordingWriter,
    read_native,
    read_stream,
    write_native,
    write_stream,
)

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("covariance", [False, True])
def test_round_trip_exact(tmp_path, rng, covariance):
    s = random_stream(rng, 50, covariance=covariance, extras=True, source="tracker", target="ü")
    path = tmp_path / "a.tfrec"
    write_stream(path, s)
    back, report = read_stream(path)
    assert back == s
    assert report.rows_read == report.rows_kept == 50 and not report.changed
    assert report.format == "native"


def test_empty_recording(tmp_path):
    empty = PoseStream("a", "b", np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 4)))
    write_native(tmp_path / "e.tfrec", empty)
    back, report = read_native(tmp_path / "e.tfrec")
    assert back == empty and report.rows_read == 0


@pytest.mark.parametrize("covariance", [False, True])
def test_truncation_at_every_byte(tmp_path, rng, covariance):
    """A file cut at any byte after its header reads as the complete records before the cut."""
    n_rec = 2 if covariance else 4
    s = random_stream(rng, n_rec, covariance=covariance, extras=True)
    full = tmp_path / "full.tfrec"
    write_native(full, s)
    data = full.read_bytes()
    rec = 368 if covariance else 80
    header = len(data) - n_rec * rec
    cut = tmp_path / "cut.tfrec"
    for k in range(len(data) + 1):
        cut.write_bytes(data[:k])
        if k < header:
            # the writer renames a complete header into place, so this only happens to files
            # damaged otherwise: a clear error, never another exception
            with pytest.raises(ValueError, match="cut.tfrec"):
                read_native(cut)
            continue
        back, report = read_native(cut)
        n, tail = divmod(k - header, rec)
        assert back == s[:n], k
        assert report.truncated == (tail > 0)
        assert report.truncated_bytes == tail
        assert report.rows_read == n + (tail > 0) == report.rows_kept + report.rows_dropped


def test_zero_filled_tail_is_a_truncation(tmp_path, rng):
    s = random_stream(rng, 5)
    path = tmp_path / "z.tfrec"
    write_native(path, s)
    with open(path, "ab") as f:
        f.write(b"\0" * 80 * 3)  # what a power failure can leave behind
    back, report = read_native(path)
    assert back == s
    assert report.dropped == {"truncated tail": [5, 6, 7]}


def test_corrupt_record_in_the_middle(tmp_path, rng):
    s = random_stream(rng, 6)
    path = tmp_path / "c.tfrec"
    write_native(path, s)
    data = bytearray(path.read_bytes())
    header = len(data) - 6 * 80
    data[header + 2 * 80 + 20] ^= 0x10  # flip one bit inside record 2's position
    path.write_bytes(bytes(data))
    with pytest.raises(ValueError, match=r"c\.tfrec: record 2 .*corrupt"):
        read_native(path)
    back, report = read_native(path, clean=True)
    want = s[np.array([0, 1, 3, 4, 5])]
    assert np.array_equal(back.t_ns, want.t_ns)
    assert np.array_equal(back.position, want.position)
    # clean=True also makes quaternion signs continuous: same rotations, maybe negated
    dots = np.sum(back.quaternion * want.quaternion, axis=1)
    assert np.allclose(np.abs(dots), 1.0, atol=1e-15)
    assert report.dropped == {"corrupt record (check mismatch)": [2]}
    assert report.signs_fixed == bool(report.sign_flips)


def test_not_a_recording(tmp_path):
    p = tmp_path / "x.tfrec"
    p.write_text("hello world, this is not binary\n")
    with pytest.raises(ValueError, match="magic"):
        read_native(p)


def test_writer_append_and_recover(tmp_path, rng):
    s = random_stream(rng, 30, covariance=True)
    path = tmp_path / "w.tfrec"
    with RecordingWriter(path, "world", "body", covariance=True) as w:
        w.append(s[:10])
        for k in range(10, 15):
            w.append_sample(
                s.t_ns[k], s.position[k], s.quaternion[k], s.covariance[k], flags=s.flags[k]
            )
        with pytest.raises(ValueError, match="not after"):
            w.append(s[:1])
        with pytest.raises(ValueError, match="T_world_other"):
            w.append(s.with_(target="other")[15:])
    assert read_native(path)[0] == s[:15]
    with open(path, "ab") as f:  # a crash in the middle of the next record
        f.write(b"\x01" * 100)
    w = RecordingWriter(path, "world", "body", covariance=True, mode="a")
    assert w.recovered_bytes == 100 and w.count == 15
    w.append(s[15:])
    w.close()
    back, report = read_native(path)
    assert back == s and not report.changed
    with pytest.raises(ValueError, match="cannot append"):
        RecordingWriter(path, "world", "body", covariance=False, mode="a")
    with pytest.raises(ValueError, match="exists"):
        RecordingWriter(path, "world", "body", covariance=True, mode="x")


def test_confidence_flag(tmp_path):
    p = tmp_path / "c.tfrec"
    with RecordingWriter(p, "a", "b", covariance=False) as w:
        w.append_sample(5, [1, 2, 3], [0, 0, 0, 1], confidence=0.25, flags=3 | FLAG_CONFIDENCE)
        with pytest.raises(ValueError, match="confidence"):
            w.append_sample(6, [1, 2, 3], [0, 0, 0, 1], confidence=2.0)
        with pytest.raises(ValueError, match="unit length"):
            w.append_sample(7, [1, 2, 3], [0, 0, 0, 3.0])
    back, _ = read_native(p)
    assert back.confidence.tolist() == [0.25] and back.flags.tolist() == [11]


_CHILD = textwrap.dedent(
    """
    import sys
    import numpy as np
    from trackflow.io import RecordingWriter
    w = RecordingWriter(sys.argv[1], "world", "body", covariance=True)
    i = 0
    while True:
        c = np.eye(6) * (1.0 + i)
        w.append_sample(1000 * (i + 1), [i, 2.0 * i, -i], [0.0, 0.0, 0.0, 1.0], c)
        i += 1
        print(i, flush=True)
    """
)


def test_killed_writer_loses_at_most_one_record(tmp_path):
    delay = 0.5  # seconds of writing before SIGKILL (thousands of appends)
    path = tmp_path / "killed.tfrec"
    env = dict(os.environ, PYTHONPATH=str(REPO / "src"))
    child = subprocess.Popen(
        [sys.executable, "-c", _CHILD, str(path)], stdout=subprocess.PIPE, env=env, text=True
    )
    try:
        first = child.stdout.readline()  # the child is writing
        assert first.strip() == "1"
        time.sleep(delay)
        child.send_signal(signal.SIGKILL)
        reported = [int(x) for x in child.stdout.read().split()] or [1]
    finally:
        child.kill()
        child.wait()
    stream, report = read_native(path)
    n = len(stream)
    # every record the child said it finished is there; at most the one in progress is missing
    assert n >= reported[-1]
    assert n <= reported[-1] + 1
    i = np.arange(n)
    assert np.array_equal(stream.t_ns, 1000 * (i + 1))
    assert np.array_equal(stream.position, np.stack([i, 2.0 * i, -i], axis=1))
    assert np.array_equal(stream.covariance[:, 5, 5], 1.0 + i)
    assert report.rows_kept == n
