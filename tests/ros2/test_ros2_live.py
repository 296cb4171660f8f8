"""``trackflow run`` and an agent on ROS 2 topics, over real loopback sockets.

A Zenoh router (standing in for the ROS 2 system's ``rmw_zenohd``) carries a ROS 2 style
pose topic to trackflow and trackflow's answers back; the test decodes what trackflow sends
with rosbags' type store and Zenoh's own deserializer (not trackflow's code) and checks every
field, the attachment, the key expression and the graph's liveliness tokens. Garbage,
foreign attachments and wrong frames sent among the poses are counted rejections.
"""

from __future__ import annotations

import re
import threading
import time

import numpy as np
import pytest
import yaml

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (pip install .[distributed])")
pytest.importorskip("rosbags", reason="rosbags is not installed (pip install .[ros])")

from _ros2live import STORE, Router, attachment, key, pose_message, read_attachment

from trackflow.dataflow import parse_setup
from trackflow.io import read_stream
from trackflow.math import Pose, UncertainPose, cov_from_ros, cov_to_ros, quat_exp
from trackflow.ros2 import entity_gid
from trackflow.trackers import run_live

PWC = "geometry_msgs/msg/PoseWithCovarianceStamped"
TF = "tf2_msgs/msg/TFMessage"
SENSOR = {"name": "head", "source": "room", "target": "head", "rate_hz": 100,
          "sigma_pos_mm": 0.5, "sigma_ori_deg": 0.2,
          "motion": {"n_dp": 1, "n_do": 1, "noise": [0.0, 3.0, 0.0, 10.0]}}  # fmt: skip


def _motion(i: int):
    """A smooth pose and its covariance in ROS's convention, message ``i`` (100 Hz)."""
    t = i * 0.01
    p = (0.2 * np.sin(t), 0.1 * np.cos(t), 1.0 + 0.05 * t)
    q = tuple(float(v) for v in quat_exp(np.array([0.0, 0.1 * np.sin(t), 0.3 * t])))
    a = np.diag([1e-6, 2e-6, 3e-6, 1e-4, 2e-4, 3e-4])
    a[0, 1] = a[1, 0] = 5e-7
    return p, q, a


def _feed(router: Router, n: int, sent: list, bad: dict) -> None:
    """``n`` PoseWithCovarianceStamped on /mocap/head at 100 Hz with rmw_zenoh attachments;
    every 25th message garbage, every 25th (+8) a foreign attachment, every 25th (+16) of
    another frame."""
    pub = router.publisher(key(0, "/mocap/head", PWC))
    gid = bytes(range(16))
    for i in range(1, n + 1):
        now = time.time_ns()
        p, q, c = _motion(i)
        frame = "room"
        att = attachment(i, now, gid)
        payload = None
        if i % 25 == 0:
            payload, what = b"\x00\x01\x00\x00not a pose at all", "malformed message"
        elif i % 25 == 8:
            att, what = b"\x03abc", "bad attachment"
        elif i % 25 == 16:
            frame, what = "world", "frame mismatch"
        else:
            what = None
        if payload is None:
            payload = pose_message(PWC, now, frame, p, q, c)
        pub.put(payload, attachment=att)
        if what is None:
            sent.append((now, p, q, c))
        else:
            bad[what] = bad.get(what, 0) + 1
        time.sleep(0.01)
    pub.undeclare()


