"""Two "hosts" as network namespaces joined by a veth pair: a sensor agent on one, the query's
agent on the other, talking over 10.231.x.0/24 (never leaving the machine)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time

import pytest

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (pip install .[distributed])")

from _agents import SRC, write_agent, write_recording

pytestmark = pytest.mark.slow


def _ip(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=10)


@pytest.fixture
def two_hosts():
    if shutil.which("ip") is None:
        pytest.skip("no 'ip' command (iproute2) to make network namespaces")
    tag = f"tf{os.getpid() % 100000}"
    a, b = f"{tag}a", f"{tag}b"
    subnet = f"10.231.{os.getpid() % 250}"
    probe = _ip("netns", "add", a)
    if probe.returncode != 0:
        pytest.skip(
            f"cannot create network namespaces here (needs root/CAP_SYS_ADMIN): "
            f"{probe.stderr.strip()}"
        )
    try:
        steps = [
            ("netns", "add", b),
            ("link", "add", f"{tag}va", "type", "veth", "peer", "name", f"{tag}vb"),
            ("link", "set", f"{tag}va", "netns", a),
            ("link", "set", f"{tag}vb", "netns", b),
            ("-n", a, "addr", "add", f"{subnet}.1/24", "dev", f"{tag}va"),
            ("-n", b, "addr", "add", f"{subnet}.2/24", "dev", f"{tag}vb"),
            ("-n", a, "link", "set", f"{tag}va", "up"),
            ("-n", b, "link", "set", f"{tag}vb", "up"),
            ("-n", a, "link", "set", "lo", "up"),
            ("-n", b, "link", "set", "lo", "up"),
        ]
        for step in steps:
            r = _ip(*step)
            if r.returncode != 0:
                pytest.skip(f"cannot wire the namespaces ({' '.join(step)}): {r.stderr.strip()}")
        yield a, b, subnet
    finally:
        _ip("netns", "del", a)
        _ip("netns", "del", b)


def test_sensor_and_query_on_two_hosts(tmp_path, two_hosts):
    ns_a, ns_b, subnet = two_hosts
    realm = "hosts"
    port = 7447
    rec = write_recording(tmp_path / "s1.tfrec", "W", "X", rate_hz=100, duration_s=60, seed=3)
    start_ns = time.time_ns()
    a = write_agent(
        tmp_path / "a.yaml",
        "sensor_host",
        realm,
        start_ns=start_ns,
        zenoh={"listen": {"endpoints": [f"tcp/{subnet}.1:{port}"]}},
        sensors=[
            dict(
                name="s1",
                source="W",
                target="X",
                rate_hz=100,
                latency_ms=5,
                sigma_pos_mm=1.0,
                sigma_ori_deg=0.2,
                recording=str(rec),
                motion={"n_dp": 1, "n_do": 1, "noise": [1.0, 1.0]},
            )
        ],
    )
    c = write_agent(
        tmp_path / "c.yaml",
        "app_host",
        realm,
        zenoh={
            "listen": {"endpoints": [f"tcp/{subnet}.2:{port}"]},
            "connect": {"endpoints": [f"tcp/{subnet}.1:{port}"]},
        },
        frames=["W", "X"],
        queries=[dict(name="q", source="W", target="X", mode="push", rate_hz=50)],
    )
    env = dict(os.environ, PYTHONPATH=str(SRC))

    def agent(ns, path, seconds, status=None):
        cmd = [
            "ip",
            "netns",
            "exec",
            ns,
            sys.executable,
            "-m",
            "trackflow.cli.main",
            "agent",
            str(path),
            "--duration",
            str(seconds),
            "--insecure",  # plain TCP between the two namespaces, said in the status
        ]
        if status is not None:
            cmd += ["--status", str(status)]
        return subprocess.Popen(
            cmd, env=env, stdout=subprocess.DEVNULL, stderr=open(tmp_path / f"{ns}.err", "w")
        )

    status = tmp_path / "status.json"
    pa = agent(ns_a, a, 25)
    pc = agent(ns_b, c, 12, status)
    try:
        pc.wait(timeout=90)
    finally:
        for p in (pa, pc):
            if p.poll() is None:
                p.kill()
                p.wait(timeout=10)
    assert status.exists(), (tmp_path / f"{ns_b}.err").read_text()
    st = json.loads(status.read_text())
    q = st["queries"]["q"]
    assert st["live_edges"] == {"s1": "sensor_host"} and st["security"] == "insecure"
    assert q["state"] == "running" and q["paths"] == ["W->X[s1]"]
    assert q["published"] > 25
    assert "sensor_host" in st["clocks"]
