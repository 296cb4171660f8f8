"""Live inputs: packets of one tracker -> time-mapped, converted pose samples of one body.

Each input has a pure part, :meth:`LiveInput.handle` (bytes + host arrival time -> samples;
keeps the protocol state: handshake, model names, frame counter, clock mapping) that tests
drive without sockets, and a transport (:meth:`LiveInput.start`) on stdlib sockets with
timeouts that feeds it from a thread. Exposure times come from the protocol wherever it has
them (NatNet mid-exposure/transmit ticks, DTrack ``ts2`` latency, the VRPN source stamp);
a packet is never stamped on arrival when the protocol has better.
"""

from __future__ import annotations

import math
import selectors
import socket
import threading
import time
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from . import dtrack, natnet, vrpn
from ._packet import PacketError
from .axes import BoundaryConversion
from .clock import ClockMapper
from .spec import InputSpec
from .status import SensorStatus

__all__ = ["DTrackInput", "LiveInput", "NatNetInput", "Sample", "VrpnInput", "make_input"]

#: The host clock of live runs: ``time.time_ns`` (Unix time, integer ns).
host_ns = time.time_ns


class Sample(NamedTuple):
    """One pose of a live body in trackflow's conventions.

    ``t_ns`` is the exposure time mapped onto the host clock and ``arrival_ns`` the host
    receive time [ns]; ``position`` (3,) [m], ``quaternion`` (4,) ``(x, y, z, w)`` unit,
    ``covariance`` (6, 6) over ``(dt, dtheta)`` exactly symmetric.
    """

    t_ns: int
    arrival_ns: int
    position: np.ndarray
    quaternion: np.ndarray
    covariance: np.ndarray


Sink = Callable[["LiveInput", bytes, int], None]


class LiveInput:
    """Base of the protocol inputs.

    Parameters
    ----------
    name : str
        The sensor (edge) name.
    spec : InputSpec
    covariance : ndarray (6, 6)
        The sensor's nominal measurement covariance (setup), used when the protocol sends
        none, and scaled by NatNet's mean marker error.
    """

    protocol = ""

    def __init__(self, name: str, spec: InputSpec, covariance):
        self.name = name
        self.spec = spec
        self.options = spec.options
        self.nominal = np.asarray(covariance, dtype=float).reshape(6, 6)
        self.conv = BoundaryConversion(spec.unit_scale, spec.up)
        self.clock = ClockMapper()
        self.status = SensorStatus(name, self.protocol)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._socks: list[socket.socket] = []

    # -- pure part --------------------------------------------------------------------------------
    def handle(self, data: bytes, arrival_ns: int) -> list[Sample]:
        """Decode one packet; rejections are counted in :attr:`status`, never raised."""
        self.status.packets += 1
        try:
            return self._handle(data, arrival_ns)
        except PacketError as exc:
            self.status.reject(exc.reason)
            return []

    def _handle(self, data: bytes, arrival_ns: int) -> list[Sample]:  # pragma: no cover
        raise NotImplementedError

    def _map(self, tx_ns: int, latency_ns: int, arrival_ns: int) -> int:
        """Exposure time on the host clock: the send time ``tx_ns`` (tracker clock) mapped
        by the envelope fit, minus the protocol's exposure-to-send latency."""
        self.clock.add(tx_ns, arrival_ns)
        self.status.clock = self.clock.estimate
        return self.clock.to_host(tx_ns) - latency_ns

    def _sample(self, t_ns: int, arrival_ns: int, position, quaternion, cov) -> Sample:
        p, q = self.conv.pose(position, quaternion)
        if not (np.isfinite(p).all() and np.isfinite(q).all()):
            raise PacketError("non-finite pose", self.name)
        n = math.sqrt(float(q @ q))
        if not 0.9 < n < 1.1:
            raise PacketError("non-unit quaternion", f"|q| = {n:.4g}")
        q = q / n
        c = self.conv.covariance(cov)
        c = 0.5 * (c + c.T)
        if not np.isfinite(c).all():
            raise PacketError("invalid covariance", self.name)
        self.status.measured(arrival_ns, t_ns)
        return Sample(int(t_ns), int(arrival_ns), p, q, c)

    # -- transport -------------------------------------------------------------------------------
    def start(self, sink: Sink) -> None:
        """Open the sockets and start the receiving thread; every packet goes to
        ``sink(input, data, arrival_ns)`` (which normally calls :meth:`handle`)."""
        self._stop.clear()
        t = threading.Thread(target=self._run, args=(sink,), name=f"input-{self.name}", daemon=True)
        self._threads.append(t)
        t.start()

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout)
        self._threads.clear()
        for s in self._socks:
            s.close()
        self._socks.clear()

    def _run(self, sink: Sink) -> None:  # pragma: no cover
        raise NotImplementedError

    def _udp(self, bind: tuple[str, int], group: str | None = None) -> socket.socket:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        if group:
            s.bind(("", bind[1]))
            mreq = socket.inet_aton(group) + socket.inet_aton(bind[0])
            s.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
        else:
            s.bind(bind)
        s.settimeout(0.2)
        self._socks.append(s)
        return s