def test_run_reads_and_publishes_ros2_topics(tmp_path, router):
    setup = parse_setup(
        {
            "sensors": [
                dict(
                    SENSOR,
                    input={
                        "ros2": {
                            "topic": "/mocap/head",
                            "type": "PoseWithCovarianceStamped",
                            "frame_id": "room",
                            "connect": router.endpoint,
                        }
                    },
                )
            ],
            "queries": [
                {
                    "name": "q",
                    "source": "room",
                    "target": "head",
                    "mode": "push",
                    "rate_hz": 50,
                    "time_offset_ms": -20,
                    "ros2": {"topic": "/trackflow/head", "connect": router.endpoint},
                }
            ],
        }  # fmt: skip
    )
    out_key = key(0, "/trackflow/head", PWC)
    got = router.watch("0/trackflow/head/**")
    answers, sent, bad = [], [], {}
    stop, inputs = threading.Event(), []
    n = 400

    def watch() -> None:  # feed, then stop once every message went through the input
        _feed(router, n, sent, bad)
        deadline = time.monotonic() + 120
        while inputs[0].packets < n and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.2)
        stop.set()

    feeder = threading.Thread(target=watch, daemon=True)

    def on_status(lines):
        if lines and lines[0].startswith("listening") and not feeder.is_alive():
            feeder.start()

    res = run_live(setup, record=tmp_path / "out.tfrec", callback=answers.append,
                   on_status=on_status, stop=stop, status_period_s=0.5,
                   on_network=lambda net, plan, inps: inputs.extend(inps))  # fmt: skip
    feeder.join(5)
    time.sleep(0.3)  # the last answers on their way through the router
    assert inputs[0].packets == n

    # the input: every good message a measurement, the rest counted by reason
    status = res.statuses["head"]
    assert status["rejections"] == bad and set(bad) == {"malformed message", "bad attachment",
                                                        "frame mismatch"}  # fmt: skip
    assert status["measurements"] == len(sent) > 200
    rec, _ = read_stream(tmp_path / "out.head.tfrec")
    by_stamp = {t: (p, q, c) for t, p, q, c in sent}
    # accepted or dropped by the live source (a message more than 500 ms old when dispatched,
    # on a loaded machine), each counted
    assert status["accepted"] + sum(status["dropped"].values()) == len(sent)
    assert set(status["dropped"]) <= {"older than the backlog window"}, status["dropped"]
    assert len(rec.t_ns) == status["accepted"] > 0.8 * len(sent)
    for k in range(0, len(rec.t_ns), 37):
        p, q, c = by_stamp[int(rec.t_ns[k])]
        np.testing.assert_array_equal(rec.position[k], p)
        np.testing.assert_allclose(rec.quaternion[k], q, rtol=0, atol=1e-15)
        np.testing.assert_allclose(rec.covariance[k], cov_from_ros(c, q), rtol=1e-12, atol=1e-20)

    # the answers: one message each, every field as the answer says
    assert res.ros2["q"]["keyexpr"] == out_key
    assert res.ros2["q"]["published"] == res.answers == len(answers) > 100
    assert len(got) == len(answers)
    answer_at = {m.t_ns: m for m in answers}
    gids, seqs = set(), []
    for k_expr, payload, att, arrival in got:
        assert k_expr == out_key
        msg = STORE.deserialize_cdr(payload, PWC)
        t = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        m = answer_at[t]
        assert msg.header.frame_id == "room"
        pose = msg.pose.pose
        pos, ori = pose.position, pose.orientation
        assert (pos.x, pos.y, pos.z) == tuple(m.pose.position)
        assert (ori.x, ori.y, ori.z, ori.w) == tuple(m.pose.quaternion)
        ros = cov_to_ros(m.pose.covariance, m.pose.quaternion)
        np.testing.assert_allclose(
            np.asarray(msg.pose.covariance).reshape(6, 6), 0.5 * (ros + ros.T), rtol=1e-12, atol=0
        )
        seq, stamp, gid = read_attachment(att)
        assert stamp <= arrival and arrival - stamp < 5e9
        gids.add(gid)
        seqs.append(seq)
    assert seqs == list(range(1, len(got) + 1))

    # the ROS 2 graph: trackflow's node, its publisher and its subscription
    tokens = [k for kind, k in router.tokens if kind == "PUT"]
    node = next(t for t in tokens if t.endswith("/NN/%/%/trackflow"))
    m = re.fullmatch(r"@ros2_lv/0/([0-9a-f]+)/(\d+)/\2/NN/%/%/trackflow", node)
    assert m, node
    zid, nid = m.groups()
    mp = f"@ros2_lv/0/{zid}/{nid}/\\d+/MP/%/%/trackflow/%trackflow%head/"
    mp += f"geometry_msgs::msg::dds_::PoseWithCovarianceStamped_/{out_key.rsplit('/', 1)[1]}/"
    mp += re.escape("::,10:,:,:,,")
    (pub_token,) = [t for t in tokens if re.fullmatch(mp, t)]
    assert gids == {entity_gid(pub_token)}
    ms = f"@ros2_lv/0/{zid}/{nid}/\\d+/MS/%/%/trackflow/%mocap%head/"
    ms += "geometry_msgs::msg::dds_::PoseWithCovarianceStamped_/RIHS01_[0-9a-f]{64}/"
    assert [t for t in tokens if re.match(ms, t)]
    # the run closed its session: its tokens are gone
    assert not [t for t in router.live_tokens() if f"/{zid}/" in t]


