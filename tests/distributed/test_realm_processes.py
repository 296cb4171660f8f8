"""A secure realm made by ``trackflow realm init``, tried by an attacker, with real processes.

Two agents (a sensor's host ``s`` and an application ``c``) run on the realm's TLS and access
control files; a third identity of the realm, ``b``, owns another sensor and is not running.
The attacker holds ``b``'s certificate and key (a stolen or misused host) and

* publishes well-formed states of ``s``'s sensor at (5, 5, 5), an hour ahead and with a
  covariance of 1e300,
* declares a liveliness token and a fragment queryable of an agent that does not exist,
* publishes results under ``c``'s key;

a second attacker has no certificate of the realm at all. The answers of ``c``'s query must
not move by more than their own error, and no fake agent may appear in any plan.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (pip install .[distributed])")

import zenoh
from _agents import SRC, AgentProcess, free_port, status, wait_for, write_agent, write_recording

from trackflow.distributed.wire import (
    decode,
    decode_batch,
    decode_state,
    encode_batch,
    encode_state,
)
from trackflow.filters import FilterSnapshot

pytestmark = pytest.mark.slow

RATE = 100
W = 2 * np.pi * 0.3


def _truth(t_s: np.ndarray) -> np.ndarray:
    """The recording's motion without its noise (tests/distributed/_agents.write_recording)."""
    return np.stack([0.2 * np.sin(W * t_s), 0.1 * np.cos(W * t_s), 1.0 + 0 * t_s], axis=1)


def _bytes(sample) -> bytes:
    return sample.payload.to_bytes()


def _session(path, listen: bool = True) -> zenoh.Session:
    """A session on a configuration ``realm init`` wrote; ``listen=False``: without its
    listening endpoint (an attacker holding a certificate whose agent does not run: that
    port was free when the test began and may be a connection's port by now)."""
    conf = zenoh.Config.from_file(str(path))
    if not listen:
        conf.insert_json5("listen/endpoints", "[]")
    return zenoh.open(conf)


@pytest.fixture
def realm(tmp_path):
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed (make test installs it: apt-get install openssl)")
    name = f"sec{free_port()}"
    start = time.time_ns()
    rec = write_recording(tmp_path / "s1.tfrec", "W", "X", rate_hz=RATE, duration_s=90, seed=7)
    motion = {"n_dp": 1, "n_do": 1, "noise": [1.0, 1.0]}
    sensor = dict(name="s1", source="W", target="X", rate_hz=RATE, sigma_pos_mm=1.0,
                  sigma_ori_deg=0.2, motion=motion)  # fmt: skip
    files = {
        "s": write_agent(
            tmp_path / "s.yaml",
            "s",
            name,
            zenoh={},
            start_ns=start,
            extra={"zenoh_config": "realm/s.json5"},
            sensors=[{**sensor, "recording": str(rec)}],
        ),  # fmt: skip
        "c": write_agent(
            tmp_path / "c.yaml",
            "c",
            name,
            zenoh={},
            extra={"zenoh_config": "realm/c.json5"},
            frames=["W", "X"],
            queries=[dict(name="q", source="W", target="X", mode="push", rate_hz=50)],
        ),  # fmt: skip
        "b": write_agent(
            tmp_path / "b.yaml",
            "b",
            name,
            zenoh={},
            sensors=[{**sensor, "name": "b1", "target": "Y"}],
        ),  # fmt: skip
    }
    ports = {n: free_port() for n in files}
    cmd = [sys.executable, "-m", "trackflow.cli.main", "realm", "init", *map(str, files.values()),
           "--out", str(tmp_path / "realm"), "--observer", "obs"]  # fmt: skip
    cmd += [f"--endpoint={n}=localhost:{p}" for n, p in ports.items()]
    env = dict(os.environ, PYTHONPATH=str(SRC))
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)
    assert done.returncode == 0, done.stderr
    return name, start, files, tmp_path / "realm"