# -- DTrack ---------------------------------------------------------------------------------------
class DTrackInput(LiveInput):
    """A DTrack body from the UDP output (``ts2`` latency preferred, else ``ts`` with the
    configured ``latency_ms``); optional TCP command channel sends
    ``dtrack2 tracking start``."""

    protocol = "dtrack"

    def __init__(self, name, spec, covariance):
        super().__init__(name, spec, covariance)
        self.days = dtrack.DayUnwrapper()

    def _handle(self, data, arrival_ns):
        f = dtrack.decode_dtrack(data)
        if f.frame is not None and not self.status.frame(f.frame):
            return []
        body = f.body(self.options["body"])
        if body is None:
            raise PacketError("body not in frame", f"body {self.options['body']}")
        _, q = dtrack.dtrack_pose(body)
        R = np.asarray(body.rotation).reshape(3, 3)
        c = f.covariance(body.id)
        cov = dtrack.dtrack_covariance(R, c) if c is not None else self.nominal
        if f.ts2 is not None:
            stamp = f.ts2[0] * 1_000_000_000 + f.ts2[1] * 1000
            lat = f.ts2[2] * 1000
        elif f.ts is not None:
            stamp = int(round(self.days(f.ts) * 1e9))
            lat = int(round(self.options["latency_ms"] * 1e6))
        else:
            raise PacketError("no timestamp", "the DTrack output has neither ts nor ts2")
        t = self._map(stamp + lat, lat, arrival_ns)
        return [self._sample(t, arrival_ns, body.position_mm, q, cov)]

    def _run(self, sink):
        o = self.options
        try:
            s = self._udp((o["interface"], o["port"]), o["group"])
            if o["command"]:
                self.command(o["command"], o["command_port"], "dtrack2 tracking start")
        except OSError as exc:
            self.status.reject(f"socket error: {exc.strerror or exc}")
            return
        self.status.connected = True
        while not self._stop.is_set():
            try:
                data = s.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                break
            sink(self, data, host_ns())

    def command(self, host: str, port: int, text: str, timeout: float = 2.0) -> str:
        """Send a DTrack2 command over TCP (NUL-terminated) and return the reply; a reply
        other than ``dtrack2 ok`` is counted as ``command refused``."""
        with socket.create_connection((host, port), timeout=timeout) as c:
            c.sendall(text.encode("ascii") + b"\0")
            reply = b""
            while not reply.endswith(b"\0") and len(reply) < 4096:
                chunk = c.recv(4096)
                if not chunk:
                    break
                reply += chunk
        answer = reply.rstrip(b"\0").decode("ascii", "replace")
        if answer != "dtrack2 ok":
            self.status.reject("command refused")
        return answer


# -- NatNet ---------------------------------------------------------------------------------------
class NatNetInput(LiveInput):
    """A NatNet rigid body: CONNECT/SERVERINFO handshake, MODELDEF for names, unicast
    KEEPALIVE (or multicast), exposure from the mid-exposure and transmit ticks."""

    protocol = "natnet"

    def __init__(self, name, spec, covariance):
        super().__init__(name, spec, covariance)
        self.server: natnet.ServerInfo | None = None
        self.models: natnet.ModelDefinitions | None = None
        body = self.options["body"]
        self.body_id: int | None = body if isinstance(body, int) else None
        self.ref_error = math.sqrt(float(np.trace(self.nominal[:3, :3])) / 3.0)

    def _handle(self, data, arrival_ns):
        msg, payload = natnet.decode_message(data)
        if msg == natnet.SERVERINFO:
            self.server = natnet.decode_server_info(payload)
            return []
        if msg == natnet.MODELDEF:
            if self.server is None:
                raise PacketError("no handshake yet", "MODELDEF before SERVERINFO")
            self.models = natnet.decode_model_definitions(payload, self.server.version)
            if self.body_id is None:
                self.body_id = self.models.id_of(self.options["body"])
            return []
        if msg != natnet.FRAMEOFDATA:
            if msg in (natnet.MESSAGESTRING, natnet.RESPONSE, natnet.KEEPALIVE):
                return []
            raise PacketError("unexpected message", f"id {msg}")
        if self.server is None:
            raise PacketError("no handshake yet", "frame before SERVERINFO")
        if self.body_id is None:
            raise PacketError("unknown body name", str(self.options["body"]))
        f = natnet.decode_frame(payload, self.server.version)
        if not self.status.frame(f.frame):
            return []
        b = f.body(self.body_id)
        if b is None:
            raise PacketError("body not in frame", f"id {self.body_id}")
        if b.valid is False:
            raise PacketError("not tracked", f"id {self.body_id}")
        timing = natnet.exposure_and_latency(f, self.server.clock_frequency)
        if timing is not None:
            freq = self.server.clock_frequency
            tx_ns = f.transmit // freq * 1_000_000_000 + (f.transmit % freq) * 1_000_000_000 // freq
            lat_ns = (f.transmit - f.mid_exposure) * 1_000_000_000 // freq
        else:  # before NatNet 3.0: the frame timestamp, latency unknown
            tx_ns, lat_ns = int(round(f.timestamp * 1e9)), 0
        t = self._map(tx_ns, lat_ns, arrival_ns)
        cov = self.nominal
        if b.mean_error is not None and self.ref_error > 0:
            err = b.mean_error * self.conv.scale
            if not math.isfinite(err) or err < 0:
                raise PacketError("bad mean error", f"{b.mean_error}")
            cov = cov * max(1.0, (err / self.ref_error) ** 2)
        return [self._sample(t, arrival_ns, b.position, b.quaternion, cov)]

    def _run(self, sink):
        o = self.options
        server = (o["server"], o["command_port"])
        try:
            cmd = self._udp((o["interface"], 0))
            data = self._udp(
                (o["interface"], o["data_port"] if o["multicast"] else 0),
                o["group"] if o["multicast"] else None,
            )
        except OSError as exc:
            self.status.reject(f"socket error: {exc.strerror or exc}")
            return
        sel = selectors.DefaultSelector()
        sel.register(cmd, selectors.EVENT_READ)
        sel.register(data, selectors.EVENT_READ)
        next_connect = next_keepalive = 0.0
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                try:
                    if self.server is None and now >= next_connect:
                        cmd.sendto(natnet.encode_connect(), server)
                        next_connect = now + 0.5
                    elif self.server is not None and self.models is None and now >= next_connect:
                        cmd.sendto(natnet.encode_message(natnet.REQUEST_MODELDEF), server)
                        next_connect = now + 0.5
                    if not o["multicast"] and now >= next_keepalive:
                        data.sendto(natnet.encode_message(natnet.KEEPALIVE), server)
                        next_keepalive = now + 1.0
                except OSError:
                    self.status.reject("send failed")
                for key, _ in sel.select(timeout=0.1):
                    try:
                        raw = key.fileobj.recv(65536)
                    except (TimeoutError, BlockingIOError):
                        continue
                    except OSError:  # e.g. ICMP port unreachable while no server runs
                        continue
                    arrival = host_ns()
                    self.status.connected = self.server is not None
                    sink(self, raw, arrival)
        finally:
            sel.close()


