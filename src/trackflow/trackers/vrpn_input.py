"""The live input of a VRPN tracker server (TCP, or the classic UDP connect-back)."""

from __future__ import annotations

import socket
import time

from . import vrpn
from ._packet import PacketError
from .live_input import Body, LiveInput, host_ns

__all__ = ["VrpnInput"]


class VrpnInput(LiveInput):
    """VRPN tracker sensors over TCP (``Name@host[:port]``), reconnecting after errors.
    ``connect: tcp`` connects to the server's port; ``connect: udp`` is the classic VRPN
    client: it listens on a TCP port of its own, sends ``"IP PORT\0"`` by UDP to the server's
    port (repeated every 0.25 s) and accepts the server's connection back, from the server's
    address only.
    ``clock: map`` estimates the server's clock offset (subtracting ``latency_ms``, the
    server's known exposure-to-send latency); ``clock: host`` trusts the stamps as host
    time (a synchronised clock)."""

    protocol = "vrpn"

    def __init__(self, spec):
        super().__init__(spec)
        self.host, self.port = spec.vrpn_address[1:]
        self.reset_stream()

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
        for r in reports:
            stamp = r.sec * 1_000_000_000 + r.usec * 1000
            mapped: dict[int, int] = {}

            def one(b: Body, r=r, stamp=stamp, mapped=mapped):
                if b.spec.vrpn_address[0] != r.device or b.options["sensor"] != r.sensor:
                    return None
                lat = int(round(b.options["latency_ms"] * 1e6))
                if b.options["clock"] == "host":
                    t = stamp
                else:
                    if lat not in mapped:
                        mapped[lat] = self._map(stamp + lat, lat, arrival_ns)
                    t = mapped[lat]
                return self._sample(b, t, arrival_ns, r.position, r.quaternion)

            out.extend(self._per_body(one))
        return out

    def _connect(self, timeout: float) -> socket.socket:
        """A TCP connection to the server, direct or by UDP connect-back (class docstring)."""
        if self.options["connect"] == "tcp":
            return socket.create_connection((self.host, self.port), timeout=timeout)
        server_ip = socket.gethostbyname(self.host)
        with (
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as ask,
            socket.socket(socket.AF_INET, socket.SOCK_STREAM) as lst,
        ):
            ask.connect((server_ip, self.port))  # no packet: picks the local address to announce
            lst.bind((ask.getsockname()[0], 0))
            lst.listen(1)
            lst.settimeout(0.25)
            ip, port = lst.getsockname()
            deadline = time.monotonic() + timeout
            while not self._stop.is_set() and time.monotonic() < deadline:
                ask.send(f"{ip} {port}\0".encode("ascii"))
                try:
                    conn, peer = lst.accept()
                except TimeoutError:
                    continue
                if peer[0] == server_ip:
                    conn.settimeout(timeout)
                    return conn
                conn.close()  # only the server may connect back
                self._event_all("connect-back from another host")
        raise OSError("no connect-back from the VRPN server")

    def _run(self, sink):
        timeout = self.options["timeout_ms"] * 1e-3
        devices = sorted({b.spec.vrpn_address[0] for b in self.bodies})
        while not self._stop.is_set():
            try:
                conn = self._connect(timeout)
            except OSError:
                self._event_all("connection failed")
                self.ready.set()
                self._stop.wait(0.5)
                continue
            self._socks.append(conn)
            self.reset_stream()
            try:
                hello = vrpn.make_cookie()
                for k, d in enumerate(devices):
                    hello += vrpn.encode_description(vrpn.SENDER_DESCRIPTION, k, d)
                hello += vrpn.encode_description(vrpn.TYPE_DESCRIPTION, 0, vrpn.POS_QUAT)
                conn.sendall(hello)
                conn.settimeout(0.2)
                self._connected(True)
                self.ready.set()
                while not self._stop.is_set():
                    try:
                        raw = conn.recv(65536)
                    except TimeoutError:
                        continue
                    if not raw:
                        self._event_all("connection closed")
                        break
                    sink(self, raw, host_ns())
                    if self.broken:
                        break
            except OSError:
                self._event_all("connection lost")
            finally:
                self._connected(False)
                conn.close()
                if conn in self._socks:
                    self._socks.remove(conn)
            self._stop.wait(0.2)
