"""Inputs that documented commands name but the docs do not make: each makes them in the
working directory ``repo`` of tests/test_readme.py's run of the docs (tests/_doc_commands.py).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from conftest import REPO_ROOT

FR1_EXCERPT = REPO_ROOT / "tests" / "cli" / "data" / "fr1_xyz_groundtruth_10s.txt"


def _shared(repo: Path) -> Path:
    return repo.parent / "shared" / "data"


def recording_as_rec_txt(repo: Path) -> None:
    """docs/cli.md's ``rec.txt``: any recording; the shipped 10 s of TUM RGB-D fr1_xyz."""
    shutil.copyfile(FR1_EXCERPT, repo / "rec.txt")


def fr1_xyz_txt(repo: Path) -> None:
    """docs/formats.md's ``fr1_xyz.txt``: the shipped 10 s of TUM RGB-D fr1_xyz."""
    shutil.copyfile(FR1_EXCERPT, repo / "fr1_xyz.txt")


def agent_files(repo: Path) -> None:
    """docs/distributed.md's three-host lab: the agent files of examples/distributed."""
    for name in ("tracker.yaml", "camera.yaml", "app.yaml"):
        shutil.copyfile(repo / "examples" / "distributed" / name, repo / name)


def saved_comparisons(repo: Path) -> None:
    """docs/cli.md's ``se3.json`` and ``sim3.json``: what ``compare --align se3|sim3
    --save-results`` saves for the TUM RGB-D fr1_xyz estimate against its ground truth."""
    from trackflow.evaluation import compare_trajectories
    from trackflow.io import read_stream

    tum = _shared(repo) / "tum_rgbd"
    ref, _ = read_stream(tum / "freiburg1_xyz-groundtruth.txt")
    est, _ = read_stream(tum / "freiburg1_xyz-rgbdslam.txt")
    for align in ("se3", "sim3"):
        res = compare_trajectories(ref, est, align=align)
        (repo / f"{align}.json").write_text(json.dumps(res.as_dict(arrays=True)) + "\n")


def robot_bag(repo: Path) -> None:
    """docs/formats.md's ``robot_bag``: a ROS 2 bag of /tf and /tf_static holding the tree
    world -> odom -> base -> cam (base -> cam static), odom -> base at 5 stamps, world -> odom
    at 3 stamps around them (so odom -> base drives and world -> odom is interpolated)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    t0 = 1_700_000_000_000_000_000
    ms = 1_000_000

    def tf(parent, child, stamp, x):
        return T["geometry_msgs/msg/TransformStamped"](
            header=T["std_msgs/msg/Header"](
                stamp=T["builtin_interfaces/msg/Time"](
                    sec=stamp // 1_000_000_000, nanosec=stamp % 1_000_000_000
                ),
                frame_id=parent,
            ),
            child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=x, y=0.0, z=0.0),
                rotation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            ),
        )

    records = [(t0 - 10 * ms, "/tf_static", [tf("base", "cam", t0, 0.1)])]
    records += [
        (t0 + k * 50 * ms, "/tf", [tf("world", "odom", t0 + k * 50 * ms, k)]) for k in (0, 1, 2)
    ]
    records += [
        (
            t0 + 5 * ms + k * 20 * ms,
            "/tf",
            [tf("odom", "base", t0 + 5 * ms + k * 20 * ms, 0.01 * k)],
        )
        for k in range(5)
    ]
    with Writer(repo / "robot_bag", version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        for t_bag, topic, items in sorted(records, key=lambda r: r[0]):
            if topic not in conns:
                conns[topic] = writer.add_connection(
                    topic, "tf2_msgs/msg/TFMessage", typestore=store
                )
            msg = T["tf2_msgs/msg/TFMessage"](transforms=items)
            writer.write(conns[topic], t_bag, store.serialize_cdr(msg, msg.__msgtype__))