# -- VRPN -----------------------------------------------------------------------------------------
class VrpnInput(LiveInput):
    """A VRPN tracker sensor over TCP (``Name@host[:port]``), reconnecting after errors.
    ``clock: map`` estimates the server's clock offset (subtracting ``latency_ms``, the
    server's known exposure-to-send latency); ``clock: host`` trusts the stamps as host
    time (a synchronised clock)."""

    protocol = "vrpn"

    def __init__(self, name, spec, covariance):
        super().__init__(name, spec, covariance)
        self.device, self.host, self.port = spec.vrpn_address
        self.decoder = vrpn.StreamDecoder()
        self.broken = False

    def reset_stream(self) -> None:
        """A new connection: a fresh decoder that expects the server's cookie."""
        self.decoder = vrpn.StreamDecoder()
        self.broken = False

    def _handle(self, data, arrival_ns):
        try:
            reports = self.decoder.feed(data)
        except PacketError:
            self.broken = True  # a TCP stream cannot be resynchronised: reconnect
            raise
        out = []
        lat = int(round(self.options["latency_ms"] * 1e6))
        for r in reports:
            if r.device != self.device or r.sensor != self.options["sensor"]:
                continue
            stamp = r.sec * 1_000_000_000 + r.usec * 1000
            if self.options["clock"] == "host":
                t = stamp
            else:
                t = self._map(stamp + lat, lat, arrival_ns)
            try:
                out.append(self._sample(t, arrival_ns, r.position, r.quaternion, self.nominal))
            except PacketError as exc:
                self.status.reject(exc.reason)
        return out

    def _run(self, sink):
        timeout = self.options["timeout_ms"] * 1e-3
        while not self._stop.is_set():
            try:
                conn = socket.create_connection((self.host, self.port), timeout=timeout)
            except OSError:
                self.status.reject("connection failed")
                self._stop.wait(0.5)
                continue
            self._socks.append(conn)
            self.reset_stream()
            try:
                conn.sendall(
                    vrpn.make_cookie()
                    + vrpn.encode_description(vrpn.SENDER_DESCRIPTION, 0, self.device)
                    + vrpn.encode_description(vrpn.TYPE_DESCRIPTION, 0, vrpn.POS_QUAT)
                )
                conn.settimeout(0.2)
                self.status.connected = True
                while not self._stop.is_set():
                    try:
                        raw = conn.recv(65536)
                    except TimeoutError:
                        continue
                    if not raw:
                        self.status.reject("connection closed")
                        break
                    sink(self, raw, host_ns())
                    if self.broken:
                        break
            except OSError:
                self.status.reject("connection lost")
            finally:
                self.status.connected = False
                conn.close()
                if conn in self._socks:
                    self._socks.remove(conn)
            self._stop.wait(0.2)


_INPUTS = {"dtrack": DTrackInput, "natnet": NatNetInput, "vrpn": VrpnInput}


def make_input(name: str, spec: InputSpec, covariance) -> LiveInput:
    """The live input of a sensor's ``input:`` spec."""
    return _INPUTS[spec.protocol](name, spec, covariance)
