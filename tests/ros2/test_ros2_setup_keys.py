"""The setup keys of ROS 2 topics: a sensor's ``input: {ros2: ...}`` and a push query's
``ros2:``, checked once with the file, the line and the key; refused links."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from trackflow.dataflow import Ros2Link, Ros2Output, load_setup
from trackflow.errors import ConfigError

SENSOR = {"name": "head", "source": "room", "target": "head", "rate_hz": 100,
          "sigma_pos_mm": 0.5, "sigma_ori_deg": 0.2}  # fmt: skip
QUERY = {"name": "view", "source": "room", "target": "head", "mode": "push", "rate_hz": 60}


def _setup(tmp_path: Path, sensor_input=None, query_ros2=None, mode="push") -> Path:
    s = dict(SENSOR)
    if sensor_input is not None:
        s["input"] = sensor_input
    q = dict(QUERY, mode=mode)
    if mode != "push":
        q.pop("rate_hz")
    if query_ros2 is not None:
        q["ros2"] = query_ros2
    path = tmp_path / "setup.yaml"
    path.write_text(yaml.safe_dump({"sensors": [s], "queries": [q]}, sort_keys=False))
    return path


def test_defaults(tmp_path):
    setup = load_setup(
        _setup(tmp_path, {"ros2": {"topic": "mocap/head"}}, {"topic": "/trackflow/view"})
    )
    spec = setup.inputs["head"]
    assert spec.protocol == "ros2"
    o = spec.options
    assert (o["topic"], o["type"], o["domain"]) == ("/mocap/head", "PoseStamped", 0)
    assert o["clock"] == "host"
    assert (o["connect"], o["node"], o["insecure"]) == ("tcp/127.0.0.1:7447", "trackflow", False)
    assert spec.unit_scale == 1.0 and spec.up == "z"
    out = setup.ros2["view"]
    assert out == Ros2Output("/trackflow/view", "PoseWithCovarianceStamped", 0, "room", "head",
                             "trackflow", Ros2Link())  # fmt: skip


def test_tf_output_defaults_to_slash_tf(tmp_path):
    setup = load_setup(_setup(tmp_path, None, {"type": "TFMessage", "child_frame_id": "hmd",
                                                "domain": 3, "node": "tracker"}))  # fmt: skip
    out = setup.ros2["view"]
    assert (out.topic, out.type, out.domain, out.frame_id, out.child_frame_id, out.node) == (
        "/tf",
        "TFMessage",
        3,
        "room",
        "hmd",
        "tracker",
    )


def test_zenoh_config_is_relative_to_the_setup(tmp_path):
    setup = load_setup(_setup(tmp_path, {"ros2": {"topic": "/a", "zenoh_config": "z.json5"}},
                              {"topic": "/b", "zenoh_config": "z.json5"}))  # fmt: skip
    assert setup.inputs["head"].options["zenoh_config"] == str(tmp_path / "z.json5")
    assert setup.ros2["view"].link.zenoh_config == str(tmp_path / "z.json5")


@pytest.mark.parametrize(
    ("sensor_input", "query_ros2", "mode", "message"),
    [
        (
            {"ros2": {"topic": "/a", "typ": "PoseStamped"}},
            None,
            "push",
            "input.ros2: unknown keys ['typ']",
        ),
        ({"ros2": {"type": "PoseStamped"}}, None, "push", "input.ros2: missing key 'topic'"),
        (
            {"ros2": {"topic": "/a", "type": "Odometry"}},
            None,
            "push",
            "input.ros2.type: 'Odometry' is not one of",
        ),
        ({"ros2": {"topic": "/a//b"}}, None, "push", "is not a ROS 2 topic name"),
        ({"ros2": {"topic": "/1a"}}, None, "push", "is not a ROS 2 topic name"),
        (
            {"ros2": {"topic": "/tf", "type": "TFMessage"}},
            None,
            "push",
            "name the one with frame_id and child_frame_id",
        ),
        ({"ros2": {"topic": "/a", "domain": 300}}, None, "push", "is not a ROS domain id"),
        ({"ros2": {"topic": "/a", "domain": True}}, None, "push", "input.ros2.domain: expected"),
        (
            {"ros2": {"topic": "/a", "connect": "127.0.0.1:7447"}},
            None,
            "push",
            "is not a Zenoh endpoint",
        ),
        ({"ros2": {"topic": "/a", "clock": "sender"}}, None, "push", "input.ros2.clock must be"),
        ({"ros2": {"topic": "/a", "node": "my node"}}, None, "push", "is not a ROS 2 node name"),
        (None, {"topic": "/b", "frame": "x"}, "push", "queries[0].ros2: unknown keys ['frame']"),
        (None, {"type": "PoseStamped"}, "push", "queries[0].ros2: missing key 'topic'"),
        (
            None,
            {"topic": "/b", "type": "TransformStamped"},
            "push",
            "queries[0].ros2.type: 'TransformStamped' is not one of",
        ),
        (None, {"topic": "/b"}, "pull", "only a push query has answers to publish"),
        (None, "/b", "push", "queries[0].ros2 must be a mapping"),
        (None, {"topic": "/b", "insecure": "yes"}, "push", "queries[0].ros2.insecure: expected"),
    ],
)
def test_mistakes_name_file_line_and_key(tmp_path, sensor_input, query_ros2, mode, message):
    path = _setup(tmp_path, sensor_input, query_ros2, mode)
    with pytest.raises(ConfigError) as err:
        load_setup(path)
    text = str(err.value)
    assert message in text
    assert text.startswith(f"{path}:")
    line = text[len(str(path)) + 1 :].split(":", 1)[0]
    assert line.isdigit() and int(line) > 1  # the line of the sensor's input or the query


def test_links_off_this_machine_are_refused():
    pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed")
    from trackflow.ros2.session import session_config
    from trackflow.zenohconf import security

    with pytest.raises(ConfigError, match=r"tcp/192\.0\.2\.7:7447.*insecure: true"):
        session_config(Ros2Link("tcp/192.0.2.7:7447"))
    conf = session_config(Ros2Link("tcp/192.0.2.7:7447", insecure=True))  # told so: accepted
    assert security(conf)[0] == "insecure"
    conf = session_config(Ros2Link())
    assert security(conf)[0] == "loopback"
    assert '"tcp/127.0.0.1:7447"' in conf.get_json("connect/endpoints")
    assert conf.get_json("scouting/multicast/enabled") == "false"
