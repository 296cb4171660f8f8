"""Helpers for tests with real agent processes on loopback (bounded in time everywhere)."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from trackflow.io import PoseStream, write_stream
from trackflow.math import quat_exp

SRC = Path(__file__).resolve().parents[2] / "src"


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def endpoint(port: int) -> str:
    return f"tcp/127.0.0.1:{port}"


def write_recording(
    path: Path,
    source: str,
    target: str,
    *,
    rate_hz: float,
    duration_s: float,
    phase: float = 0.0,
    sigma_pos: float = 1e-3,
    seed: int = 0,
) -> Path:
    """A noisy smooth motion ``T_source_target`` (0.2 m / 20 deg swings at 0.3 Hz) from
    recording time 0, written with its covariance."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    w = 2 * np.pi * 0.3
    pos = np.stack([0.2 * np.sin(w * t + phase), 0.1 * np.cos(w * t), 1.0 + 0 * t], axis=1)
    pos += rng.normal(0.0, sigma_pos, pos.shape)
    rot = np.stack([0 * t, 0 * t, np.radians(20) * np.sin(w * t + phase)], axis=1)
    quat = quat_exp(rot)
    cov = np.broadcast_to(np.diag([sigma_pos**2] * 3 + [np.radians(0.2) ** 2] * 3), (len(t), 6, 6))
    t_ns = np.round(t * 1e9).astype(np.int64)
    write_stream(path, PoseStream(source, target, t_ns, pos, quat, covariance=np.array(cov)))
    return path


def write_agent(
    path: Path,
    name: str,
    realm: str,
    *,
    zenoh: dict,
    start_ns: int = 0,
    extra: dict | None = None,
    **setup,
) -> Path:
    doc = {
        "agent": {
            "name": name,
            "realm": realm,
            "zenoh": zenoh,
            "start_ns": int(start_ns),
            **(extra or {}),
        }
    }
    doc.update(setup)
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def sensor_and_app(tmp_path: Path, realm: str, duration_s: float = 60.0):
    """The two agent files of a small realm: ``host_s`` plays sensor ``s1`` (W -> X, 100 Hz,
    a recording of ``duration_s`` from now) and ``host_c`` asks the 50 Hz push query ``q``
    (W -> X). Returns ``(sensor file, app file, [their endpoints])``."""
    ps, pc = free_port(), free_port()
    rec = write_recording(tmp_path / "s1.tfrec", "W", "X", rate_hz=100, duration_s=duration_s,
                          seed=5)  # fmt: skip
    sensor = write_agent(
        tmp_path / "s.yaml", "host_s", realm, start_ns=time.time_ns(),
        zenoh={"listen": {"endpoints": [endpoint(ps)]}},
        sensors=[dict(name="s1", source="W", target="X", rate_hz=100, sigma_pos_mm=1.0,
                      sigma_ori_deg=0.2, motion={"n_dp": 1, "n_do": 1, "noise": [1.0, 1.0]},
                      recording=str(rec))],
    )  # fmt: skip
    app = write_agent(
        tmp_path / "c.yaml", "host_c", realm,
        zenoh={"listen": {"endpoints": [endpoint(pc)]}, "connect": {"endpoints": [endpoint(ps)]}},
        frames=["W", "X"], queries=[dict(name="q", source="W", target="X", mode="push",
                                         rate_hz=50)],
    )  # fmt: skip
    return sensor, app, [endpoint(ps), endpoint(pc)]


class AgentProcess:
    """``trackflow agent FILE`` in its own process; stdout goes to a log file."""

    def __init__(self, yaml_path: Path, *args: str, log_dir: Path):
        self.yaml_path = yaml_path
        self.log = log_dir / f"{yaml_path.stem}.{time.monotonic_ns()}.log"
        env = dict(os.environ, PYTHONPATH=str(SRC))
        self._out = open(self.log, "w")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "trackflow.cli.main", "agent", str(yaml_path), *args],
            stdout=self._out,
            stderr=subprocess.STDOUT,
            env=env,
        )

    def wait_ready(self, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"agent exited early:\n{self.log.read_text()}")
            if '"ready"' in self.log.read_text():
                return
            time.sleep(0.1)
        raise TimeoutError(f"agent not ready after {timeout_s} s:\n{self.log.read_text()}")

    def kill9(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(timeout=10)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.kill9()
        self._out.close()


def observer(connect: list[str]):
    """A Zenoh peer session of the test itself (loopback, no multicast)."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([endpoint(free_port())]))
    conf.insert_json5("connect/endpoints", json.dumps(connect))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


def status(session, realm: str, agent: str, timeout_s: float = 3.0) -> dict | None:
    for reply in session.get(f"trackflow/{realm}/status/{agent}", timeout=timeout_s):
        if reply.ok is not None:
            return json.loads(reply.ok.payload.to_bytes())
    return None


def wait_for(fn, timeout_s: float, interval_s: float = 0.2):
    """Poll ``fn()`` until it returns something truthy; raise TimeoutError with the last value."""
    deadline = time.monotonic() + timeout_s
    last = None
    while time.monotonic() < deadline:
        last = fn()
        if last:
            return last
        time.sleep(interval_s)
    raise TimeoutError(f"condition not met in {timeout_s} s; last value: {last!r}")
