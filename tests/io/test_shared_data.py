"""Every real recording format in ../shared/data reads, with its documented quirks reported."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from trackflow.io import BROAD_RATE_HZ, guess_format, read_stream, write_stream

TUM_FILES = [
    "tumvi/dataset-room1_512_16.txt",
    "tumvi/dataset-room2_512_16.txt",
    "tumvi/dataset-room3_512_16.txt",
    "ar_table/table_01.txt",
    "ar_table/table_02.txt",
    "ar_table/table_03.txt",
    "ar_table/table_04.txt",
    "euroc/V1_01_easy_groundtruth_200hz.txt",
    "tum_rgbd/freiburg1_xyz-groundtruth.txt",
    "tum_rgbd/freiburg1_xyz-rgbdslam.txt",
    "quest_ur5e/quest2/robot_tcp_traj1.tum.txt",
]


def _check_counts(report):
    assert report.rows_read == report.rows_kept + report.rows_dropped


@pytest.mark.parametrize("name", TUM_FILES)
def test_tum_files_read_without_cleaning(shared_data, name):
    path = shared_data / name
    assert guess_format(path) == "tum"
    s, report = read_stream(path)
    _check_counts(report)
    assert report.rows_dropped == 0 and len(s) > 700
    assert np.all(np.diff(s.t_ns) > 0)
    # timestamps are the file's decimal text exactly: compare with the first line's token
    first = next(
        ln for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")
    )
    whole, frac = first.split()[0].split(".")
    assert s.t_ns[0] == int(whole) * 10**9 + int(frac.ljust(9, "0"))


def test_tum_rgbd_desk_has_a_repeated_stamp(shared_data):
    path = shared_data / "tum_rgbd/fr2_desk_groundtruth.txt"
    with pytest.raises(ValueError, match=r"fr2_desk_groundtruth\.txt:\d+: duplicated timestamp"):
        read_stream(path)
    s, report = read_stream(path, clean=True)
    _check_counts(report)
    assert report.rows_dropped == 1 and len(report.sign_flips) > 0 and report.signs_fixed
    assert np.all(np.sum(s.quaternion[1:] * s.quaternion[:-1], axis=1) >= 0)


def test_tumvi_sign_flips_counted(shared_data):
    s, report = read_stream(shared_data / "tumvi/dataset-room1_512_16.txt")
    dots = np.sum(s.quaternion[1:] * s.quaternion[:-1], axis=1)
    assert len(report.sign_flips) == int(np.sum(dots < 0)) >= 5


def test_quest_log(shared_data):
    path = shared_data / "quest_ur5e/quest2/traj1.txt"
    assert guess_format(path) == "quest"
    s, report = read_stream(path)
    _check_counts(report)
    assert report.truncated and report.dropped == {"truncated tail": [report.rows_read]}
    # Unity is y up; the mirror keeps y: the headset sits about 1.2-2 m above the floor
    assert 1.0 < np.median(s.position[:, 1]) < 2.2
    rate = 1e9 / np.median(np.diff(s.t_ns))
    assert 60 < rate < 90  # ~72 Hz
    # first sample's UTC ticks -> Unix ns exactly (column 2 of the first line)
    ticks = int(path.read_text().split("\n", 1)[0].split(",")[1])
    assert s.t_ns[0] == (ticks - 621355968000000000) * 100
    q_file = [float(x) for x in path.read_text().split("\n", 1)[0].split(",")[12:16]]
    assert s.quaternion[0] == pytest.approx(np.array(q_file) * [-1, -1, 1, 1], abs=1e-6)


def test_quest_excerpt_fixture():
    path = Path(__file__).parent / "data" / "quest_excerpt.txt"
    s, report = read_stream(path)
    assert len(s) == 30 and report.truncated and report.dropped == {"truncated tail": [31]}


def test_bag_matches_its_tum_export(shared_data):
    bag = shared_data / "quest_ur5e/quest2/robot_tcp_traj1.bag"
    s, report = read_stream(bag)
    _check_counts(report)
    assert report.format == "rosbag" and s.target == "my_ur5e/endeffpos"
    tum, _ = read_stream(shared_data / "quest_ur5e/quest2/robot_tcp_traj1.tum.txt")
    # the TUM export went through float seconds: its stamps are off by up to 1 ns
    assert np.max(np.abs(s.t_ns - tum.t_ns)) <= 1
    assert np.allclose(s.position, tum.position, atol=1e-9)
    assert np.allclose(s.quaternion, tum.quaternion, atol=1e-9)
    recv, _ = read_stream(bag, stamp="receive")
    lag = (recv.t_ns - s.t_ns) * 1e-9
    assert np.all(lag >= 0) and np.median(lag) < 0.05


def test_bag_rewritten_as_ros2(shared_data, tmp_path):
    s, _ = read_stream(shared_data / "quest_ur5e/quest2/robot_tcp_traj1.bag")
    s = s[:200]
    write_stream(tmp_path / "ros2bag", s, format="rosbag", msgtype="TransformStamped")
    back, _ = read_stream(tmp_path / "ros2bag")
    assert np.array_equal(back.position, s.position) and np.array_equal(back.t_ns, s.t_ns)


def test_broad_trial(shared_data):
    path = shared_data / "broad/06_undisturbed_fast_rotation_A.mat"
    s, report = read_stream(path)
    _check_counts(report)
    dropouts = report.dropped["mocap dropout (NaN row)"]
    assert len(dropouts) > 0 and report.rows_read == len(s) + len(dropouts)
    step = np.diff(s.t_ns)
    assert np.median(step) == pytest.approx(1e9 / BROAD_RATE_HZ, abs=1.0)
    from scipy.io import loadmat

    raw = loadmat(path)["opt_quat"]
    k = int(np.flatnonzero(~np.isnan(raw).any(axis=1))[0])
    assert s.quaternion[0] == pytest.approx(raw[k][[1, 2, 3, 0]])


def test_optitrack_unity_csv(shared_data):
    for name in ("opti.csv", "unity.csv"):
        path = shared_data / "quest_ur5e/optitrack_unity_example" / name
        assert guess_format(path) == "csv"
        s, report = read_stream(path)
        _check_counts(report)
        assert len(s) > 900 and s.duration_s > 12


@pytest.mark.parametrize("name", ["broad/01_undisturbed_slow_rotation_A.mat"])
def test_real_data_through_native_round_trip(shared_data, tmp_path, name):
    s, _ = read_stream(shared_data / name)
    write_stream(tmp_path / "x.tfrec", s)
    back, report = read_stream(tmp_path / "x.tfrec")
    assert back == s and not report.changed


def test_imu_csv_is_not_a_pose_file(shared_data):
    """The EuRoC IMU file looks like EuRoC csv but has 7 columns: a clear error, not garbage."""
    path = shared_data / "euroc/V1_01_easy_imu0.csv"
    assert guess_format(path) == "euroc"
    with pytest.raises(ValueError, match=r"V1_01_easy_imu0\.csv:2: short row: 7 columns"):
        read_stream(path)