def test_agent_publishes_tf(tmp_path, router):
    from trackflow.distributed import Agent, load_agent

    doc = {
        "agent": {"name": "hmd", "realm": f"ros2test{time.time_ns() % 10**6}"},
        "sensors": [SENSOR],
        "queries": [{"name": "q", "source": "room", "target": "head", "mode": "push",
                     "rate_hz": 50, "ros2": {"type": "TFMessage", "child_frame_id": "hmd_link",
                                             "connect": router.endpoint, "node": "agent"}}],
    }  # fmt: skip
    path = tmp_path / "agent.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    got = router.watch("0/tf/**")
    with Agent(load_agent(path)) as agent:
        router.wait_token("/MP/%/%/agent/%tf/tf2_msgs::msg::dds_::TFMessage_/")
        cov = np.diag([1e-6] * 3 + [1e-4] * 3)
        for i in range(150):
            p, q, _ = _motion(i)
            agent.feed("head", agent.now_ns(), UncertainPose(Pose(p, q), cov))
            time.sleep(0.01)
        time.sleep(0.2)
        last = agent.queries["q"].last
        time.sleep(0.3)
        status = agent.status()["ros2"]["q"]
    assert status["published"] >= len(got) > 20
    assert status["keyexpr"] == key(0, "/tf", TF)
    found = 0
    for k_expr, payload, att, _ in got:
        assert k_expr == key(0, "/tf", TF)
        (tr,) = STORE.deserialize_cdr(payload, TF).transforms
        assert (tr.header.frame_id, tr.child_frame_id) == ("room", "hmd_link")
        read_attachment(att)
        if tr.header.stamp.sec * 10**9 + tr.header.stamp.nanosec == last.t_ns:
            v, r = tr.transform.translation, tr.transform.rotation
            assert (v.x, v.y, v.z) == tuple(last.pose.position)
            assert (r.x, r.y, r.z, r.w) == tuple(last.pose.quaternion)
            found += 1
    assert found == 1


def test_agent_reads_a_ros2_topic(tmp_path, router):
    """An agent opens a sensor's ``input: {ros2: ...}`` as ``trackflow run`` does."""
    from trackflow.distributed import Agent, load_agent

    inp = {"ros2": {"topic": "/mocap/head", "type": "PoseWithCovarianceStamped", "frame_id": "room",
                    "connect": router.endpoint, "node": "agent_in"}}  # fmt: skip
    doc = {
        "agent": {"name": "mocap", "realm": f"ros2in{time.time_ns() % 10**6}"},
        "sensors": [dict(SENSOR, input=inp)],
        "queries": [{"name": "q", "source": "room", "target": "head", "mode": "push",
                     "rate_hz": 50}],
    }  # fmt: skip
    path = tmp_path / "agent.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    sent, bad = [], {}
    with Agent(load_agent(path)) as agent:
        router.wait_token("/MS/%/%/agent_in/%mocap%head/")
        _feed(router, 100, sent, bad)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            status = agent.status()
            if status["inputs"]["head"]["packets"] >= 100:
                break
            time.sleep(0.05)
        time.sleep(0.3)
        status = agent.status()
    head = status["inputs"]["head"]
    assert head["protocol"] == "ros2" and head["packets"] == 100
    assert head["measurements"] == len(sent) and head["rejections"] == bad
    assert status["queries"]["q"]["published"] > 0
