"""Agent configuration (safe defaults, the LAN example, errors) and graph fragments."""

from __future__ import annotations

import json
import socket
import threading
from pathlib import Path

import numpy as np
import pytest

from trackflow.dataflow import load_setup, parse_setup
from trackflow.distributed import (
    AgentConfig,
    edge_from_dict,
    edge_to_dict,
    fragment_json,
    fragment_stale,
    load_agent,
    parse_fragment,
)

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples" / "distributed"


def test_default_zenoh_config_is_loopback_without_multicast():
    zenoh = pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed")
    from trackflow.distributed import zenoh_config

    conf = zenoh_config(AgentConfig("a", parse_setup({})))
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:0"]
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    assert json.loads(conf.get_json("mode")) == "peer"
    assert json.loads(conf.get_json("transport/shared_memory/enabled")) is False
    on = {"transport": {"shared_memory": {"enabled": True}}}
    conf = zenoh_config(AgentConfig("a", parse_setup({}), zenoh=on))
    assert json.loads(conf.get_json("transport/shared_memory/enabled")) is True
    with pytest.raises(ValueError, match="zenoh config key 'nonsense'"):
        zenoh_config(AgentConfig("a", parse_setup({}), zenoh={"nonsense": 1}))
    lan = AgentConfig("a", parse_setup({}), zenoh_config=EXAMPLES / "lan.json5")
    conf = zenoh_config(lan)
    assert json.loads(conf.get_json("access_control/enabled")) is True
    assert json.loads(conf.get_json("transport/link/tls/enable_mtls")) is True
    assert all(e.startswith("tls/") for e in json.loads(conf.get_json("listen/endpoints")))
    del zenoh


def _zenoh_segments() -> set[str]:
    """Zenoh's shared-memory segments this process has mapped (``/dev/shm/*.zenoh``)."""
    with open("/proc/self/maps") as f:
        return {line.split()[-1] for line in f if line.rstrip().endswith(".zenoh")}


def test_two_agents_sessions_talk_without_shared_memory_segments():
    """Two sessions on the default configuration exchange a message and neither maps a
    shared-memory segment: with Zenoh's default each session made a 16 MB segment that every
    local peer it heard from mapped, so an agent's memory grew with the realm."""
    zenoh = pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed")
    if not Path("/proc/self/maps").exists():
        pytest.skip("needs /proc/self/maps (Linux)")
    from trackflow.distributed import zenoh_config

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{sock.getsockname()[1]}"
    listener = AgentConfig("a", parse_setup({}), zenoh={"listen": {"endpoints": [endpoint]}})
    dialer = AgentConfig("b", parse_setup({}), zenoh={"connect": {"endpoints": [endpoint]}})
    before, got = _zenoh_segments(), threading.Event()
    with zenoh.open(zenoh_config(listener)) as a, zenoh.open(zenoh_config(dialer)) as b:
        sub = a.declare_subscriber("tf/shm/test", lambda sample: got.set())
        pub = b.declare_publisher("tf/shm/test")
        for _ in range(100):  # until the link and the subscription are up (bounded)
            pub.put(bytes(64 * 1024))  # a payload Zenoh would put in shared memory
            if got.wait(0.1):
                break
        assert got.is_set(), "the message never arrived"
        assert _zenoh_segments() - before == set()
        sub.undeclare()


def test_example_agents_split_the_demo_setup():
    single = load_setup(ROOT / "examples" / "demo_setup.yaml").graph
    parts = [load_agent(EXAMPLES / f"{n}.yaml") for n in ("tracker", "camera", "app")]
    names = sorted(e.name for p in parts for e in p.setup.graph.edges)
    assert names == sorted(e.name for e in single.edges)
    for p in parts:
        for e in p.setup.graph.edges:
            ref = single.edge(e.name)
            assert edge_to_dict(e) == edge_to_dict(ref)
    assert (
        parts[2].setup.query("sheep") == load_setup(ROOT / "examples" / "demo_setup.yaml").query()
    )


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("sensors: []\n", "needs an 'agent:' mapping"),
        ("agent: {realm: x}\n", "missing key 'name'"),
        ("agent: {name: a, colour: red}\n", "unknown keys"),
        ("agent: {name: 'a b'}\n", "use letters, digits"),
        ("agent: {name: a, clock_sync: ntp}\n", "clock_sync"),
        ("agent: {name: a, pull_via: rpc}\n", "pull_via must be"),
        ("agent: {name: a}\nsensors: [{name: s, source: A}]\n", "missing key 'target'"),
    ],
)
def test_bad_agent_files_name_the_problem(tmp_path, text, match):
    p = tmp_path / "agent.yaml"
    p.write_text(text)
    with pytest.raises(ValueError, match=match) as info:
        load_agent(p)
    assert str(p) in str(info.value)


