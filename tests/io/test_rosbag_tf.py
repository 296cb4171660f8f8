"""ROS 2 bags in both storages (SQLite, MCAP), tf2 transforms (/tf, /tf_static) chained for a
frame pair, and the TFMessage writer; checked against ``rosbags`` itself and real recordings."""

from __future__ import annotations

import json
import pickle
import shutil

import numpy as np
import pytest
from _io_helpers import random_stream
from scipy.spatial.transform import Rotation, Slerp

from _rosbag_read import assert_bag_holds, bag_messages
from trackflow.cli.main import main
from trackflow.errors import FormatError
from trackflow.io import FrameLookupError, PoseStream, read_stream, write_stream
from trackflow.math import Pose, cov_to_ros, quat_angle, quat_exp

pytest.importorskip("rosbags")

STORAGES = {"mcap": ".mcap", "sqlite3": ".db3"}


def _storage_id(bag) -> str:
    text = (bag / "metadata.yaml").read_text()
    return text.split("storage_identifier:")[1].split()[0]


# -- storages, layout and the single-pose writers ---------------------------------------------


@pytest.mark.parametrize("storage", sorted(STORAGES))
@pytest.mark.parametrize("msgtype", ["PoseWithCovarianceStamped", "Odometry", "TFMessage"])
def test_every_message_and_covariance_round_trips_in_both_storages(tmp_path, rng, storage, msgtype):
    s = random_stream(rng, 25, covariance=True, source="map", target="tool")
    given = tmp_path / f"run{STORAGES[storage]}"
    written = write_stream(given, s, format="rosbag", msgtype=msgtype)
    bag = tmp_path / "run"
    assert written == bag  # run.mcap -> the bag directory run/ holding run/run.mcap
    assert sorted(p.name for p in bag.iterdir()) == sorted(["metadata.yaml", given.name])
    assert _storage_id(bag) == storage

    msgs = bag_messages(bag)
    assert len(msgs) == 25
    cov_ros = cov_to_ros(s.covariance, s.quaternion).reshape(-1, 36)
    for k, (topic, _, t_bag, m) in enumerate(msgs):
        assert t_bag == s.t_ns[k]
        if msgtype == "TFMessage":
            assert topic == "/tf" and len(m.transforms) == 1
            ts = m.transforms[0]
            # T_source_target: header.frame_id is the parent (source), child_frame_id the target
            assert (ts.header.frame_id, ts.child_frame_id) == ("map", "tool")
            hdr, p, q = ts.header, ts.transform.translation, ts.transform.rotation
        else:
            assert topic == "/tool" and m.header.frame_id == "map"
            hdr, p, q = m.header, m.pose.pose.position, m.pose.pose.orientation
            assert np.array_equal(m.pose.covariance, cov_ros[k])
        assert hdr.stamp.sec * 1_000_000_000 + hdr.stamp.nanosec == s.t_ns[k]
        assert [p.x, p.y, p.z] == s.position[k].tolist()
        assert [q.x, q.y, q.z, q.w] == s.quaternion[k].tolist()

    opts = {"source": "map", "target": "tool"} if msgtype == "TFMessage" else {}
    back, report = read_stream(given, **opts)  # the name it was written under reads back
    assert report.format == "rosbag" and report.rows_read == 25
    assert (back.source, back.target) == ("map", "tool")
    assert np.array_equal(back.t_ns, s.t_ns)
    assert np.array_equal(back.position, s.position)
    assert np.array_equal(back.quaternion, s.quaternion)
    if msgtype == "TFMessage":
        assert back.covariance is None
    else:
        np.testing.assert_allclose(back.covariance, s.covariance, rtol=1e-12, atol=1e-18)
    for other in (bag, bag / given.name):  # the directory and its storage file too
        assert read_stream(other, **opts)[0] == back