def test_a_realm_made_by_realm_init_cannot_be_spoofed(tmp_path, realm):
    name, start, files, folder = realm
    procs = [AgentProcess(files[n], "--duration", "90", log_dir=tmp_path) for n in ("s", "c")]
    sessions = []
    try:
        for p in procs:
            p.wait_ready()
        obs = _session(folder / "obs.json5")
        sessions.append(obs)
        answers, states = [], []
        r = f"trackflow/{name}"
        obs.declare_subscriber(f"{r}/result/*/q", lambda s: answers.append(decode(_bytes(s))))
        obs.declare_subscriber(f"{r}/states/s", lambda s: states.extend(
            decode_state(st) for e, st in decode_batch(_bytes(s)) if e == "s1"))  # fmt: skip
        wait_for(lambda: len(answers) >= 50 and states, 60)
        before = len(answers)

        # the attacker with b's certificate
        evil = _session(folder / "b.json5", listen=False)  # it connects to s and c
        sessions.append(evil)
        real = states[-1]
        x = real.x.copy()
        x[:3] = 5.0
        # s1's states as agent s's batches, and as b's (c takes s1 from s alone)
        pubs = [evil.declare_publisher(f"trackflow/{name}/states/{a}") for a in ("s", "b")]
        token = evil.liveliness().declare_token(f"trackflow/{name}/alive/evil/s1")
        frag = evil.declare_queryable(f"trackflow/{name}/fragment/evil", lambda q: None)
        fake_result = evil.declare_publisher(f"trackflow/{name}/result/c/q")
        for k in range(100):
            now = time.time_ns()
            p = real.p if k % 3 else np.diag(np.full(real.p.shape[0], 1e300))
            stamp = now + (3_600_000_000_000 if k % 5 == 0 else 0)
            fake = encode_state(FilterSnapshot(stamp * 1e-9, x, p, False), seq=real.seq + 1 + k,
                                stamp_ns=stamp, host_ns=now, origin_ns=now, n_dp=real.n_dp,
                                n_do=real.n_do)  # fmt: skip
            for pub in pubs:
                pub.put(encode_batch([("s1", fake)]))
            fake_result.put(b"\0" * 40)
            time.sleep(0.01)
        time.sleep(1.0)
        token.undeclare()
        frag.undeclare()

        # an attacker without the realm's certificate: TLS to the agents' endpoints fails
        outsider = zenoh.Config()
        outsider.insert_json5("mode", '"peer"')
        outsider.insert_json5("connect/endpoints", json.dumps([
            ep for ep in json.loads((folder / "c.json5").read_text())["connect"]["endpoints"]
        ]))  # fmt: skip
        outsider.insert_json5("scouting/multicast/enabled", "false")
        lone = zenoh.open(outsider)
        sessions.append(lone)
        assert status(lone, name, "s", timeout_s=2.0) is None

        wait_for(lambda: len(answers) >= before + 100, 60)
        st = status(obs, name, "c")
    finally:
        for s in sessions:
            s.close()
        for p in procs:
            p.stop()
    assert st["security"] == "tls+acl" and st["queries"]["q"]["state"] == "running"
    assert "evil" not in json.dumps(st)  # no fake agent or edge in its graph or plans
    t = np.array([a.exposure_ns for a in answers], dtype=np.int64)
    p = np.array([a.pose.position for a in answers])
    sigma = np.sqrt(np.array([np.trace(a.pose.covariance[:3, :3]) / 3 for a in answers]))
    err = np.linalg.norm(p - _truth((t - start) * 1e-9), axis=1)
    # the attack moved nothing: every answer within its own error (5 sigma, plus the
    # recording's 1 mm noise thrice) of the truth, before, during and after it; a fake state
    # that got through would put answers metres off (8.1 m without the access control)
    assert np.all(err < 5 * sigma + 3e-3), (err.max(), sigma[np.argmax(err)])
    assert err[before:].max() < 0.1, err[before:].max()
