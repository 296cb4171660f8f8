"""The fuzz bar of the live inputs: ``trackflow run`` behind a faulty link.

For DTrack and NatNet in turn, ``trackflow simulate`` replays a real recording (default
TUM-VI room1, 120 Hz, 5 ms latency, 2 ms jitter, 1 % loss, a clock offset and 20 ppm drift)
to a proxy in this process, which forwards every datagram to ``trackflow run --record``
(NatNet: both ways, the handshake and round trips included) and adds, after a real datagram
with probability ``--rate``, one of: random bytes, a truncated copy, a copy with one bit
flipped, an oversized datagram (60 kB); and every 0.5 s a copy with a bogus frame counter
(DTrack ``fr 999999999``, NatNet frame number 999,999,999). Reported per protocol: what was
sent and injected, what ``trackflow run`` took and rejected (by reason), and the error of
every recorded sample's exposure time against the sender's truth (matched by position),
over the run after its first second. The bar: p99 within 0.5 ms.

Usage: ``python bench/fuzz_live.py [--seconds 30] [--rate 0.1] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import random
import re
import selectors
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from trackflow.io import read_stream

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
from trackers_e2e import match  # noqa: E402  (the same matching of samples to the truth)

SETUP = """frames: [W, B]
sensors:
  - name: s
    source: W
    target: B
    rate_hz: 120
    sigma_pos_mm: 0.3
    sigma_ori_deg: 0.1
    motion: {{n_dp: 1, n_do: 1, noise: [0.0, 3.0, 0.0, 10.0]}}
    input: {input}
queries:
  - {{name: q, source: W, target: B, mode: push, rate_hz: 60}}
