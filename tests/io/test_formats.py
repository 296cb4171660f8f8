"""Write -> read round trips for every format, format guessing and option handling."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _io_helpers import random_stream
from hypothesis import given, settings
from hypothesis import strategies as st

from trackflow.io import (
    BROAD_RATE_HZ,
    FLAG_COVARIANCE,
    PoseStream,
    guess_format,
    read_stream,
    write_stream,
)
from trackflow.math import cov_to_ros, quat_rotate

DATA = Path(__file__).parent / "data"


def _pose_only(s: PoseStream) -> PoseStream:
    """What formats without covariance, confidence or flags can hold."""
    return PoseStream(s.source, s.target, s.t_ns, s.position, s.quaternion)


@pytest.mark.parametrize("fmt, name", [("tum", "a.txt"), ("euroc", "a.csv")])
def test_pose_only_text_round_trip(tmp_path, rng, fmt, name):
    s = _pose_only(random_stream(rng, 40, source="map", target="cam"))
    path = tmp_path / name
    write_stream(path, s, format=fmt)
    back, report = read_stream(path, format=fmt)
    assert back == s  # bit-exact: decimal ns times, repr floats, frames from the comment
    assert report.rows_read == 40 and not report.changed
    assert guess_format(path) == fmt


@pytest.mark.parametrize("covariance", [False, True])
@pytest.mark.parametrize("time_unit", ["s", "ns"])
def test_csv_round_trip_all_fields(tmp_path, rng, covariance, time_unit):
    s = random_stream(rng, 25, covariance=covariance, extras=True)
    path = tmp_path / "a.csv"
    write_stream(path, s, time_unit=time_unit)
    back, _ = read_stream(path, time_unit=time_unit)
    assert back == s


def test_csv_column_mapping(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text("time_ms;w;i;j;k;px;py;pz\n10.5;1;0;0;0;1;2;3\n20.25;0;1;0;0;4;5;6\n")
    cols = {"t": "time_ms", "qw": "w", "qx": "i", "qy": "j", "qz": "k"}
    cols |= {"x": "px", "y": "py", "z": 7}
    s, _ = read_stream(path, format="csv", columns=cols, delimiter=";", time_unit="ms")
    assert s.t_ns.tolist() == [10_500_000, 20_250_000]
    assert s.position.tolist() == [[1, 2, 3], [4, 5, 6]]
    assert s.quaternion.tolist() == [[0, 0, 0, 1], [1, 0, 0, 0]]
    with pytest.raises(ValueError, match="no column named 'nope'"):
        read_stream(path, format="csv", columns={**cols, "x": "nope"}, delimiter=";")


def test_csv_auto_mapping_with_suffixes(tmp_path):
    path = tmp_path / "o.csv"
    path.write_text(
        "t_opti,x_opti,y_opti,z_opti,qx_opti,qy_opti,qz_opti,qw_opti\n0,1,2,3,0,0,0,1\n"
    )
    s, _ = read_stream(path)
    assert s.position.tolist() == [[1, 2, 3]]


def test_euroc_fixture(tmp_path):
    s, report = read_stream(DATA / "euroc_gt.csv")
    assert report.format == "euroc" and len(s) == 5
    assert s.t_ns[0] == 1403636580838555648  # integer ns kept exactly
    # w-first columns reordered: first row q_RS = (w, x, y, z) = (0.534108, -0.153029, ...)
    assert s.quaternion[0] == pytest.approx([-0.153029, -0.827383, -0.082152, 0.534108], abs=1e-5)
    assert s.position[0].tolist() == [4.688319, -1.786938, 0.783338]


def test_quest_round_trip_and_mirror(tmp_path, rng):
    s = random_stream(rng, 30, source="quest_world", target="quest_headset")
    s = s.with_(t_ns=s.t_ns - s.t_ns % 100)  # Quest logs hold 100 ns ticks
    path = tmp_path / "q.txt"
    write_stream(path, s, format="quest")
    back, report = read_stream(path)
    assert report.format == "quest"
    assert back == s
    # the file holds Unity's left-handed values: z of positions negated
    first = path.read_text().splitlines()[0].split(",")
    assert float(first[11]) == -s.position[0, 2]
    with pytest.raises(ValueError, match="100 ns"):
        write_stream(tmp_path / "r.txt", s.with_(t_ns=s.t_ns + 1), format="quest")


def test_quest_mirror_is_a_proper_change_of_handedness():
    """A point seen through Unity's pose maps like the mirrored point through ours."""
    q_unity = np.array([0.2, -0.3, 0.4, 0.8])
    q_unity /= np.linalg.norm(q_unity)
    p_unity = np.array([0.5, 1.6, -2.0])
    x_local = np.array([0.1, 0.2, 0.3])
    # Unity: x_world = R x_local + t, computed with its left-handed rotation of the same matrix
    r_unity = quat_rotate(q_unity, x_local) + p_unity
    mirror = np.array([1.0, 1.0, -1.0])
    q_ours = q_unity * np.array([-1.0, -1.0, 1.0, 1.0])
    ours = quat_rotate(q_ours, x_local * mirror) + p_unity * mirror
    assert ours == pytest.approx(r_unity * mirror, abs=1e-12)


