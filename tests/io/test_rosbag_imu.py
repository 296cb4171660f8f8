"""``sensor_msgs/Imu`` in ROS 1 and ROS 2 bags (both storages): every field and covariance
round trips, REP 145's ``-1`` markers, and the conversion of the orientation covariance."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.errors import FormatError
from trackflow.io import ImuStream, read_imu, read_rosbag_imu, write_rosbag_imu
from trackflow.math import quat_exp, quat_to_matrix

pytest.importorskip("rosbags")

BAGS = {"mcap": "imu.mcap", "sqlite3": "imu.db3", "ros1": "imu.bag"}


def _messages(bag):
    """(bag time, message) of every message, read by rosbags alone."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if bag.suffix == ".bag" else Stores.ROS2_HUMBLE)
    with AnyReader([bag], default_typestore=store) as reader:
        return [(t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages()]


def _spd(rng, n, scale):
    a = rng.normal(size=(n, 3, 3)) * scale
    return a @ np.swapaxes(a, 1, 2)


@pytest.fixture
def euroc_imu(shared_data):
    path = shared_data / "euroc" / "V1_01_easy_imu0.csv"
    if not path.is_file():
        pytest.skip(f"{path} is missing: the IMU round trip needs a real IMU recording")
    imu, _ = read_imu(path, frame="imu0")
    return imu.select(slice(0, 400))  # 2 s at 200 Hz: every field, a few hundred messages


@pytest.mark.parametrize("kind", sorted(BAGS))
def test_a_real_imu_round_trips_with_every_covariance(tmp_path, rng, euroc_imu, kind):
    n = len(euroc_imu)
    q = quat_exp(rng.normal(scale=1.0, size=(n, 3)))
    full = ImuStream(
        euroc_imu.t_ns,
        euroc_imu.gyro,
        euroc_imu.accel,
        None,
        "imu0",
        orientation=q,
        orientation_covariance=_spd(rng, n, 1e-2),
        gyro_covariance=_spd(rng, n, 1e-3),
        accel_covariance=_spd(rng, n, 1e-2),
    )
    given = tmp_path / BAGS[kind]
    bag = write_rosbag_imu(given, full)
    assert bag == (given if kind == "ros1" else tmp_path / "imu")

    msgs = _messages(bag)
    assert len(msgs) == n
    for k, (t_bag, m) in enumerate(msgs):
        assert t_bag == full.t_ns[k] and m.header.frame_id == "imu0"
        assert m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec == full.t_ns[k]
        w, a, o = m.angular_velocity, m.linear_acceleration, m.orientation
        assert [w.x, w.y, w.z] == full.gyro[k].tolist()
        assert [a.x, a.y, a.z] == full.accel[k].tolist()
        assert [o.x, o.y, o.z, o.w] == full.orientation[k].tolist()
        # rates in the sensor frame: stored as they are, row-major
        assert np.array_equal(m.angular_velocity_covariance, full.gyro_covariance[k].ravel())
        assert np.array_equal(m.linear_acceleration_covariance, full.accel_covariance[k].ravel())
        # orientation: about the fixed axes in ROS, dphi = R dtheta -> C_ros = R C R^T
        r = quat_to_matrix(full.orientation[k])
        want = r @ full.orientation_covariance[k] @ r.T
        np.testing.assert_allclose(
            m.orientation_covariance.reshape(3, 3), want, rtol=1e-13, atol=1e-20
        )

    back, report = read_imu(given)  # format guessed from the name, read under it
    assert report.format == "rosbag" and report.rows_read == report.rows_kept == n
    assert back.frame == "imu0" and back.mag is None
    assert np.array_equal(back.t_ns, full.t_ns)
    assert np.array_equal(back.gyro, full.gyro) and np.array_equal(back.accel, full.accel)
    assert np.array_equal(back.orientation, full.orientation)
    assert np.array_equal(back.gyro_covariance, full.gyro_covariance)
    assert np.array_equal(back.accel_covariance, full.accel_covariance)
    np.testing.assert_allclose(
        back.orientation_covariance, full.orientation_covariance, rtol=1e-12, atol=1e-20
    )


def test_an_imu_without_orientation_says_so_as_rep_145_asks(tmp_path, euroc_imu):
    bag = write_rosbag_imu(tmp_path / "plain.mcap", euroc_imu, topic="/imu0")
    msgs = _messages(bag)
    assert all(m.orientation_covariance[0] == -1.0 for _, m in msgs)
    assert all(np.all(m.angular_velocity_covariance == 0.0) for _, m in msgs)  # unknown
    back, _ = read_rosbag_imu(bag, topic="/imu0")
    assert back.orientation is None and back.orientation_covariance is None
    assert back.gyro_covariance is None and back.accel_covariance is None
    assert np.array_equal(back.gyro, euroc_imu.gyro) and np.array_equal(back.t_ns, euroc_imu.t_ns)


def _imu_bag(path, rows):
    """A bag of Imu messages: rows of (t_ns, gyro_cov0, accel_cov0, orientation_cov0)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    with Writer(path, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=store)
        for t, g0, a0, o0 in rows:
            hdr = T["std_msgs/msg/Header"](
                stamp=T["builtin_interfaces/msg/Time"](
                    sec=t // 1_000_000_000, nanosec=t % 1_000_000_000
                ),
                frame_id="imu",
            )
            v = T["geometry_msgs/msg/Vector3"](x=0.1, y=0.2, z=9.8)
            cov = np.zeros(9)
            msg = T["sensor_msgs/msg/Imu"](
                header=hdr,
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=np.r_[o0, cov[1:]],
                angular_velocity=v,
                angular_velocity_covariance=np.r_[g0, cov[1:]],
                linear_acceleration=v,
                linear_acceleration_covariance=np.r_[a0, cov[1:]],
            )
            w.write(c, t, store.serialize_cdr(msg, "sensor_msgs/msg/Imu"))


def test_rep_145_markers_and_bad_messages(tmp_path):
    t0 = 1_600_000_000_000_000_000
    bag = tmp_path / "marked"
    _imu_bag(
        bag,
        [
            (t0, 0.01, 0.1, 0.001),
            (t0 + 5_000_000, -1.0, 0.1, 0.001),  # no angular velocity: unusable
            (t0 + 10_000_000, 0.01, 0.1, -1.0),  # no orientation in this one
            (t0 + 10_000_000, 0.01, 0.1, 0.001),  # time not increasing
        ],
    )
    with pytest.raises(FormatError, match="message 1: angular velocity or linear acceleration"):
        read_rosbag_imu(bag)
    imu, report = read_rosbag_imu(bag, clean=True)
    assert imu.t_ns.tolist() == [t0, t0 + 10_000_000]
    assert report.dropped == {
        "angular velocity or acceleration marked missing (-1)": [1],
        "time not increasing": [3],
    }
    assert imu.orientation is None  # only one of the two kept messages has one
    assert any("orientation in only 1 of 2" in n for n in report.notes)
    assert imu.gyro_covariance[:, 0, 0].tolist() == [0.01, 0.01]

    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    poses = tmp_path / "poses"
    with Writer(poses, version=8, storage_plugin=StoragePlugin.SQLITE3) as w:
        w.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=store)
    with pytest.raises(FormatError, match=r"no sensor_msgs/msg/Imu topics.*/odom \(nav_msgs"):
        read_imu(poses)
    with pytest.raises(
        FormatError, match="no supported sensor_msgs/msg/Imu messages on topic '/odom'"
    ):
        read_rosbag_imu(poses, topic="/odom")
