"""Simulated trackers: replay a real recording as DTrack, NatNet or VRPN packets on loopback.

A sample recorded at time ``t_i`` is exposed at host time ``start + (t_i - t_0) / speed``;
the tracker's clock reads ``host + clock_offset`` (plus ``drift``); the packet is stamped
``latency`` after the exposure (NatNet transmit tick, DTrack ``ts2`` latency), then waits a
random ``U(0, jitter)`` in the "network" and is sent; a fraction ``loss`` of the frames is
never sent (their frame numbers are skipped, as a real loss). In an ``outage`` window
``(a, b)`` [s after the first frame] no frame is sent (occluded markers, a tracker that
stopped); in a ``freeze`` window the frames are held and leave together at ``b`` (a sender
process that was stopped and continued). ``noise_mm``/``noise_deg`` add seeded Gaussian
noise of that sigma per axis to the sent positions and orientations (``R Exp(n)``);
``changes`` switch latency and noise at given times (a tracker that degrades mid-run).
``truth`` receives the exposure host times and the noise-free poses of the sent frames, so a
receiver's mapped times and errors can be checked.
"""

from __future__ import annotations

import heapq
import socket
import struct
import threading
import time
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..io import PoseStream, read_stream, write_stream
from ..math import quat_exp, quat_multiply, quat_to_matrix
from . import dtrack, natnet
from ._packet import PacketError
from .vrpn_server import VrpnTrackerServer

__all__ = ["SimConfig", "Simulator", "simulate"]


@dataclass
class SimConfig:
    """How a recording is replayed (units in the names)."""

    protocol: str
    host: str = "127.0.0.1"
    port: int = 0
    latency_ms: float = 5.0
    clock_offset_s: float = 0.0
    drift_ppm: float = 0.0
    loss: float = 0.0
    jitter_ms: float = 0.0
    speed: float = 1.0
    duration_s: float | None = None
    start_s: float = 0.0
    seed: int = 0
    version: tuple[int, int] = (4, 1)
    body_id: int = 1
    body_name: str = "body"
    bodies: int = 1
    device: str = "Tracker0"
    clock_frequency: int = 10_000_000
    command_port: int | None = None
    multicast_group: str | None = None  # NatNet: stream to this group ...
    data_port: int = 1511  # ... on this port (through the interface ``host``)
    outages: tuple[tuple[float, float], ...] = ()  # no frames sent in [a, b) [s]
    freezes: tuple[tuple[float, float], ...] = ()  # frames of [a, b) held, sent at b [s]
    noise_mm: float = 0.0  # position noise sigma per axis [mm]
    noise_deg: float = 0.0  # orientation noise sigma per axis [deg]
    #: from ``at`` [s] on: ``{"latency_ms": .., "noise_mm": .., "noise_deg": ..}`` (any of them)
    changes: tuple[tuple[float, dict], ...] = ()
    #: plays of the (chosen part of the) recording, every second one backwards, so that the
    #: motion stays continuous and a soak can run for hours on a short recording
    plays: int = 1