def test_storage_option_and_suffix_must_agree(tmp_path, rng):
    s = random_stream(rng, 3)
    write_stream(tmp_path / "plain", s, storage="mcap")
    assert _storage_id(tmp_path / "plain") == "mcap"
    assert read_stream(tmp_path / "plain")[0] == s
    with pytest.raises(ValueError, match="suffix says sqlite3"):
        write_stream(tmp_path / "x.db3", s, storage="mcap")
    with pytest.raises(ValueError, match="no storage choice"):
        write_stream(tmp_path / "x.bag", s, storage="mcap")


def test_a_bare_mcap_file_is_refused_with_a_hint(tmp_path, rng):
    write_stream(tmp_path / "run.mcap", random_stream(rng, 3))
    bare = tmp_path / "bare.mcap"
    shutil.copy(tmp_path / "run" / "run.mcap", bare)
    with pytest.raises(FormatError, match="without metadata.yaml.*reindex"):
        read_stream(bare)


def test_convert_to_mcap_names_the_bag_it_wrote(tmp_path, capsys):
    src = tmp_path / "a.txt"
    s = random_stream(np.random.default_rng(3), 12, source="world", target="head")
    write_stream(src, s)
    out = tmp_path / "out.mcap"
    assert main(["convert", str(src), str(out), "--to", "rosbag"]) == 0
    err = capsys.readouterr().err
    assert "ROS 2 bag directory" in err and str(tmp_path / "out" / "out.mcap") in err
    assert _storage_id(tmp_path / "out") == "mcap"
    assert main(["convert", str(out), str(tmp_path / "b.txt")]) == 0
    back, _ = read_stream(tmp_path / "b.txt")
    assert np.array_equal(back.position, s.position) and np.array_equal(back.t_ns, s.t_ns)
    assert main(["convert", str(src), str(out), "--to", "rosbag"]) == 1  # no silent overwrite


def test_answers_go_to_tf_from_the_command_line(tmp_path, capsys):
    src = tmp_path / "answers.txt"
    s = random_stream(np.random.default_rng(4), 9, source="world", target="head")
    write_stream(src, s)
    out = tmp_path / "answers.mcap"
    assert main(["convert", str(src), str(out), "--msgtype", "TFMessage", "--quiet"]) == 0
    ((topic, msgtype, _, m), *_) = bag_messages(tmp_path / "answers")
    assert (topic, msgtype) == ("/tf", "tf2_msgs/msg/TFMessage")
    assert (m.transforms[0].header.frame_id, m.transforms[0].child_frame_id) == ("world", "head")
    assert main(["info", str(out)]) == 1  # a /tf bag needs the pair, and says so as flags
    assert "pass the pair as --source and --target" in capsys.readouterr().err
    back, _ = read_stream(out, source="world", target="head")
    assert back == s
    assert main(["convert", str(src), str(tmp_path / "a.csv"), "--msgtype", "TFMessage"]) == 1
    assert "--msgtype" in capsys.readouterr().err


@pytest.mark.parametrize("msgtype", ["PoseWithCovarianceStamped", "TFMessage"])
def test_a_run_recording_converts_to_an_mcap_bag_rosbags_reads_whole(tmp_path, msgtype):
    """The answers file of ``trackflow run --record`` (written by its RecordingWriter, with
    covariances) through ``trackflow convert ... out.mcap``: rosbags reads every message,
    with the covariance in ROS's convention (a /tf message has none)."""
    from trackflow.io import RecordingWriter

    s = random_stream(np.random.default_rng(8), 40, covariance=True, source="room", target="tool")
    rec = tmp_path / "answers.tfrec"
    w = RecordingWriter(rec, "room", "tool", covariance=True)
    w.append(s)
    w.close()
    out = tmp_path / "answers.mcap"
    assert main(["convert", str(rec), str(out), "--msgtype", msgtype, "--quiet"]) == 0
    msgs = bag_messages(tmp_path / "answers")
    assert _storage_id(tmp_path / "answers") == "mcap"
    assert_bag_holds(msgs, s, msgtype)


# -- a /tf bag built from a real recording ----------------------------------------------------