def test_fragment_round_trip_and_rejections():
    g = load_setup(ROOT / "examples" / "demo_setup.yaml").graph
    agent, frames, edges = parse_fragment(fragment_json("host", g))
    assert agent == "host" and set(frames) == set(g.frames)
    for e in edges:
        ref = g.edge(e.name)
        assert edge_to_dict(e) == edge_to_dict(ref)
        assert np.array_equal(e.covariance, ref.covariance)
        assert e.motion == ref.motion and e.stamp_offset_s == ref.stamp_offset_s
    with pytest.raises(ValueError, match="not JSON"):
        parse_fragment(b"\xff")
    with pytest.raises(ValueError, match="unknown fragment version 2"):
        parse_fragment(b'{"version": 2}')
    bad = edge_to_dict(g.edge("art"))
    bad["covariance"] = [[1.0]]
    with pytest.raises(ValueError, match="fragment edge 'art'"):
        edge_from_dict(bad)
    del bad["motion"]
    with pytest.raises(ValueError, match="missing or malformed field"):
        edge_from_dict(bad)


def test_a_fragment_advertises_its_live_sensors_stale_windows():
    g = load_setup(ROOT / "examples" / "demo_setup.yaml").graph
    data = fragment_json("host", g, stale_s={"art": 0.1})
    assert fragment_stale(data) == {"art": 0.1}
    assert [e.name for e in parse_fragment(data)[2]] == [e.name for e in g.edges]
    assert fragment_stale(fragment_json("host", g)) == {}
    # a malformed window is left out, not believed
    doc = json.loads(data)
    for bad in (0, -1.0, "fast", True, float("inf")):
        doc["edges"][0]["stale_s"] = bad
        assert fragment_stale(json.dumps(doc).encode()) == {}, bad


def test_setup_players_read_recordings(tmp_path):
    # Setup.players() reads each sensor's recording (read_stream returns (stream, report))
    from _agents import write_recording

    setup = load_setup(ROOT / "examples" / "demo_setup.yaml")
    setup.recordings = {
        "art": write_recording(tmp_path / "art.tfrec", "A", "T", rate_hz=60, duration_s=1),
        "artoolkit": write_recording(tmp_path / "cam.tfrec", "C", "M", rate_hz=30, duration_s=1),
    }
    players = setup.players()
    assert sorted(players) == ["art", "artoolkit"]
    assert len(players["art"].t_ns) == 60
    assert players["artoolkit"].latency_ns == 50_000_000


def test_agent_file_duplicate_key_is_refused_with_its_line(tmp_path):
    p = tmp_path / "agent.yaml"
    p.write_text("agent:\n  name: a\n  realm: x\n  realm: y\n")
    with pytest.raises(ValueError, match="duplicate key 'realm'") as info:
        load_agent(p)
    assert str(info.value).startswith(f"{p}:4: ")


@pytest.mark.parametrize(
    ("text", "line", "match"),
    [
        ("agent:\n  name: a\n\n  reorder_ms: -1\n", 4, "reorder_ms must be >= 0"),
        ("agent:\n  name: a\n  start_ns: soon\n", 3, "start_ns: 'soon' is not valid"),
        ("agent:\n  name: a\n  realm: x\n  colour: red\n", 4, "unknown keys"),
        ("sensors: []\nagent:\n  name: a\n  pull_via: rpc\n", 4, "pull_via must be"),
    ],
)
def test_a_bad_agent_value_reports_its_line(tmp_path, text, line, match):
    p = tmp_path / "agent.yaml"
    p.write_text(text)
    with pytest.raises(ValueError, match=match) as info:
        load_agent(p)
    assert str(info.value).startswith(f"{p}:{line}: ")