class Simulator:
    """Replays ``stream`` as packets of ``cfg.protocol``; :meth:`run` blocks until done.

    The sockets are opened in the constructor, so :attr:`port` (the NatNet command port,
    the DTrack destination port or the VRPN server port) is known before :meth:`run`.
    """

    def __init__(self, stream: PoseStream, cfg: SimConfig):
        if cfg.protocol not in ("natnet", "dtrack", "vrpn"):
            raise InputError(f"unknown protocol {cfg.protocol!r} (natnet, dtrack, vrpn)")
        if not (0 <= cfg.loss < 1 and cfg.jitter_ms >= 0 and cfg.latency_ms >= 0):
            raise InputError("need 0 <= loss < 1, jitter_ms >= 0, latency_ms >= 0")
        if not cfg.speed > 0:
            raise InputError("speed must be > 0")
        if not 1 <= cfg.bodies <= 1000:
            raise InputError("bodies must be 1 .. 1000")
        if not 1 <= cfg.plays <= 100_000:
            raise InputError("plays must be 1 .. 100000")
        if not (cfg.noise_mm >= 0 and cfg.noise_deg >= 0):
            raise InputError("need noise_mm >= 0 and noise_deg >= 0")
        for at, change in cfg.changes:
            unknown = set(change) - {"latency_ms", "noise_mm", "noise_deg"}
            if at < 0 or unknown or any(not v >= 0 for v in change.values()):
                raise InputError(
                    f"a change at {at} s needs a time >= 0 and latency_ms, noise_mm, noise_deg "
                    f">= 0 (got {change})"
                )
        for a, b in (*cfg.outages, *cfg.freezes):
            if not 0 <= a < b:
                raise InputError(f"an outage or freeze window needs 0 <= start < end, got {a}:{b}")
        if cfg.protocol == "natnet" and not (2, 0) <= tuple(cfg.version) <= (4, 1):
            raise InputError(f"NatNet {cfg.version[0]}.{cfg.version[1]} is not supported (2.0-4.1)")
        t = (stream.t_ns - stream.t_ns[0]).astype(np.float64) * 1e-9
        keep = t >= cfg.start_s
        if cfg.duration_s is not None:
            keep &= t < cfg.start_s + cfg.duration_s
        if not keep.any():
            raise InputError("no samples in the chosen part of the recording")
        self.cfg = cfg
        self.rel_s = (t[keep] - cfg.start_s) / cfg.speed
        self.position = stream.position[keep]
        self.quaternion = stream.quaternion[keep]
        dt = np.diff(t)
        rate = 1.0 / float(np.median(dt[dt > 0])) if len(dt) else 100.0
        self.frames = np.round(t[keep] * rate).astype(np.int64) + 1
        if cfg.plays > 1:
            self._play_again(cfg.plays, 1.0 / (rate * cfg.speed))
        self.latency_ns, self._dp, self._dq = self._per_frame(cfg)
        self.stop = threading.Event()
        self.sent = 0
        self.lost = 0
        self.withheld = 0  # frames of the outage windows
        self.truth_t: list[int] = []
        self.truth_i: list[int] = []
        self._clients: set = set()
        self._started = threading.Event()
        self.vrpn = None
        if cfg.protocol == "vrpn":
            self.vrpn = VrpnTrackerServer(cfg.device, cfg.host, cfg.port)
            self.port = self.vrpn.port
        else:
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            if cfg.protocol == "natnet":
                self.sock.bind((cfg.host, cfg.port))
                self.port = self.sock.getsockname()[1]
                self.sock.settimeout(0.05)
                if cfg.multicast_group:
                    self.sock.setsockopt(
                        socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(cfg.host)
                    )
                    self.sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
            else:
                self.port = cfg.port
        self._cmd = None
        if cfg.protocol == "dtrack" and cfg.command_port is not None:
            self._cmd = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self._cmd.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._cmd.bind((cfg.host, cfg.command_port))
            self._cmd.listen(2)
            self._cmd.settimeout(0.2)
            self.command_port = self._cmd.getsockname()[1]
        else:
            self._started.set()

    def _per_frame(self, cfg: SimConfig):
        """Each frame's latency [ns], position noise [m] and orientation noise (unit
        quaternions), after ``cfg.changes``."""
        n = len(self.rel_s)
        lat = np.full(n, cfg.latency_ms)
        sp, so = np.full(n, cfg.noise_mm), np.full(n, cfg.noise_deg)
        for at, change in sorted(cfg.changes, key=lambda c: c[0]):
            later = self.rel_s >= at
            for key, arr in (("latency_ms", lat), ("noise_mm", sp), ("noise_deg", so)):
                if key in change:
                    arr[later] = change[key]
        rng = np.random.default_rng([cfg.seed, 1])
        dp = rng.standard_normal((n, 3)) * (sp * 1e-3)[:, None]
        dq = quat_exp(rng.standard_normal((n, 3)) * np.radians(so)[:, None])
        return np.round(lat * 1e6).astype(np.int64), dp, dq

    def sent_quaternion(self, i: int) -> np.ndarray:
        """The orientation sent for frame ``i`` (with its noise)."""
        return quat_multiply(self.quaternion[i], self._dq[i])

    # -- tracker clock ----------------------------------------------------------------------
    def tracker_ns(self, host: int) -> int:
        c = self.cfg
        return host + int(round(c.clock_offset_s * 1e9 + c.drift_ppm * 1e-6 * host))

    # -- servers ----------------------------------------------------------------------------
    def _natnet_server(self) -> None:
        c = self.cfg
        group = tuple(int(x) for x in (c.multicast_group or "239.255.42.99").split("."))
        info = natnet.ServerInfo(
            "trackflow simulate",
            (3, 1, 0, 0),
            (c.version[0], c.version[1], 0, 0),
            c.clock_frequency if c.version >= (3, 0) else None,
            c.data_port,
            c.multicast_group is not None,
            group,
        )
        defs = natnet.ModelDefinitions(
            tuple(
                natnet.RigidBodyDescription(self.body_label(k), c.body_id + k)
                for k in range(c.bodies)
            )
        )
        while not self.stop.is_set():
            try:
                data, addr = self.sock.recvfrom(65536)
            except TimeoutError:
                continue
            except OSError:
                break
            try:
                msg, payload = natnet.decode_message(data)
            except PacketError:
                continue
            if msg == natnet.CONNECT:
                self.sock.sendto(natnet.encode_server_info(info), addr)
                if c.multicast_group:
                    self._clients.add((c.multicast_group, c.data_port))
            elif msg == natnet.REQUEST_MODELDEF:
                self.sock.sendto(natnet.encode_model_definitions(defs, c.version), addr)
            elif msg == natnet.KEEPALIVE:
                self._clients.add(addr)
            elif msg == natnet.ECHOREQUEST and c.version >= (3, 0) and len(payload) >= 8:
                (token,) = struct.unpack_from("<Q", payload)
                ticks = self.tracker_ns(time.time_ns()) * c.clock_frequency // 1_000_000_000
                self.sock.sendto(natnet.encode_echo_response(token, ticks), addr)
            elif msg == natnet.ECHOREQUEST:  # NatNet 2.x: unknown request
                self.sock.sendto(natnet.encode_message(natnet.UNRECOGNIZED), addr)

    def _dtrack_commands(self) -> None:
        while not self.stop.is_set():
            try:
                conn, _ = self._cmd.accept()
            except TimeoutError:
                continue
            except OSError:
                break
            with conn:
                conn.settimeout(1.0)
                try:
                    text = conn.recv(4096).split(b"\0", 1)[0].decode("ascii", "replace")
                except OSError:
                    continue
                ok = text in ("dtrack2 tracking start", "dtrack2 tracking stop")
                conn.sendall((b"dtrack2 ok" if ok else b"dtrack2 err 1") + b"\0")
                if text == "dtrack2 tracking start":
                    self._started.set()

    # -- packets ----------------------------------------------------------------------------
    def body_label(self, k: int) -> str:
        """Name of body ``k`` (the first is ``body_name``, then ``body_name_2`` ...)."""
        return self.cfg.body_name if k == 0 else f"{self.cfg.body_name}_{k + 1}"

    def body_position(self, i: int, k: int) -> np.ndarray:
        """Body ``k`` moves like the recording, shifted by ``0.1 k`` m along x (with frame
        ``i``'s noise)."""
        p = self.position[i] + self._dp[i]
        return p if k == 0 else p + np.array([0.1 * k, 0.0, 0.0])

    def _packet(self, i: int, exp_host: int, tx_host: int) -> bytes | None:
        c = self.cfg
        q = self.sent_quaternion(i)
        exp_tr, tx_tr = self.tracker_ns(exp_host), self.tracker_ns(tx_host)
        if c.protocol == "natnet":
            f = c.clock_frequency
            bodies = tuple(
                natnet.NatNetRigidBody(
                    c.body_id + k, tuple(self.body_position(i, k)), tuple(q), 0.0002, True
                )
                for k in range(c.bodies)
            )
            fr = natnet.NatNetFrame(
                int(self.frames[i]),
                bodies,
                timestamp=exp_tr * 1e-9,
                mid_exposure=exp_tr * f // 1_000_000_000,
                data_received=exp_tr * f // 1_000_000_000,
                transmit=tx_tr * f // 1_000_000_000,
                precision=(exp_tr // 1_000_000_000, 0),
            )
            return natnet.encode_frame(fr, c.version)
        if c.protocol == "dtrack":
            sec, rest = divmod(exp_tr, 1_000_000_000)
            usec = rest // 1000
            lat_us = (tx_tr - (sec * 1_000_000_000 + usec * 1000)) // 1000
            R = tuple(quat_to_matrix(q).ravel())
            bodies = tuple(
                dtrack.DTrackBody(
                    c.body_id + k, 1.0, tuple(float(x) * 1e3 for x in self.body_position(i, k)), R
                )
                for k in range(c.bodies)
            )
            fr = dtrack.DTrackFrame(
                int(self.frames[i]), None, (sec, usec, lat_us), c.bodies, bodies
            )
            return dtrack.encode_dtrack(fr, digits=None, rot_digits=None)
        return None

    def _send(self, i: int, exp_host: int, data: bytes | None) -> None:
        c = self.cfg
        if c.protocol == "vrpn":
            # the header time is the exposure on the server's clock
            for k in range(c.bodies):
                self.vrpn.report(
                    k, self.body_position(i, k), self.sent_quaternion(i),
                    self.tracker_ns(exp_host),
                )  # fmt: skip
            return
        if c.protocol == "natnet":
            for addr in list(self._clients):
                self.sock.sendto(data, addr)
        else:
            self.sock.sendto(data, (c.host, self.port))

    def _play_again(self, plays: int, step_s: float) -> None:
        """The recording played ``plays`` times in a row, every second play backwards (the
        poses in reverse order on the same time grid), one frame period between plays; frame
        numbers and times go on."""
        n = len(self.rel_s)
        span = float(self.rel_s[-1]) + step_s
        back = np.arange(n)[::-1]
        order = np.concatenate([back if k % 2 else np.arange(n) for k in range(plays)])
        self.rel_s = np.concatenate([self.rel_s + k * span for k in range(plays)])
        self.position = self.position[order]
        self.quaternion = self.quaternion[order]
        frame_span = int(self.frames[-1] - self.frames[0]) + 1
        self.frames = np.concatenate([self.frames + k * frame_span for k in range(plays)])

    def run(self, wait_for_client_s: float = 10.0) -> dict:
        """Replay; returns counts. Waits up to ``wait_for_client_s`` for a first client
        (NatNet keep-alive, VRPN connection, DTrack ``tracking start``) before starting."""
        c = self.cfg
        threads = []
        if c.protocol == "natnet":
            threads.append(threading.Thread(target=self._natnet_server, daemon=True))
        if self._cmd is not None:
            threads.append(threading.Thread(target=self._dtrack_commands, daemon=True))
        for t in threads:
            t.start()
        deadline = time.monotonic() + wait_for_client_s
        while time.monotonic() < deadline and not self.stop.is_set():
            ready = {
                "natnet": lambda: bool(self._clients),
                "vrpn": lambda: self.vrpn.clients > 0,
                "dtrack": self._started.is_set,
            }[c.protocol]()
            if ready:
                break
            time.sleep(0.01)
        rng = np.random.default_rng(c.seed)
        lat = self.latency_ns
        start = time.time_ns() + 50_000_000
        exp = start + np.round(self.rel_s * 1e9).astype(np.int64)
        jit = np.round(rng.uniform(0.0, c.jitter_ms * 1e6, len(exp))).astype(np.int64)
        lost = rng.random(len(exp)) < c.loss
        # (stamp time, index): stamped `lat` after exposure; sent `jitter` after the stamp
        send = exp + lat + jit
        withheld = np.zeros(len(exp), bool)
        for a, b in c.outages:
            withheld |= (self.rel_s >= a) & (self.rel_s < b)
        for a, b in c.freezes:
            held = (self.rel_s >= a) & (self.rel_s < b)
            send[held] = np.maximum(send[held], start + int(round(b * 1e9)))
        heap = [(int(send[i]), i) for i in range(len(exp))]
        heapq.heapify(heap)
        try:
            while heap and not self.stop.is_set():
                send_at, i = heapq.heappop(heap)
                if withheld[i]:
                    self.withheld += 1
                    continue
                if lost[i]:
                    self.lost += 1
                    continue
                # the tracker stamps the frame `latency` after the exposure and it leaves
                # `jitter` later (network delay); the packet is built before the wait so
                # that building it does not count as transit
                packet = self._packet(i, int(exp[i]), int(exp[i] + lat[i]))
                _wait_until(send_at)
                self._send(i, int(exp[i]), packet)
                self.sent += 1
                self.truth_t.append(int(exp[i]))
                self.truth_i.append(i)
        finally:
            self.stop.set()
            for t in threads:
                t.join(2.0)
            self.close()
        return {"sent": self.sent, "lost": self.lost, "withheld": self.withheld,
                "frames": len(exp)}  # fmt: skip

    def truth(self) -> PoseStream:
        """Exposure host times and poses of the sent samples, in time order."""
        n = min(len(self.truth_t), len(self.truth_i))  # a stop may fall between the appends
        order = np.argsort(self.truth_t[:n], kind="stable")
        idx = np.asarray(self.truth_i[:n], dtype=np.int64)[order]
        t = np.asarray(self.truth_t[:n], dtype=np.int64)[order]
        return PoseStream("world", "body", t, self.position[idx], self.quaternion[idx])

    def close(self) -> None:
        if self.vrpn is not None:
            self.vrpn.close()
        else:
            self.sock.close()
        if self._cmd is not None:
            self._cmd.close()


def _wait_until(t_ns: int) -> int:
    """Sleep until host time ``t_ns`` (the last half millisecond spinning, so packets leave
    on time on a loaded machine); returns the host time reached."""
    while True:
        now = time.time_ns()
        left = t_ns - now
        if left <= 0:
            return now
        if left > 500_000:
            time.sleep((left - 400_000) * 1e-9)


def simulate(recording, cfg: SimConfig, truth_path=None, wait_for_client_s: float = 10.0) -> dict:
    """Replay ``recording`` (any format ``trackflow.io`` reads) as ``cfg.protocol`` packets;
    optionally write the truth (exposure host times, poses) to ``truth_path``."""
    stream, _ = read_stream(recording)
    sim = Simulator(stream, cfg)
    try:
        return sim.run(wait_for_client_s)
    finally:  # also when stopped (Ctrl-C, SIGTERM): the truth of what was sent
        if truth_path is not None and sim.truth_i:  # (appended last of a sample's records)
            write_stream(truth_path, sim.truth())