T_BASE_CAM = Pose([0.12, -0.03, 0.25], quat_exp(np.array([0.3, -0.2, 1.1])))
T_CAM_OPT = Pose([0.0, 0.0, 0.0], [-0.5, 0.5, -0.5, 0.5])
ODOM_V = np.array([0.02, -0.01, 0.005])  # m/s
ODOM_W = np.array([0.01, 0.03, -0.02])  # rad/s about a fixed body axis: SLERP is exact


def _odom(t_ns, t0_ns) -> Pose:
    """world -> odom: a constant screw motion (velocity ODOM_V, body rate ODOM_W), so linear
    interpolation of the position and SLERP of the rotation between stamps are exact."""
    dt = (np.asarray(t_ns) - t0_ns) * 1e-9
    q0 = np.array([0.1, 0.2, -0.3, 0.9])
    q0 /= np.linalg.norm(q0)
    start = Pose(np.array([1.0, 2.0, 0.5]) + dt[:, None] * ODOM_V, np.tile(q0, (len(dt), 1)))
    return start @ Pose(np.zeros((len(dt), 3)), quat_exp(dt[:, None] * ODOM_W))


def _write_tf_bag(path, storage, records):
    """records: (bag time, topic, [(parent, child, stamp, position, quaternion), ...])."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=8, storage_plugin=plugin) as writer:
        conns = {}
        for t_bag, topic, transforms in sorted(records, key=lambda r: r[0]):
            if topic not in conns:
                conns[topic] = writer.add_connection(
                    topic, "tf2_msgs/msg/TFMessage", typestore=store
                )
            items = []
            for parent, child, stamp, p, q in transforms:
                hdr = T["std_msgs/msg/Header"](
                    stamp=T["builtin_interfaces/msg/Time"](
                        sec=int(stamp) // 1_000_000_000, nanosec=int(stamp) % 1_000_000_000
                    ),
                    frame_id=parent,
                )
                tr = T["geometry_msgs/msg/Transform"](
                    translation=T["geometry_msgs/msg/Vector3"](x=p[0], y=p[1], z=p[2]),
                    rotation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
                )
                items.append(
                    T["geometry_msgs/msg/TransformStamped"](
                        header=hdr, child_frame_id=child, transform=tr
                    )
                )
            msg = T["tf2_msgs/msg/TFMessage"](transforms=items)
            writer.write(conns[topic], int(t_bag), store.serialize_cdr(msg, msg.__msgtype__))


def _tf(parent, child, stamp, pose, k=None):
    p = pose.position if k is None else pose.position[k]
    q = pose.quaternion if k is None else pose.quaternion[k]
    return (parent, child, int(stamp), [float(v) for v in p], [float(v) for v in q])


@pytest.fixture(scope="module")
def fr1(shared_data_module):
    path = shared_data_module / "tum_rgbd" / "freiburg1_xyz-groundtruth.txt"
    gt, _ = read_stream(path, source="world", target="cam")
    return path, gt


@pytest.fixture(scope="module")
def shared_data_module():
    from conftest import shared_data_dir

    d = shared_data_dir()
    if not (d / "README.md").is_file():
        pytest.skip(f"shared recordings not found at {d} (set TRACKFLOW_DATA to their folder)")
    return d


OTHER_RANGE_S = (5.0, 20.0)  # world -> other exists only in this part of the recording


def _other(t_ns):
    """world -> other: a wobbly motion sampled at 37 Hz (interpolation is approximate here)."""
    s = np.asarray(t_ns) * 1e-9
    s = s - s[0]
    pos = np.stack([np.sin(s), np.cos(0.7 * s), 0.1 * s], axis=1)
    rot = quat_exp(np.stack([0.4 * np.sin(0.9 * s), 0.2 * s, 0.3 * np.cos(1.3 * s)], axis=1))
    return Pose(pos, rot)


@pytest.fixture(scope="module", params=sorted(STORAGES))
def tf_bag(request, fr1, tmp_path_factory):
    """world -> odom (10 Hz, dynamic) -> base (at the recording's stamps) -> cam (static) ->
    cam_optical (static); world -> other (37 Hz, dynamic, part of the time); map -> robot
    (static, a second tree)."""
    storage = request.param
    _, gt = fr1
    t = gt.t_ns
    t0 = int(t[0])
    records = []
    slow = np.arange(t0 - 50_000_000, int(t[-1]) + 150_000_000, 100_000_000)
    odom = _odom(slow, t0)
    other_t = np.arange(
        t0 + int(OTHER_RANGE_S[0] * 1e9), t0 + int(OTHER_RANGE_S[1] * 1e9), 27_027_027
    )
    other = _other(other_t)
    for k, ts in enumerate(slow):
        records.append((ts + 1_000_000, "/tf", [_tf("world", "odom", ts, odom, k)]))
    for k, ts in enumerate(other_t):
        records.append((ts + 2_000_000, "/tf", [_tf("world", "other", ts, other, k)]))
    T_world_cam = Pose(gt.position, gt.quaternion)
    T_odom_base = _odom(t, t0).inverse() @ T_world_cam @ T_BASE_CAM.inverse()
    for k, ts in enumerate(t):
        # odom -> base shares its message with a repeated world -> odom of the slow stream's
        # first stamp now and then: many transforms in one TFMessage, as a robot sends them
        items = [_tf("odom", "base", ts, T_odom_base, k)]
        if k % 50 == 0:
            items.append(_tf("world", "odom", slow[0], odom, 0))
        records.append((ts + 3_000_000, "/tf", items))
    statics = [
        _tf("base", "cam", t0, T_BASE_CAM),
        _tf("cam", "cam_optical", t0, T_CAM_OPT),
        _tf("map", "robot", t0, Pose([1.0, 0, 0], [0, 0, 0, 1.0])),
    ]
    records.append((t0 - 10, "/tf_static", statics))
    records.append((t0 + 5_000_000_000, "/tf_static", statics))  # latched again: harmless
    bag = tmp_path_factory.mktemp(f"tf_{storage}") / "tf_bag"
    _write_tf_bag(bag, storage, records)
    assert _storage_id(bag) == storage
    return bag, other_t, other


def test_the_chained_pair_is_the_recording(tf_bag, fr1):
    bag, _, _ = tf_bag
    _, gt = fr1
    s, report = read_stream(bag, source="world", target="cam")
    assert (s.source, s.target) == ("world", "cam")
    assert np.array_equal(s.t_ns, gt.t_ns)  # at the driving link's (odom -> base) stamps
    assert report.rows_read == len(gt) and not report.dropped
    assert any("odom -> base" in n and "interpolated" in n for n in report.notes)
    np.testing.assert_allclose(s.position, gt.position, rtol=0, atol=1e-12)
    assert np.max(quat_angle(s.quaternion, gt.quaternion)) < 1e-12
    inv, _ = read_stream(bag, source="cam", target="world")
    back = Pose(inv.position, inv.quaternion).inverse()
    np.testing.assert_allclose(back.position, gt.position, rtol=0, atol=1e-12)
    # the static link below cam is chained too, and a leading slash is ROS 1's spelling
    opt, _ = read_stream(bag, source="/world", target="cam_optical")
    want = Pose(gt.position, gt.quaternion) @ T_CAM_OPT
    np.testing.assert_allclose(opt.position, want.position, rtol=0, atol=1e-12)
    assert np.max(quat_angle(opt.quaternion, want.quaternion)) < 1e-12


def test_pairs_across_branches_interpolate_and_drop_where_a_link_has_no_data(tf_bag, fr1):
    """other -> cam_optical climbs to world and down the other branch; world -> other exists
    only from 5 s to 20 s at 37 Hz, so the driving stamps outside are dropped and the ones
    inside interpolate it (scipy's Slerp is the independent reference)."""
    bag, other_t, other = tf_bag
    _, gt = fr1
    s, report = read_stream(bag, source="other", target="cam_optical")
    inside = (gt.t_ns >= other_t[0]) & (gt.t_ns <= other_t[-1])
    assert np.array_equal(s.t_ns, gt.t_ns[inside])
    (reason,) = report.dropped
    assert "world -> other" in reason and len(report.dropped[reason]) == int((~inside).sum())
    assert report.rows_read == len(gt) == report.rows_kept + report.rows_dropped

    t = (gt.t_ns[inside] - other_t[0]) * 1e-9  # relative seconds: no float64 rounding of Unix
    ot = (other_t - other_t[0]) * 1e-9
    rot_other = Slerp(ot, Rotation.from_quat(other.quaternion))(t)
    pos_other = np.stack([np.interp(t, ot, other.position[:, i]) for i in range(3)], 1)
    r_wc = Rotation.from_quat(gt.quaternion[inside]) * Rotation.from_quat(T_CAM_OPT.quaternion)
    p_wc = gt.position[inside] + Rotation.from_quat(gt.quaternion[inside]).apply(T_CAM_OPT.position)
    want_r = rot_other.inv() * r_wc
    want_p = rot_other.inv().apply(p_wc - pos_other)
    np.testing.assert_allclose(s.position, want_p, rtol=0, atol=1e-9)
    assert np.max(quat_angle(s.quaternion, want_r.as_quat())) < 1e-9


def _without_paths(d):
    if isinstance(d, dict):
        return {
            k: _without_paths(v) for k, v in d.items() if k not in ("path", "reference", "estimate")
        }
    if isinstance(d, list):
        return [_without_paths(v) for v in d]
    return d


def _assert_close(a, b, where="$"):
    if isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            _assert_close(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _assert_close(x, y, f"{where}[{i}]")
    elif isinstance(a, float) and isinstance(b, float):
        assert b == pytest.approx(a, rel=1e-9, abs=1e-12), where
    else:
        assert a == b, where


def test_compare_on_the_tf_pair_equals_compare_on_the_tum_twin(tf_bag, fr1, capsys):
    bag, _, _ = tf_bag
    tum, _ = fr1
    est = tum.parent / "freiburg1_xyz-rgbdslam.txt"
    common = ["--align", "se3", "--json", "--quiet"]
    assert main(["compare", str(tum), str(est), *common]) == 0
    want = json.loads(capsys.readouterr().out)
    args = ["compare", str(bag), str(est), "--source", "world", "--target", "cam", *common]
    assert main(args) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["pairs"] == want["pairs"] > 700
    _assert_close(_without_paths(want), _without_paths(got))


def test_evaluate_on_the_tf_pair_equals_evaluate_on_the_tum_twin(tf_bag, fr1, capsys):
    bag, _, _ = tf_bag
    tum, _ = fr1
    common = ["--json", "--quiet", "--tune-fraction", "0", "--learned-orders", "none"]
    common += ["--horizons", "20,50"]
    assert main(["evaluate", str(tum), *common]) == 0
    want = json.loads(capsys.readouterr().out)
    assert main(["evaluate", str(bag), "--source", "world", "--target", "cam", *common]) == 0
    got = json.loads(capsys.readouterr().out)
    _assert_close(_without_paths(want), _without_paths(got))


def test_a_pair_the_tree_cannot_give_is_a_typed_error_naming_the_frames(tf_bag):
    bag, _, _ = tf_bag
    with pytest.raises(FrameLookupError) as info:
        read_stream(bag, source="world", target="gripper")
    err = info.value
    assert (err.source, err.target) == ("world", "gripper")
    assert "'gripper'" in str(err) and "'world'" in str(err)
    assert set(err.frames) == {
        "world",
        "odom",
        "base",
        "cam",
        "cam_optical",
        "other",
        "map",
        "robot",
    }
    assert "cam_optical" in str(err)  # the message lists what the bag has
    with pytest.raises(FrameLookupError, match="'cam' and 'robot' are not connected.*map -> robot"):
        read_stream(bag, source="cam", target="robot")
    with pytest.raises(FrameLookupError, match="pass the pair as source= and target="):
        read_stream(bag)
    back = pickle.loads(pickle.dumps(err))
    assert type(back) is FrameLookupError and vars(back) == vars(err)


def test_the_command_line_names_the_frames_too(tf_bag, capsys):
    bag, _, _ = tf_bag
    assert main(["info", str(bag), "--source", "world", "--target", "gripper"]) == 1
    err = capsys.readouterr().err
    assert "gripper" in err and "cam_optical" in err and "Traceback" not in err


def test_a_static_chain_gives_one_pose(tf_bag, fr1):
    bag, _, _ = tf_bag
    s, report = read_stream(bag, source="base", target="cam_optical")
    assert len(s) == 1 and s.t_ns[0] == fr1[1].t_ns[0]
    want = T_BASE_CAM @ T_CAM_OPT
    np.testing.assert_allclose(s.position[0], want.position, atol=1e-15)
    assert any("all static" in n for n in report.notes)


def test_bad_tf_and_unsupported_bags(tmp_path):
    t0 = 1_700_000_000_000_000_000
    eye = Pose([0.0, 0, 0], [0, 0, 0, 1.0])
    bad = tmp_path / "bad"
    _write_tf_bag(
        bad,
        "mcap",
        [
            (t0, "/tf", [_tf("a", "b", t0, eye)]),
            (t0 + 1, "/tf", [("a", "b", t0 + 10, [0.0, 0.0, float("nan")], [0, 0, 0, 1.0])]),
            (t0 + 2, "/tf", [("a", "b", t0 + 20, [0.0, 0.0, 0.0], [0, 0, 0, 2.0])]),
            (t0 + 3, "/tf", [_tf("c", "b", t0 + 30, eye)]),  # a second parent of b
        ],
    )
    with pytest.raises(FormatError, match="several parents"):
        read_stream(bad, source="a", target="b")
    clean_bag = tmp_path / "nan"
    records = [
        (t0, "/tf", [_tf("a", "b", t0, eye)]),
        (t0 + 1, "/tf", [("a", "b", t0 + 10, [0.0, 0.0, float("nan")], [0, 0, 0, 1.0])]),
        (t0 + 2, "/tf", [_tf("a", "b", t0 + 20, eye)]),
        (t0 + 3, "/tf", [_tf("a", "b", t0 + 20, Pose([1.0, 0, 0], [0, 0, 0, 1.0]))]),
    ]
    _write_tf_bag(clean_bag, "sqlite3", records)
    with pytest.raises(FormatError, match="/tf message 1: transform a -> b is not finite"):
        read_stream(clean_bag, source="a", target="b")
    s, report = read_stream(clean_bag, source="a", target="b", clean=True)
    assert s.t_ns.tolist() == [t0, t0 + 20] and s.position[1, 0] == 0.0  # tf2 keeps the first
    assert report.dropped == {
        "non-finite transform": [1],
        "repeated stamp (tf2 keeps the first)": [3],
    }

    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    other = tmp_path / "strings"
    with Writer(other, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
        msg = store.types["std_msgs/msg/String"](data="hi")
        w.write(c, t0, store.serialize_cdr(msg, "std_msgs/msg/String"))
    with pytest.raises(
        FormatError, match=r"no pose topics; pass topic= one of: /chatter \(std_msgs"
    ):
        read_stream(other)
    with pytest.raises(FormatError, match="no supported pose messages on topic '/chatter'"):
        read_stream(other, topic="/chatter")
    garbage = tmp_path / "g" / "g.mcap"
    garbage.parent.mkdir()
    garbage.write_bytes(b"\x89MCAP0\r\n" + b"\0" * 64)
    (garbage.parent / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    with pytest.raises(FormatError, match="cannot open as a ROS bag"):
        read_stream(garbage)


def test_ros1_bags_hold_tf_messages_too(tmp_path, rng):
    s = random_stream(rng, 6, source="odom", target="base_link")
    write_stream(tmp_path / "tf.bag", s, msgtype="TFMessage")
    back, _ = read_stream(tmp_path / "tf.bag", source="odom", target="base_link")
    assert back == PoseStream(s.source, s.target, s.t_ns, s.position, s.quaternion)
