"""A VRPN tracker server: applications with a VRPN client (Unity/Unreal plugins, VRPN tools)
read trackflow's answers as ``Tracker0@host`` (or ``Tracker0@tcp://host:port``).

The server listens on TCP (default port 3883, loopback unless told otherwise) and on UDP
for the classic connect-back request (``"IP PORT\\0"``, after which the server connects to the
client's TCP port). Each connection gets the cookie, the sender and type descriptions, then
every :meth:`VrpnTrackerServer.report` as a ``vrpn_Tracker Pos_Quat`` message whose header
time is the pose's time (host clock, Unix seconds and microseconds). Everything goes over TCP.
What a client sends is read: its cookie (checked), its id descriptions, and its device's
pings, each answered at once with a pong on the device's sender, as a VRPN server does
(without it every VRPN client warns "No response from server" each second). Other messages
are counted and ignored; a stream that cannot be decoded closes that client (counted).
"""

from __future__ import annotations

import selectors
import socket
import threading
import time

from . import vrpn
from ._packet import PacketError

__all__ = ["VrpnTrackerServer"]

_PONG_ID = 1  # this server's type id of the pong (0 is Pos_Quat)


class VrpnTrackerServer:
    """Serve poses as one VRPN tracker device.

    Parameters
    ----------
    device : str
        Device name (``Tracker0``).
    host, port : str, int
        Where to listen (default loopback; port 0 picks a free one, see :attr:`port`).
    """

    def __init__(self, device: str = "Tracker0", host: str = "127.0.0.1", port: int = 3883):
        self.device = device
        self._tcp = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._tcp.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._tcp.bind((host, port))
        self.host, self.port = self._tcp.getsockname()
        self._tcp.listen(8)
        self._tcp.settimeout(0.2)
        self._udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._udp.bind((host, self.port))
        self._udp.settimeout(0.2)
        self._clients: list[socket.socket] = []
        self._joining: list[socket.socket] = []  # greeted, not yet read by _read
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.rejections: dict[str, int] = {}
        self.sent = 0
        #: pings answered (every client's device pings until answered)
        self.pongs = 0
        self._threads = [
            threading.Thread(target=self._accept, daemon=True, name="vrpn-accept"),
            threading.Thread(target=self._lob, daemon=True, name="vrpn-udp"),
            threading.Thread(target=self._read, daemon=True, name="vrpn-read"),
        ]
        for t in self._threads:
            t.start()

    def _reject(self, reason: str) -> None:
        self.rejections[reason] = self.rejections.get(reason, 0) + 1

    def _greet(self, conn: socket.socket) -> None:
        conn.settimeout(2.0)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.sendall(vrpn.make_cookie())
        cookie = b""
        while len(cookie) < vrpn.COOKIE_SIZE:
            chunk = conn.recv(vrpn.COOKIE_SIZE - len(cookie))
            if not chunk:
                raise PacketError("truncated", "peer closed before its cookie")
            cookie += chunk
        vrpn.check_cookie(cookie)
        conn.sendall(
            vrpn.encode_description(vrpn.SENDER_DESCRIPTION, 0, self.device)
            + vrpn.encode_description(vrpn.TYPE_DESCRIPTION, 0, vrpn.POS_QUAT)
            + vrpn.encode_description(vrpn.TYPE_DESCRIPTION, _PONG_ID, vrpn.PONG)
        )
        conn.setblocking(False)  # reports never wait for a slow reader
        with self._lock:
            self._clients.append(conn)
            self._joining.append(conn)

    def _welcome(self, conn: socket.socket) -> None:
        try:
            self._greet(conn)
        except (OSError, PacketError) as exc:
            self._reject(getattr(exc, "reason", "connection failed"))
            conn.close()

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._tcp.accept()
            except TimeoutError:
                continue
            except OSError:
                break
            threading.Thread(target=self._welcome, args=(conn,), daemon=True).start()

    def _lob(self) -> None:
        while not self._stop.is_set():
            try:
                data, (peer, _) = self._udp.recvfrom(256)
            except TimeoutError:
                continue
            except OSError:
                break
            try:
                text = data.split(b"\0", 1)[0].decode("ascii")
                ip, port = text.split()
                port_n = int(port)
                if ip != peer or not 0 < port_n < 65536:
                    raise ValueError(text)
            except (UnicodeDecodeError, ValueError):
                self._reject("bad connect-back request")
                continue
            try:
                conn = socket.create_connection((peer, port_n), timeout=2.0)
            except OSError:
                self._reject("connect-back failed")
                continue
            threading.Thread(target=self._welcome, args=(conn,), daemon=True).start()

    def _read(self) -> None:
        """Read every client: answer its device's pings; a client whose stream cannot be
        decoded, or that closed, is dropped (counted)."""
        sel = selectors.DefaultSelector()
        try:
            while not self._stop.is_set():
                with self._lock:
                    joining, self._joining = self._joining, []
                for conn in joining:
                    dec = vrpn.StreamDecoder(expect_cookie=False)
                    dec.on_other = lambda sender, kind, m, c=conn: self._other(c, sender, kind)
                    sel.register(conn, selectors.EVENT_READ, dec)
                if not sel.get_map():
                    self._stop.wait(0.05)
                    continue
                for key, _ in sel.select(0.05):
                    conn = key.fileobj
                    try:
                        data = conn.recv(65536)
                        if not data:
                            raise ConnectionResetError
                        key.data.feed(data)
                    except BlockingIOError:
                        continue
                    except (OSError, PacketError) as exc:
                        sel.unregister(conn)
                        self._drop(conn, getattr(exc, "reason", None))
                for key in list(sel.get_map().values()):  # dropped by report(): closed
                    if key.fileobj.fileno() == -1:
                        sel.unregister(key.fileobj)
        finally:
            sel.close()

    def _other(self, conn: socket.socket, sender: str | None, kind: str | None) -> None:
        if kind != vrpn.PING:
            return
        if sender != self.device:
            self._reject("ping for another device")
            return
        sec, rest = divmod(time.time_ns(), 1_000_000_000)
        pong = vrpn.encode_message(sec & 0xFFFFFFFF, rest // 1000, 0, _PONG_ID, b"")
        with self._lock:
            if conn not in self._clients:
                return
            try:
                conn.sendall(pong)
            except OSError:  # the reader finds the closed connection next
                return
        self.pongs += 1

    def _drop(self, conn: socket.socket, reason: str | None) -> None:
        """Forget a client: one that closed (``reason`` None) or sent garbage (counted)."""
        with self._lock:
            if conn in self._clients:
                self._clients.remove(conn)
                if reason is not None:
                    self._reject(reason)
        conn.close()

    @property
    def clients(self) -> int:
        with self._lock:
            return len(self._clients)

    def report(self, sensor: int, position, quaternion, t_ns: int) -> None:
        """Send one pose (``position`` [m], ``quaternion`` ``(x, y, z, w)``) of ``sensor``
        valid at ``t_ns`` (host clock) to every connected client; a client that cannot keep
        up or went away is dropped (counted)."""
        sec, rest = divmod(int(t_ns), 1_000_000_000)
        msg = vrpn.encode_message(
            sec & 0xFFFFFFFF, rest // 1000, 0, 0, vrpn.encode_pos_quat(sensor, position, quaternion)
        )
        with self._lock:
            for c in list(self._clients):
                try:
                    c.sendall(msg)
                except (BlockingIOError, OSError):
                    self._reject("client dropped")
                    self._clients.remove(c)
                    c.close()
        self.sent += 1

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(2.0)
        self._tcp.close()
        self._udp.close()
        with self._lock:
            for c in self._clients:
                c.close()
            self._clients.clear()

    def __enter__(self) -> VrpnTrackerServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
