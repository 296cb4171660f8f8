"""The NatNet input against a faulty server, over real loopback sockets: a model definition
with one malformed description (asked for again until the name is known) and a server that
never answers the handshake (reported, with what to check).

The server here is a few lines of this test on a real UDP socket: it answers what the
input sends the way Motive does (SERVERINFO to CONNECT, MODELDEF to its request, frames to
the command socket's address), and misbehaves as each test needs.
"""

from __future__ import annotations

import socket
import struct
import threading
import time

import numpy as np

from trackflow.dataflow import parse_input
from trackflow.trackers import natnet
from trackflow.trackers.inputs import make_input

COV = np.diag([1e-6] * 3 + [1e-5] * 3)
FREQ = 10_000_000
V = (4, 1)


def _description(name: bytes, bid: int, size: int | None = None) -> bytes:
    body = name + b"\0" + struct.pack("<ii3fi", bid, -1, 0, 0, 0, 0)
    n = len(body) if size is None else size
    return struct.pack("<iI", 1, n) + body.ljust(n, b"\0")[:n]


class _Motive:
    """CONNECT -> SERVERINFO; the first ``bad`` MODELDEF requests get a definition whose
    ``head`` description has a wrong size, later ones a good one; after CONNECT a frame of
    bodies 3 (head) and 5 (hand) every 10 ms to the client."""

    def __init__(self, bad: int, port: int = 0):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.01)
        self.port = self.sock.getsockname()[1]
        self.bad, self.requests = bad, 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._serve, daemon=True)

    def _modeldef(self) -> bytes:
        self.requests += 1
        head = _description(b"head", 3, 3 if self.requests <= self.bad else None)
        payload = struct.pack("<i", 2) + head + _description(b"hand", 5)
        return natnet.encode_message(natnet.MODELDEF, payload)

    def _serve(self) -> None:
        client, k = None, 0
        info = natnet.ServerInfo(clock_frequency=FREQ)
        while not self.stop.is_set():
            try:
                data, addr = self.sock.recvfrom(65536)
                msg, _ = natnet.decode_message(data)
                if msg == natnet.CONNECT:
                    client = addr
                    self.sock.sendto(natnet.encode_server_info(info), addr)
                elif msg == natnet.REQUEST_MODELDEF:
                    self.sock.sendto(self._modeldef(), addr)
            except TimeoutError:
                pass
            if client is not None:
                k += 1
                tick = time.time_ns() // 100  # 10 MHz ticks of the host clock
                rbs = tuple(
                    natnet.NatNetRigidBody(i, (0.1 * i, 0.0, 1.0), (0, 0, 0, 1), 1e-4, True)
                    for i in (3, 5)
                )
                frame = natnet.NatNetFrame(k, rbs, k / 100, tick, tick, tick)
                self.sock.sendto(natnet.encode_frame(frame, V), client)

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join(5)
        self.sock.close()


def _input(port: int, body="head"):
    spec = parse_input({"natnet": {"server": "127.0.0.1", "command_port": port, "body": body}})
    return make_input("s", spec, COV)


def _wait(cond, seconds: float = 20.0) -> bool:
    deadline = time.monotonic() + seconds
    while not cond() and time.monotonic() < deadline:
        time.sleep(0.02)
    return cond()


def test_a_bad_description_is_skipped_and_the_definitions_asked_for_again():
    """Two definitions with a malformed ``head``: the input keeps asking (0.5 s, then 1 s)
    and measures ``head`` once the third, good one arrives; ``hand``, well described in
    every definition, has its id from the first."""
    with _Motive(bad=2) as motive:
        inp = _input(motive.port)
        got = []
        inp.start(lambda i, data, a: got.extend(i.handle(data, a)))
        try:
            assert inp.ready.wait(10)
            assert _wait(lambda: inp.status.measurements >= 5)
        finally:
            inp.stop()
    st = inp.status
    assert motive.requests >= 3 and inp.models.id_of("head") == 3
    assert inp.models.id_of("hand") == 5
    assert st.rejections["model description skipped"] == 2
    assert st.rejections["unknown body name"] >= 1  # frames before the good definition
    assert "hint" not in st.notes
    assert got and all(np.allclose(s.position, [0.3, 0.0, 1.0], atol=1e-7) for _, s in got)


def test_a_name_missing_from_the_definitions_is_named_in_the_status():
    with _Motive(bad=0) as motive:
        inp = _input(motive.port, body="foot")
        inp.start(lambda i, data, a: i.handle(data, a))
        try:
            assert _wait(lambda: motive.requests >= 2)
        finally:
            inp.stop()
    hint = inp.status.notes["hint"]
    assert hint == "body 'foot' not in the model definitions (bodies: head, hand)"


def test_a_server_that_never_answers_is_reported():
    quiet = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    quiet.bind(("127.0.0.1", 0))  # receives CONNECT, answers nothing
    try:
        inp = _input(quiet.getsockname()[1])
        inp.start(lambda i, data, a: i.handle(data, a))
        try:
            assert _wait(lambda: "handshake not answered" in inp.status.connection)
        finally:
            inp.stop()
    finally:
        quiet.close()
    assert inp.status.connection["handshake not answered"] == 1
    assert "to CONNECT for 2 s: is Motive streaming" in inp.status.notes["hint"]
    assert inp.status.measurements == 0


def test_a_restarted_server_is_connected_to_again():
    """Motive restarted: the new server streams only to clients that CONNECT. The input hears
    nothing for 2 s, says so and connects again; the measurements go on."""
    first = _Motive(bad=0)
    port = first.port
    inp = _input(port)
    inp.start(lambda i, data, a: i.handle(data, a))
    try:
        with first:
            assert _wait(lambda: inp.status.measurements >= 5)
        before = inp.status.measurements
        with _Motive(bad=0, port=port):
            assert _wait(lambda: inp.status.measurements >= before + 20, 30)
    finally:
        inp.stop()
    assert inp.status.connection["server silent: handshake again"] >= 1