"""
KINDS = ("random", "truncated", "bit flip", "oversized")


def _port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class FaultyLink:
    """A UDP proxy that forwards datagrams and injects garbage after them (module
    docstring). ``upstream`` is where the tracker listens (NatNet: its command port) or
    ``None`` (DTrack: the tracker sends to us); ``client`` is where trackflow listens
    (DTrack) or ``None`` (NatNet: learnt from its first request)."""

    def __init__(self, protocol: str, client: int | None, upstream: int | None, rate: float):
        self.protocol, self.rate = protocol, rate
        self.front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # the tracker's side
        self.front.bind(("127.0.0.1", 0))
        self.port = self.front.getsockname()[1]
        self.back = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # towards the tracker
        self.back.bind(("127.0.0.1", 0))
        self.client = None if client is None else ("127.0.0.1", client)
        self.upstream = None if upstream is None else ("127.0.0.1", upstream)
        self.injected = dict.fromkeys((*KINDS, "bogus frame counter"), 0)
        self.forwarded = 0
        self.rng = random.Random(7)
        self._stop = threading.Event()
        self._next_bogus = time.monotonic() + 0.5
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _garbage(self, real: bytes) -> tuple[str, bytes]:
        kind = self.rng.choice(KINDS)
        if kind == "random":
            return kind, self.rng.randbytes(self.rng.randint(1, 400))
        if kind == "truncated":
            return kind, real[: self.rng.randint(0, max(len(real) - 1, 0))]
        if kind == "bit flip":
            b = bytearray(real)
            b[self.rng.randrange(len(b))] ^= 1 << self.rng.randrange(8)
            return kind, bytes(b)
        return kind, self.rng.randbytes(60_000)

    def _bogus(self, real: bytes) -> bytes | None:
        if self.protocol == "dtrack":
            out = re.sub(rb"^fr \d+", b"fr 999999999", real)
            return out if out != real else None
        if len(real) >= 8 and real[:2] == (7).to_bytes(2, "little"):  # FRAMEOFDATA
            return real[:4] + (999_999_999).to_bytes(4, "little") + real[8:]
        return None

    def _to_client(self, data: bytes) -> None:
        if self.client is None:
            return
        self.front.sendto(data, self.client)
        self.forwarded += 1
        if self.rng.random() < self.rate:
            kind, junk = self._garbage(data)
            self.front.sendto(junk, self.client)
            self.injected[kind] += 1
        if time.monotonic() >= self._next_bogus:
            bogus = self._bogus(data)
            if bogus is not None:
                self.front.sendto(bogus, self.client)
                self.injected["bogus frame counter"] += 1
                self._next_bogus += 0.5

    def _run(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self.front, selectors.EVENT_READ)
        sel.register(self.back, selectors.EVENT_READ)
        while not self._stop.is_set():
            for key, _ in sel.select(0.1):
                try:
                    data, addr = key.fileobj.recvfrom(65536)
                except OSError:
                    continue
                if key.fileobj is self.back:  # the tracker answers (NatNet)
                    self._to_client(data)
                elif self.upstream is not None:  # NatNet: trackflow asks the tracker
                    self.client = addr
                    self.back.sendto(data, self.upstream)
                else:  # DTrack: the tracker's output
                    self._to_client(data)
        sel.close()

    def close(self) -> None:
        self._stop.set()
        self.thread.join(5)
        self.front.close()
        self.back.close()


def _trackflow(*args) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    return subprocess.Popen([sys.executable, "-m", "trackflow.cli.main", *map(str, args)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)  # fmt: skip


def _listening(run: subprocess.Popen, timeout_s: float) -> None:
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in run.stderr], daemon=True).start()
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if lines.get(timeout=0.5).startswith("listening:"):
                return
        except queue.Empty:
            continue
    raise RuntimeError("trackflow run did not listen")


def measure(protocol: str, recording: Path, seconds: float, rate: float, folder: Path) -> dict:
    track = _port()
    if protocol == "dtrack":
        link = FaultyLink("dtrack", track, None, rate)
        spec = f"{{dtrack: {{port: {track}, body: 1}}}}"
        sim_port = link.port
    else:
        sim_port = _port()
        link = FaultyLink("natnet", None, sim_port, rate)
        spec = f"{{natnet: {{command_port: {link.port}, body: rig}}}}"
    setup = folder / f"{protocol}.yaml"
    setup.write_text(SETUP.format(input=spec))
    record = folder / f"{protocol}.tfrec"
    truth_path = folder / f"{protocol}.truth.tfrec"
    run = _trackflow("run", setup, "--record", record, "--duration", seconds + 15, "--json")
    try:
        _listening(run, 120)
        sim = _trackflow(
            "simulate", protocol, recording, "--port", sim_port, "--latency-ms", 5,
            "--clock-offset-s", -3600.5, "--drift-ppm", 20, "--jitter-ms", 2, "--loss", 0.01,
            "--body", "rig", "--wait", 60, "--duration", seconds, "--truth", truth_path,
        )  # fmt: skip
        sent = json.loads(sim.communicate(timeout=seconds + 120)[0])
        run.send_signal(2)  # Ctrl-C: the recording closed, the summary printed
        summary = json.loads(run.communicate(timeout=60)[0])
    finally:
        link.close()
        for p in (run,):
            if p.poll() is None:
                p.kill()
                p.communicate()
    truth, _ = read_stream(truth_path)
    got, _ = read_stream(folder / f"{protocol}.s.tfrec")
    samples = [_Sample(t, p) for t, p in zip(got.t_ns.tolist(), got.position)]
    idx, exact, err_us = match(samples, truth)
    t_rel = (truth.t_ns[idx] - truth.t_ns[0]) * 1e-9
    settled = np.abs(err_us[t_rel > 1.0])
    st = summary["sensors"]["s"]
    return {
        "sent": sent["sent"],
        "forwarded": link.forwarded,
        "injected": link.injected,
        "measurements": st["measurements"],
        "recorded": len(got.t_ns),
        "rejections": st["rejections"],
        "dropped": st["dropped"],
        "connection": st["connection"],
        "positions_exact_f32": exact,
        "time_error_us_after_1s": {
            "p50": float(np.percentile(settled, 50)),
            "p99": float(np.percentile(settled, 99)),
            "max": float(settled.max()),
        },
    }


class _Sample:
    __slots__ = ("t_ns", "position")

    def __init__(self, t_ns, position):
        self.t_ns, self.position = t_ns, position


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--rate", type=float, default=0.1, help="garbage per real datagram")
    room1 = ROOT.parent / "shared" / "data" / "tumvi" / "dataset-room1_512_16.txt"
    ap.add_argument("--recording", type=Path, default=room1)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if not args.recording.exists():
        print(f"needs {args.recording}", file=sys.stderr)
        return 2
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for protocol in ("dtrack", "natnet"):
            out[protocol] = measure(protocol, args.recording, args.seconds, args.rate, Path(tmp))
            p99 = out[protocol]["time_error_us_after_1s"]["p99"]
            print(f"{protocol}: p99 {p99:.1f} us", file=sys.stderr, flush=True)
    out["bar_p99_us"] = 500.0
    print(json.dumps(out) if args.json else json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