def test_broad_round_trip(tmp_path, rng):
    n = 40
    grid = np.rint(np.arange(n) * (1e9 / BROAD_RATE_HZ)).astype(np.int64)
    idx = np.sort(rng.choice(n, size=30, replace=False))
    base = random_stream(rng, 30, source="optitrack", target="imu")
    s = base.with_(t_ns=grid[idx])
    path = tmp_path / "b.mat"
    write_stream(path, s)
    back, report = read_stream(path)
    assert back == s
    missing = sorted(set(range(idx[-1] + 1)) - set(idx.tolist()))
    assert report.dropped.get("mocap dropout (NaN row)", []) == missing
    with pytest.raises(ValueError, match="grid"):
        write_stream(tmp_path / "c.mat", s.with_(t_ns=s.t_ns + 7))


MSGTYPES = ["PoseStamped", "PoseWithCovarianceStamped", "TransformStamped", "Odometry"]


@pytest.mark.parametrize("ros", ["ros1", "ros2"])
@pytest.mark.parametrize("msgtype", MSGTYPES)
def test_rosbag_round_trip(tmp_path, rng, ros, msgtype):
    s = random_stream(rng, 15, covariance=True, source="map", target="tool")
    path = tmp_path / ("out.bag" if ros == "ros1" else "out_bag")
    write_stream(path, s, format="rosbag", msgtype=msgtype)
    back, report = read_stream(path)
    assert report.format == "rosbag" and report.rows_read == 15
    if ros == "ros2":  # the storage file inside the directory works too
        (db,) = path.glob("*.db3")
        assert read_stream(db)[0] == back
    assert (back.source, back.target) == ("map", "tool")
    assert np.array_equal(back.t_ns, s.t_ns)
    assert np.array_equal(back.position, s.position)
    assert np.array_equal(back.quaternion, s.quaternion)
    if msgtype in ("PoseWithCovarianceStamped", "Odometry"):
        # stored in ROS's convention and converted back
        assert np.allclose(back.covariance, s.covariance, rtol=1e-12, atol=1e-18)
        assert np.all(back.flags & FLAG_COVARIANCE)
    else:
        assert back.covariance is None


def test_rosbag_covariance_is_stored_in_ros_convention(tmp_path, rng):
    from rosbags.highlevel import AnyReader

    s = random_stream(rng, 3, covariance=True)
    path = tmp_path / "c.bag"
    write_stream(path, s)
    with AnyReader([path]) as reader:
        raw = [reader.deserialize(r, c.msgtype) for c, _, r in reader.messages()]
    stored = np.array([m.pose.covariance for m in raw]).reshape(3, 6, 6)
    assert np.allclose(stored, cov_to_ros(s.covariance, s.quaternion), rtol=1e-14, atol=0)
    # the rotation block differs from ours unless the rotation is trivial
    assert not np.allclose(stored[:, 3:, 3:], s.covariance[:, 3:, 3:])


def test_rosbag_unknown_covariance_clears_flag(tmp_path, rng):
    s = random_stream(rng, 4)  # no covariance: ROS gets zeros, meaning "unknown"
    path = tmp_path / "u.bag"
    write_stream(path, s, msgtype="PoseWithCovarianceStamped")
    back, report = read_stream(path)
    assert np.all(back.covariance == 0.0)
    assert not np.any(back.flags & FLAG_COVARIANCE)
    assert any("unknown covariance" in n for n in report.notes)


def test_options_and_formats_are_checked(tmp_path, rng):
    s = random_stream(rng, 3)
    with pytest.raises(ValueError, match="does not take option"):
        write_stream(tmp_path / "a.txt", s, colour="red")
    write_stream(tmp_path / "a.txt", s)
    with pytest.raises(ValueError, match="does not take option"):
        read_stream(tmp_path / "a.txt", topic="/x")
    with pytest.raises(ValueError, match="unknown format"):
        read_stream(tmp_path / "a.txt", format="xml")
    with pytest.raises(ValueError, match="format="):
        write_stream(tmp_path / "a.weird", s)


# positions beyond MAX_POSITION_M (1e9 m) are rejected as corrupt (tests/cli/test_malformed_cli)
_finite = st.floats(allow_nan=False, allow_infinity=False, width=64, min_value=-1e9, max_value=1e9)


@settings(max_examples=30, deadline=None)
@given(
    st.lists(st.tuples(_finite, _finite, _finite), min_size=1, max_size=5),
    st.integers(-(2**62), 2**62),
    st.sampled_from(["tum", "csv", "euroc", "native"]),
)
def test_any_float_round_trips_exactly(tmp_path_factory, rows, t0, fmt):
    """repr-written floats and decimal ns times read back bit for bit, whatever the value."""
    n = len(rows)
    t = t0 + np.arange(n, dtype=np.int64) * 7
    q = np.tile([0.0, 0.6, 0.0, 0.8], (n, 1))
    s = PoseStream("world", "body", t, np.array(rows, dtype=float), q)
    path = tmp_path_factory.mktemp("h") / f"x.{fmt}"
    write_stream(path, s, format=fmt)
    back, _ = read_stream(path, format=fmt)
    assert back == s
