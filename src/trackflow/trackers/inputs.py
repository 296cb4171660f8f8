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
import struct
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np

from ..dataflow import NETWORK_PROTOCOLS, InputSpec
from ..math import check_covariance, frozen, kernels_for
from ..timesync import ClockMapper
from . import dtrack, natnet, vrpn
from . import kernels as _kernels
from ._packet import PacketError
from .axes import BoundaryConversion
from .status import SensorStatus, StatusGroup
from .waiting import DueWait

__all__ = [
    "Body",
    "DTrackInput",
    "LiveInput",
    "NatNetInput",
    "Sample",
    "SampleBlock",
    "VrpnInput",
    "make_input",
    "make_inputs",
    "warm_up_inputs",
]

#: The host clock of live runs: ``time.time_ns`` (Unix time, integer ns).
host_ns = time.time_ns

#: Linux's SO_TIMESTAMPNS (= SCM_TIMESTAMPNS); the socket module does not always name it.
_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
_TIMESPEC = struct.Struct("qq")


def enable_kernel_stamps(sock: socket.socket) -> bool:
    """Ask the kernel to stamp every received datagram (Linux ``SO_TIMESTAMPNS``, the same
    clock as ``time.time_ns``); False where unavailable."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
    except OSError:
        return False
    return True


def recv_stamped(sock: socket.socket, kernel: bool) -> tuple[bytes, int]:
    """One datagram and its arrival time [host ns]: the kernel's receive stamp when
    ``kernel`` (so thread wake-up and interpreter delays do not count), else the time the
    call returned."""
    if not kernel:
        data = sock.recv(65536)
        return data, host_ns()
    data, ancillary, _, _ = sock.recvmsg(65536, socket.CMSG_SPACE(_TIMESPEC.size))
    now = host_ns()
    for level, kind, raw in ancillary:
        if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(raw) >= 16:
            sec, nsec = _TIMESPEC.unpack_from(raw)
            t = sec * 1_000_000_000 + nsec
            if 0 <= now - t < 10_000_000_000:  # a sane stamp on the same clock
                return data, t
    return data, now


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


class CheckedSample(Sample):
    """A :class:`Sample` as :meth:`LiveInput._sample` makes it from the body's nominal
    covariance: float64 arrays of the right shapes, a finite position, a quaternion of unit
    norm to rounding and a covariance checked once when the body was made, so
    :class:`~trackflow.trackers.runtime.LiveSource` takes it without checking again."""

    __slots__ = ()


class SampleBlock(Sequence):
    """The samples of one packet as arrays, when every one is a :class:`CheckedSample` of
    the packet's exposure and arrival times (the NatNet input makes them so from a frame's
    rigid-body table).

    As a sequence it is what :meth:`LiveInput.handle` returns otherwise, ``(body index,
    sample)`` pairs, each made on access; the live runtime takes the arrays instead
    (:meth:`~trackflow.trackers.runtime.LiveSources.deliver_block`), so a packet's bodies
    cost no Python object each on their way to the filters.

    Attributes
    ----------
    index : tuple of int (m,)
        Body indices (into :attr:`LiveInput.bodies`), increasing.
    t_ns, arrival_ns : int
        Exposure on the host clock and host receive time [ns], shared by the samples.
    position : ndarray (m, 3)
        Positions [m], read-only.
    quaternion : ndarray (m, 4)
        Unit quaternions ``(x, y, z, w)``, read-only.
    covariance : ndarray (m, 6, 6)
        The bodies' nominal covariances (:attr:`Body.nominal_converted`), read-only.
    covariances : tuple of ndarray (6, 6)
        The same, as the bodies' own arrays (the samples of the sequence view share them).
    """

    __slots__ = ("index", "t_ns", "arrival_ns", "position", "quaternion", "covariance",
                 "covariances")  # fmt: skip

    def __init__(self, index, t_ns, arrival_ns, position, quaternion, covariance, covariances):
        self.index = index
        self.t_ns, self.arrival_ns = t_ns, arrival_ns
        self.position, self.quaternion = position, quaternion
        self.covariance, self.covariances = covariance, covariances

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return SampleBlock(
                self.index[k], self.t_ns, self.arrival_ns, self.position[k],
                self.quaternion[k], self.covariance[k], self.covariances[k],
            )  # fmt: skip
        s = CheckedSample(
            self.t_ns, self.arrival_ns, self.position[k], self.quaternion[k],
            self.covariances[k],
        )  # fmt: skip
        return self.index[k], s


Sink = Callable[["LiveInput", bytes, int], None]


class Body:
    """One sensor fed by a connection: its body selector, conversion, nominal covariance
    (setup; used when the protocol sends none, scaled by NatNet's mean marker error) and
    status."""

    def __init__(self, name: str, spec: InputSpec, covariance):
        self.name = name
        self.spec = spec
        self.options = spec.options
        self.nominal = np.asarray(covariance, dtype=float).reshape(6, 6)
        self.conv = BoundaryConversion(spec.unit_scale, spec.up)
        self.status = SensorStatus(name, spec.protocol)
        c = self.conv.covariance(self.nominal)
        #: the nominal covariance in trackflow's frames, exactly symmetric; read-only, since
        #: every sample without a covariance of its own shares it
        self.nominal_converted = 0.5 * (c + c.T)
        self.nominal_converted.flags.writeable = False
        try:  # a valid nominal covariance makes samples without their own CheckedSamples
            self.nominal_valid = check_covariance(self.nominal_converted) is self.nominal_converted
        except ValueError:
            self.nominal_valid = False
        #: nominal position sigma [m] (NatNet's mean marker error is compared with it)
        self.nominal_sigma = math.sqrt(float(np.trace(self.nominal[:3, :3])) / 3.0)


class LiveInput:
    """One connection to a tracker (a socket or two and a thread) feeding one or more
    sensors (bodies); a packet is decoded once for all of them.

    Parameters
    ----------
    spec : InputSpec
        The first sensor's spec; its connection options define the connection.
    """

    protocol = ""
    #: attributes the input learns from its server (a handshake), mirrored by a rehearsal
    handshake: tuple[str, ...] = ()

    def __init__(self, spec: InputSpec):
        self.spec = spec
        self.options = spec.options
        self.bodies: list[Body] = []
        #: the bodies' statuses, counted once per packet where a packet counts for every body
        self.statuses = StatusGroup()
        self.clock = ClockMapper()
        self.packets = 0
        self._stop = threading.Event()
        self.ready = threading.Event()  # set once the sockets are open (or failed)
        self.kernel_stamps = False  # arrival times from the kernel (UDP on Linux)
        self._threads: list[threading.Thread] = []
        self._socks: list[socket.socket] = []
        #: ``rehearsal(data, arrival_ns, waiting)``
        #: (:class:`trackflow.trackers.rehearsal.Rehearsal`), run on the last frame before
        #: each frame (option ``rehearse_us``); set before start
        self.rehearsal: Callable[[bytes, int, Callable[[], bool]], object] | None = None
        self._last_frame: tuple[bytes, int] | None = None

    @staticmethod
    def connection_key(spec: InputSpec) -> tuple:
        """Sensors whose specs give the same key share one connection."""
        o = spec.options
        keys = {
            "natnet": ("server", "command_port", "data_port", "multicast", "group", "interface"),
            "dtrack": ("interface", "port", "group", "command", "command_port"),
        }.get(spec.protocol)
        if spec.protocol not in NETWORK_PROTOCOLS:  # a feed: one per set of options
            return (spec.protocol, *sorted((k, v) for k, v in o.items() if k != "body"))
        if keys is None:
            return (spec.protocol, spec.vrpn_address[1:], o["timeout_ms"])
        return (spec.protocol, *(o[k] for k in keys))

    def add_body(self, name: str, spec: InputSpec, covariance) -> Body:
        if self.connection_key(spec) != self.connection_key(self.spec):
            raise ValueError(f"sensor {name!r}: another connection than {self.spec.options}")
        b = Body(name, spec, covariance)
        self.bodies.append(b)
        self.statuses.add(b.status)
        return b

    @property
    def status(self) -> SensorStatus:
        """The first sensor's status (single-body inputs)."""
        return self.bodies[0].status

    # -- pure part --------------------------------------------------------------------------------
    def handle(self, data: bytes, arrival_ns: int) -> Sequence[tuple[int, Sample]]:
        """Decode one packet into ``(body index, sample)`` pairs (a :class:`SampleBlock`
        when the input has them as arrays); rejections are counted in the bodies' statuses
        (a packet-level error on every body), never raised."""
        self.packets += 1
        self.statuses.packet()
        try:
            return self._handle(data, arrival_ns)
        except PacketError as exc:
            for b in self.bodies:
                b.status.reject(exc.reason)
            return []

    def _handle(self, data: bytes, arrival_ns: int) -> list[tuple[int, Sample]]:
        raise NotImplementedError  # pragma: no cover

    def _per_body(self, fn) -> list[tuple[int, Sample]]:
        """Call ``fn(body) -> Sample | None`` for every body; its PacketError is counted on
        that body only."""
        out = []
        for i, b in enumerate(self.bodies):
            try:
                s = fn(b)
            except PacketError as exc:
                b.status.reject(exc.reason)
                continue
            if s is not None:
                out.append((i, s))
        return out

    def _map(self, tx_ns: int, latency_ns: int, arrival_ns: int) -> int:
        """Exposure time on the host clock: the send time ``tx_ns`` (tracker clock) mapped
        by the envelope fit, minus the protocol's exposure-to-send latency."""
        clock = self.clock
        clock.add(tx_ns, arrival_ns)
        est = clock.estimate  # never None after add
        if est is not self.bodies[0].status.clock:  # a new estimate: every body's status
            for b in self.bodies:
                b.status.clock = est
        return est.to_host(tx_ns) - latency_ns

    @staticmethod
    def _sample(b: Body, t_ns: int, arrival_ns: int, position, quaternion, cov=None) -> Sample:
        """A checked sample; ``cov`` is a 6x6 covariance over ``(dt [m], dtheta)`` in the
        wire's frames, or ``None`` for the body's nominal one (already converted)."""
        x, y, z = position
        qx, qy, qz, qw = quaternion
        n2 = qx * qx + qy * qy + qz * qz + qw * qw
        if not (math.isfinite(x + y + z) and math.isfinite(n2)):
            raise PacketError("non-finite pose", b.name)
        if not 0.81 < n2 < 1.21:
            raise PacketError("non-unit quaternion", f"|q|^2 = {n2:.4g}")
        n = math.sqrt(n2)
        if b.conv.up == "z":
            k = b.conv.scale
            p = np.array((x * k, y * k, z * k))
            q = np.array((qx / n, qy / n, qz / n, qw / n))
        else:
            p, q = b.conv.pose((x, y, z), (qx / n, qy / n, qz / n, qw / n))
        px, py, pz = p.tolist()
        if not math.isfinite(px + py + pz):  # the unit scale made it overflow
            raise PacketError("non-finite pose", b.name)
        if cov is None:
            c = b.nominal_converted
            kind = CheckedSample if b.nominal_valid else Sample
        else:
            kind = Sample
            c = b.conv.covariance(cov)
            c = 0.5 * (c + c.T)
            if not np.isfinite(c).all():
                raise PacketError("invalid covariance", b.name)
        b.status.measured(arrival_ns, t_ns)
        return kind(int(t_ns), int(arrival_ns), p, q, c)

    def _frame(self, number: int) -> bool:
        ok = True
        if self.bodies and self.statuses.next_frame(number):
            return True  # the next frame of every body: no gap, no restart
        for b in self.bodies:
            before = b.status.connection.get("frame counter restarted", 0)
            ok = b.status.frame(number) and ok
            restarted = b.status.connection.get("frame counter restarted", 0) > before
        if self.bodies and restarted:
            self.clock.reset()  # a restarted tracker may have restarted its clock too
        return ok

    # -- transport -------------------------------------------------------------------------------
    def start(self, sink: Sink) -> None:
        """Open the sockets and start the receiving thread; every packet goes to
        ``sink(input, data, arrival_ns)`` (which normally calls :meth:`handle`)."""
        self._stop.clear()
        self.ready.clear()
        name = f"input-{self.protocol}-{self.bodies[0].name if self.bodies else ''}"
        t = threading.Thread(target=self._run, args=(sink,), name=name, daemon=True)
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

    def _run(self, sink: Sink) -> None:
        raise NotImplementedError  # pragma: no cover

    def _due_wait(self) -> DueWait:
        """The receiving thread's wait for a periodic stream (options ``spin_us`` and
        ``rehearse_us``), rehearsing the last frame before the next is due when the input
        has a :attr:`rehearsal`."""
        o = self.options
        wait = self.waiting = DueWait(o["spin_us"] * 1e-6, rehearse_s=o["rehearse_us"] * 1e-6)
        if self.rehearsal is not None and wait.rehearse_s:
            wait.rehearse = self._rehearse
        return wait

    def _frame_arrived(self, wait: DueWait, data: bytes, arrival_ns: int) -> None:
        """A frame of the stream was received (and handled): its time for the wait, and
        the frame for the next rehearsal."""
        wait.arrived(arrival_ns * 1e-9)
        self._last_frame = (data, arrival_ns)

    def _rehearse(self, waiting: Callable[[], bool]) -> None:
        """The rehearsal of the last frame, cut short when ``waiting()`` says a datagram
        came; one that fails is turned off and reported on every body (it never touches the
        live path, which goes on)."""
        if self._last_frame is None:
            return
        try:
            self.rehearsal(*self._last_frame, waiting)
        except Exception as exc:  # a bug in the twins must not stop the live input
            self.waiting.rehearse = None
            self._event_all(f"rehearsal off: {type(exc).__name__}: {exc}")

    def _reject_all(self, reason: str) -> None:
        for b in self.bodies:
            b.status.reject(reason)

    def _event_all(self, kind: str) -> None:
        for b in self.bodies:
            b.status.event(kind)

    def _connected(self, value: bool) -> None:
        for b in self.bodies:
            b.status.connected = value

    def _udp(self, bind: tuple[str, int], group: str | None = None) -> socket.socket:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        if group:  # bound to the group address: only that group's datagrams arrive
            s.bind((group, bind[1]))
            mreq = socket.inet_aton(group) + socket.inet_aton(bind[0])
            s.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
        else:
            s.bind(bind)
        s.settimeout(0.2)
        self.kernel_stamps = enable_kernel_stamps(s)
        self._socks.append(s)
        return s


# -- DTrack ---------------------------------------------------------------------------------------
class DTrackInput(LiveInput):
    """DTrack bodies from the UDP output (``ts2`` latency preferred, else ``ts`` with the
    configured ``latency_ms``); the optional TCP command channel sends
    ``dtrack2 tracking start``.

    A sensor's ``kind`` picks the line its ``body`` id is looked up in: ``body`` (``6d``,
    with its ``6dcov`` covariance when sent), ``flystick`` (``6df2``), ``tool`` (``6dmt2``:
    the tip's position covariance replaces the nominal position block) or ``hand`` (``gl``,
    the back of the hand). The newest ``st`` line is kept in :attr:`tracker_status`.
    """

    protocol = "dtrack"

    def __init__(self, spec):
        super().__init__(spec)
        self.days = dtrack.DayUnwrapper()
        self.tracker_status: dtrack.DTrackStatus | None = None

    def _handle(self, data, arrival_ns):
        f = dtrack.decode_dtrack(data)
        if f.frame is not None and not self._frame(f.frame):
            return []
        if f.ts2 is not None:
            stamp = f.ts2[0] * 1_000_000_000 + f.ts2[1] * 1000
            lat = f.ts2[2] * 1000
        elif f.ts is not None:
            stamp = int(round(self.days(f.ts) * 1e9))
            lat = int(round(self.options["latency_ms"] * 1e6))
        else:
            raise PacketError("no timestamp", "the DTrack output has neither ts nor ts2")
        t = self._map(stamp + lat, lat, arrival_ns)
        if f.status is not None:
            self.tracker_status = f.status
        lines = {"body": f.bodies, "flystick": f.flysticks, "tool": f.tools, "hand": f.hands}
        by_id = {k: {x.id: x for x in v} for k, v in lines.items() if v}
        covs = {x.id: x for x in f.covariances}

        def one(b: Body):
            kind = b.options["kind"]
            body = by_id.get(kind, {}).get(b.options["body"])
            if body is None:
                raise PacketError(f"{kind} not in frame", f"{kind} {b.options['body']}")
            _, q = dtrack.dtrack_pose(body)
            cov = None
            if kind == "body" and body.id in covs:
                R = np.asarray(body.rotation).reshape(3, 3)
                cov = dtrack.dtrack_covariance(R, covs[body.id])
            elif kind == "tool":
                cov = np.array(b.nominal)
                cov[:3, :] = cov[:, :3] = 0.0
                pc = np.asarray(body.position_cov_mm2).reshape(3, 3)
                cov[:3, :3] = pc * b.conv.scale**2
            return self._sample(b, t, arrival_ns, body.position_mm, q, cov)

        return self._per_body(one)

    def _run(self, sink):
        o = self.options
        try:
            s = self._udp((o["interface"], o["port"]), o["group"])
            if o["command"]:
                self.command(o["command"], o["command_port"], "dtrack2 tracking start")
        except OSError as exc:
            self._event_all(f"socket error: {exc.strerror or exc}")
            self.ready.set()
            return
        self._connected(True)
        self.ready.set()
        s.setblocking(False)  # the selector waits (DueWait: or polls around a frame's time)
        sel = selectors.DefaultSelector()
        sel.register(s, selectors.EVENT_READ)
        wait = self._due_wait()
        try:
            while not self._stop.is_set():
                for _ in wait.select(sel, 0.2):
                    try:
                        data, arrival = recv_stamped(s, self.kernel_stamps)
                    except BlockingIOError:
                        continue
                    except OSError:
                        return
                    sink(self, data, arrival)
                    self._frame_arrived(wait, data, arrival)  # one datagram per frame
        finally:
            sel.close()

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
            self._event_all("command refused")
        return answer


class NatNetInput(LiveInput):
    """NatNet rigid bodies: CONNECT/SERVERINFO handshake, MODELDEF for names, unicast
    KEEPALIVE (or multicast), exposure from the mid-exposure and transmit ticks.

    From NatNet 3.0 on, ECHOREQUEST round trips (a few at the start, then one a second)
    measure the transit delay, which the clock mapping then subtracts
    (:meth:`ClockMapper.add_round_trip`); a server that does not know them (UNRECOGNIZED)
    is not asked again."""

    protocol = "natnet"
    #: round trips at the start, then the period between them [s]
    ECHO_FIRST, ECHO_PERIOD_S = 8, 1.0

    handshake = ("server", "models")

    def __init__(self, spec):
        super().__init__(spec)
        self.server: natnet.ServerInfo | None = None
        self.models: natnet.ModelDefinitions | None = None
        self.echo = True  # the server answers echo requests (until it says otherwise)
        self.echoes_sent = 0
        #: (frame ids, model definitions, _body_rows, _block_plan of them, the ids as an array)
        self._plan = None
        self._pass_server: natnet.ServerInfo | None = None  # the server _pass_version is of
        self._pass_version = 0  # 256 major + minor when frames take the one pass, else 0
        self._pass_out = np.zeros(5, np.uint64)  # the pass's frame number, ticks, table

    def body_id(self, b: Body) -> int:
        sel = b.options["body"]
        if isinstance(sel, int):
            return sel
        bid = None if self.models is None else self.models.id_of(sel)
        if bid is None:
            raise PacketError("unknown body name", str(sel))
        return bid

    def _handle(self, data, arrival_ns):
        if self._pass_server is not self.server:
            s = self.server
            self._pass_server = s
            ok = s is not None and s.clock_frequency  # the stamps need the clock frequency
            self._pass_version = 256 * s.version[0] + s.version[1] if ok else 0
        if self._pass_version >= 3 * 256:
            out = self._frame_pass(data, arrival_ns)
            if out is not None:
                return out
        msg, payload = natnet.decode_message(data)
        if msg == natnet.SERVERINFO:
            self.server = natnet.decode_server_info(payload)
            return []
        if msg == natnet.MODELDEF:
            if self.server is None:
                raise PacketError("no handshake yet", "MODELDEF before SERVERINFO")
            self.models = natnet.decode_model_definitions(payload, self.server.version)
            return []
        if msg == natnet.ECHORESPONSE:
            self._round_trip(payload, arrival_ns)
            return []
        if msg == natnet.UNRECOGNIZED:
            self.echo = False  # the only request this client sends that a server may not know
            return []
        if msg != natnet.FRAMEOFDATA:
            if msg in (natnet.MESSAGESTRING, natnet.RESPONSE, natnet.KEEPALIVE):
                return []
            raise PacketError("unexpected message", f"id {msg}")
        if self.server is None:
            raise PacketError("no handshake yet", "frame before SERVERINFO")
        f = natnet.decode_frame(payload, self.server.version, table=True)
        if not self._frame(f.frame):
            return []
        freq = self.server.clock_frequency
        if natnet.exposure_and_latency(f, freq) is not None:
            tx_ns = self._ticks_ns(f.transmit)
            lat_ns = (f.transmit - f.mid_exposure) * 1_000_000_000 // freq
        else:  # before NatNet 3.0: the frame timestamp, latency unknown
            tx_ns, lat_ns = int(round(f.timestamp * 1e9)), 0
        t = self._map(tx_ns, lat_ns, arrival_ns)
        if f.body_table is not None:
            return self._table_samples(f.body_table, t, arrival_ns)
        by_id = {rb.id: rb for rb in f.rigid_bodies}

        def one(b: Body):
            rb = by_id.get(self.body_id(b))
            if rb is None:
                raise PacketError("body not in frame", str(b.options["body"]))
            return self._body_sample(b, rb, t, arrival_ns)

        return self._per_body(one)

    def _frame_pass(self, data, arrival_ns):
        """A FRAMEOFDATA datagram in one compiled pass (:func:`kernels.natnet_frame`): the
        frame's layout checked as :func:`natnet.decode_frame` checks it, its frame number,
        clock ticks and rigid-body table found, and, when the table's ids are the plan's and
        every body is plainly valid, the :class:`SampleBlock` made, with no frame object and
        no Python per body. ``None`` when the pass cannot tell (an error, another message, a
        layout it does not take): :meth:`_handle` then decodes the datagram as before. The
        rest (frame counter, stamps, clock mapping, the per-body path when there is no block)
        is :meth:`_handle`'s, in the same order, so results and rejections are the same."""
        plan = self._plan
        if plan is not None and plan[1] is self.models and plan[3] is not None:
            bp = plan[3]
            ids, rows, bounds, want = plan[4], bp[1], bp[8], 1
        else:
            bp, ids, rows, bounds, want = None, _NO_ROWS, _NO_ROWS, _NO_BOUNDS, 0
        m = len(rows)
        pos, quat, out = np.empty((m, 3)), np.empty((m, 4)), self._pass_out
        code = kernels_for(_kernels).natnet_frame(
            np.frombuffer(data, np.uint8), self._pass_version, ids, rows, bounds, want, pos,
            quat, out,
        )  # fmt: skip
        if code == _kernels.FRAME_SLOW:
            return None
        number, mid, tx, table, n = out.tolist()
        if not self._frame(number - (number >> 31 << 32)):  # the frame number's i32 bits
            return []
        freq = self.server.clock_frequency
        lat_ns = natnet.latency_ticks(mid, tx, freq) * 1_000_000_000 // freq
        t = self._map(self._ticks_ns(tx), lat_ns, arrival_ns)
        if code == _kernels.FRAME_BLOCK:
            return self._block_samples(bp, self._make_block(bp, pos, quat, t, arrival_ns))
        tab = np.frombuffer(data, natnet.RIGID_BODY_DTYPE, n, table)
        return self._table_samples(tab, t, arrival_ns)

    def _body_sample(self, b: Body, rb: natnet.NatNetRigidBody, t: int, arrival_ns: int):
        """The sample of body ``b`` from its rigid body ``rb`` (covariance scaled by the mean
        marker error when that is above the nominal sigma)."""
        if rb.valid is False:
            raise PacketError("not tracked", str(b.options["body"]))
        cov = None
        ref = b.nominal_sigma
        if rb.mean_error is not None and ref > 0:
            err = rb.mean_error * b.conv.scale
            if not (math.isfinite(err) and err >= 0):
                raise PacketError("bad mean error", f"{rb.mean_error}")
            if err > ref:  # scaled by (error / nominal)^2: still exactly symmetric
                cov = b.nominal * (err / ref) ** 2
        return self._sample(b, t, arrival_ns, rb.position, rb.quaternion, cov)

    def _body_rows(self, ids: list[int]) -> list | None:
        """Per body, for frames with these rigid-body ids: ``(index, row, unit scale,
        nominal sigma, sample class, nominal covariance)``, when every body is in the frame
        and sent in trackflow's frame (Z-up); else ``None``."""
        row_of = {bid: k for k, bid in enumerate(ids)}
        out = []
        for i, b in enumerate(self.bodies):
            try:
                row = row_of.get(self.body_id(b))
            except PacketError:
                return None
            if row is None or b.conv.up != "z":
                return None
            kind = CheckedSample if b.nominal_valid else Sample
            out.append((i, row, b.conv.scale, b.nominal_sigma, kind, b.nominal_converted))
        return out

    @classmethod
    def warm_up(cls) -> None:
        """Run the one pass over a frame (:meth:`_frame_pass`) and over a frame's bodies
        (:meth:`_block`) once, so that compiling their kernels (numba, first use in a
        process) happens before a tracker is listened to."""
        tab = np.zeros(1, natnet.RIGID_BODY_DTYPE)
        tab["quaternion"][0, 3], tab["params"][0] = 1.0, 1
        nominal = np.eye(6) * 1e-6
        plan = cls._block_plan([(0, 0, 1.0, 1e-3, CheckedSample, nominal)])
        if cls._block(plan, tab, 0, 0) is None:
            raise RuntimeError("the NatNet block kernel refused a plainly valid body")
        body = natnet.NatNetRigidBody(7, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), 0.0, True)
        data = natnet.encode_frame(natnet.NatNetFrame(1, (body,), 0.0, 1, 1, 2), (4, 1))
        kernel = kernels_for(_kernels).natnet_frame
        pos, quat, out = np.empty((1, 3)), np.empty((1, 4)), np.zeros(5, np.uint64)
        for ids, rows, bounds, want in ((frozen([7], np.int64), plan[1], plan[8], 1),
                                        (_NO_ROWS, _NO_ROWS, _NO_BOUNDS, 0)):  # fmt: skip
            code = kernel(np.frombuffer(data, np.uint8), 4 * 256 + 1, ids, rows, bounds, want,
                          pos, quat, out)  # fmt: skip
            if code != (_kernels.FRAME_BLOCK if want else _kernels.FRAME_DECODED):
                raise RuntimeError("the NatNet frame kernel refused a plain frame")

    @staticmethod
    def _block_plan(rows: list | None) -> tuple | None:
        """For rows of :meth:`_body_rows`: the constants of their :class:`SampleBlock` (body
        indices, table rows, unit scales, bounds of the scaled mean marker error, the
        covariances stacked (m, 6, 6) and as a tuple, the sample classes or ``None`` when
        all are checked, and the scales and bounds as one (3, m) array)."""
        if rows is None:
            return None
        kinds = tuple(r[4] for r in rows)
        covs = tuple(r[5] for r in rows)
        ref = np.array([r[3] for r in rows])
        scales = frozen([r[2] for r in rows])
        lo = frozen(np.where(ref > 0, 0.0, -np.inf))  # no bound without a nominal sigma
        hi = frozen(np.where(ref > 0, ref, np.inf))
        return (
            tuple(r[0] for r in rows),
            frozen([r[1] for r in rows], np.int64),
            scales,
            lo,
            hi,
            frozen(np.stack(covs)),
            covs,
            None if all(k is CheckedSample for k in kinds) else kinds,
            frozen(np.stack([scales, lo, hi])),
        )

    @staticmethod
    def _make_block(plan: tuple, pos, quat, t: int, arrival_ns: int) -> SampleBlock:
        """The :class:`SampleBlock` of a :meth:`_block_plan` with these positions and
        quaternions (made read-only)."""
        pos.setflags(write=False)
        quat.setflags(write=False)
        return SampleBlock(plan[0], t, arrival_ns, pos, quat, plan[5], plan[6])

    def _block_samples(self, plan: tuple, block: SampleBlock):
        """Count a block's samples in the bodies' statuses (every body is in it); the block,
        or its samples as pairs when some body's class is not :class:`CheckedSample`."""
        self.statuses.measured(block.arrival_ns, block.t_ns)
        kinds = plan[7]
        if kinds is None:
            return block
        return [(i, kind(*s)) for (i, s), kind in zip(block, kinds)]

    @staticmethod
    def _block(plan: tuple, tab: np.ndarray, t: int, arrival_ns: int) -> SampleBlock | None:
        """The :class:`SampleBlock` of a frame's table for a :meth:`_block_plan` when every
        body in it is plainly valid (:func:`kernels.block_poses`: the arithmetic of
        :meth:`LiveInput._sample`, so the same bits), with no side effect; ``None`` as soon
        as one is not."""
        index, rows, scales, lo, hi = plan[:5]
        # position, quaternion and mean error of every row: 8 float32 after the id
        v = np.ndarray((len(tab), 8), "<f4", tab, 4, (tab.itemsize, 4))
        pos = np.empty((len(index), 3))
        quat = np.empty((len(index), 4))
        ok = kernels_for(_kernels).block_poses(
            frozen(v), frozen(tab["params"], np.int64), rows, scales, lo, hi, pos, quat
        )
        if not ok:
            return None
        return NatNetInput._make_block(plan, pos, quat, t, arrival_ns)

    def _table_samples(self, tab: np.ndarray, t: int, arrival_ns: int):
        """:meth:`_body_sample` for every body from a frame's rigid-body table
        (:data:`natnet.RIGID_BODY_DTYPE`), the arithmetic of :meth:`LiveInput._sample` done
        for all rows at once (the same operations, so the same bits): a :class:`SampleBlock`
        when every body is plainly valid and makes checked samples. A body whose covariance
        is scaled or whose frame is converted (Y-up) takes the per-body path."""
        t, arrival_ns = int(t), int(arrival_ns)
        ids = tab["id"].tolist()
        plan = self._plan
        if plan is None or plan[0] != ids or plan[1] is not self.models:
            rows = self._body_rows(ids)
            plan = (ids, self.models, rows, self._block_plan(rows), frozen(ids, np.int64))
            self._plan = plan
        if plan[3] is not None:
            block = self._block(plan[3], tab, t, arrival_ns)
            if block is not None:
                return self._block_samples(plan[3], block)
        row_of = {bid: k for k, bid in enumerate(ids)}  # the last of a repeated id, as a dict
        pos = tab["position"].astype(np.float64)
        quat = tab["quaternion"].astype(np.float64)
        err = tab["mean_error"].tolist()
        params = tab["params"].tolist()
        with np.errstate(all="ignore"):  # non-finite rows are rejected below, per body
            q0, q1, q2, q3 = quat.T
            n2 = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3
            finite = np.isfinite(pos[:, 0] + pos[:, 1] + pos[:, 2]) & np.isfinite(n2)
            unit = (0.81 < n2) & (n2 < 1.21)
            qn = quat / np.sqrt(np.where(unit, n2, 1.0))[:, None]
        finite, unit = finite.tolist(), unit.tolist()
        scaled: dict[float, tuple[np.ndarray, list]] = {}  # unit scale -> positions, finite
        out = []
        for i, b in enumerate(self.bodies):
            try:
                row = row_of.get(self.body_id(b))
                if row is None:
                    raise PacketError("body not in frame", str(b.options["body"]))
                conv = b.conv
                e = err[row]
                ref = b.nominal_sigma
                if conv.up != "z" or (ref > 0 and not 0.0 <= e * conv.scale <= ref):
                    rb = natnet.NatNetRigidBody(
                        ids[row], tuple(tab["position"][row].tolist()),
                        tuple(tab["quaternion"][row].tolist()), e, params[row] & 1 == 1,
                    )  # fmt: skip
                    out.append((i, self._body_sample(b, rb, t, arrival_ns)))
                    continue
                if not params[row] & 1:
                    raise PacketError("not tracked", str(b.options["body"]))
                if not finite[row]:
                    raise PacketError("non-finite pose", b.name)
                if not unit[row]:
                    raise PacketError("non-unit quaternion", f"|q|^2 = {float(n2[row]):.4g}")
                k = conv.scale
                if k not in scaled:
                    with np.errstate(all="ignore"):
                        p = pos * k
                        ok = np.isfinite(p[:, 0] + p[:, 1] + p[:, 2]).tolist()
                    scaled[k] = (p, ok)
                p, ok = scaled[k]
                if not ok[row]:  # the unit scale made it overflow
                    raise PacketError("non-finite pose", b.name)
            except PacketError as exc:
                b.status.reject(exc.reason)
                continue
            b.status.measured(arrival_ns, t)
            kind = CheckedSample if b.nominal_valid else Sample
            out.append((i, kind(t, arrival_ns, p[row], qn[row], b.nominal_converted)))
        return out

    def _ticks_ns(self, ticks: int) -> int:
        """Server clock ticks -> tracker time [ns] (exact integers)."""
        freq, g = self.server.clock_frequency, 1_000_000_000
        return ticks // freq * g + (ticks % freq) * g // freq

    def _round_trip(self, payload, arrival_ns: int) -> None:
        if self.server is None or self.server.clock_frequency is None:
            raise PacketError("no handshake yet", "ECHORESPONSE before a 3.0+ SERVERINFO")
        token, ticks = natnet.decode_echo_response(payload)
        if not self.clock.add_round_trip(token, self._ticks_ns(ticks), arrival_ns):
            raise PacketError("bad round trip", f"{(arrival_ns - token) * 1e-6:.3f} ms")

    def _echo_due(self, now: float, last: float) -> bool:
        if not (self.echo and self.server is not None and self.server.clock_frequency):
            return False
        period = 0.05 if self.echoes_sent < self.ECHO_FIRST else self.ECHO_PERIOD_S
        return now - last >= period

    def _run(self, sink):
        o = self.options
        server = (o["server"], o["command_port"])
        try:
            cmd = self._udp((o["interface"], 0))
            mc = o["multicast"]
            data = self._udp(
                (o["interface"], o["data_port"] if mc else 0), o["group"] if mc else None
            )
        except OSError as exc:
            self._event_all(f"socket error: {exc.strerror or exc}")
            self.ready.set()
            return
        self.ready.set()
        # the selector waits; the sockets never do (a blocking socket with a timeout polls
        # once more before every receive)
        cmd.setblocking(False)
        data.setblocking(False)
        sel = selectors.DefaultSelector()
        sel.register(cmd, selectors.EVENT_READ)
        sel.register(data, selectors.EVENT_READ)
        next_cmd = next_keepalive = last_echo = 0.0
        connected = None
        need_names = any(isinstance(b.options["body"], str) for b in self.bodies)
        wait = self._due_wait()
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                try:
                    if now >= next_cmd and self.server is None:
                        cmd.sendto(natnet.encode_connect(), server)
                        next_cmd = now + 0.5
                    elif now >= next_cmd and need_names and self.models is None:
                        cmd.sendto(natnet.encode_message(natnet.REQUEST_MODELDEF), server)
                        next_cmd = now + 0.5
                    if not mc and self.server is not None and now >= next_keepalive:
                        # after the handshake, from the command socket as the SDK does: a
                        # unicast server streams to where it comes from
                        cmd.sendto(natnet.encode_message(natnet.KEEPALIVE), server)
                        next_keepalive = now + 1.0
                    if self._echo_due(now, last_echo):
                        cmd.sendto(natnet.encode_echo_request(host_ns()), server)
                        self.echoes_sent += 1
                        last_echo = now
                except OSError:
                    self._event_all("send failed")
                for key, _ in wait.select(sel, 0.1):
                    try:
                        raw, arrival = recv_stamped(key.fileobj, self.kernel_stamps)
                    except OSError:  # nothing to read, ICMP port unreachable while no server
                        continue
                    had_server = self.server is not None
                    sink(self, raw, arrival)
                    if raw[:2] == _FRAME_ID:  # the stream's period is the frames'
                        self._frame_arrived(wait, raw, arrival)
                    if connected is not (self.server is not None):
                        connected = self.server is not None
                        self._connected(connected)
                    if not had_server and connected:
                        next_cmd = 0.0  # ask for the model definitions at once
        finally:
            sel.close()


_FRAME_ID = natnet.FRAMEOFDATA.to_bytes(2, "little")  # a NatNet frame's first bytes


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


#: no plan for the one pass (:meth:`NatNetInput._frame_pass`): no ids, rows or bounds
_NO_ROWS = frozen(np.empty(0, np.int64), np.int64)
_NO_BOUNDS = frozen(np.empty((3, 0)))

_INPUTS = {"dtrack": DTrackInput, "natnet": NatNetInput, "vrpn": VrpnInput}


def warm_up_inputs() -> None:
    """Compile (or load) the inputs' kernels, the clock fit and NatNet's one pass over a
    frame's bodies, before any tracker is listened to."""
    ClockMapper.warm_up()
    NatNetInput.warm_up()


def _input_class(protocol: str) -> type[LiveInput]:
    """The input of a network tracker, else a :class:`~trackflow.trackers.feed.FeedInput`
    (in-process feeds such as ``optical``, see :func:`trackflow.dataflow.register_feed`)."""
    if protocol in _INPUTS:
        return _INPUTS[protocol]
    from .feed import FeedInput  # imports this module

    return FeedInput


def make_input(name: str, spec: InputSpec, covariance) -> LiveInput:
    """A live input (one connection) feeding the one sensor ``name``."""
    inp = _input_class(spec.protocol)(spec)
    inp.add_body(name, spec, covariance)
    return inp


def make_inputs(sensors: dict[str, tuple[InputSpec, np.ndarray]]) -> list[LiveInput]:
    """Live inputs for ``{sensor: (spec, nominal covariance)}``: sensors on the same
    connection (same server, ports) share one input, so each packet is decoded once."""
    by_key: dict[tuple, LiveInput] = {}
    for name, (spec, cov) in sensors.items():
        key = LiveInput.connection_key(spec)
        if key not in by_key:
            by_key[key] = _input_class(spec.protocol)(spec)
        by_key[key].add_body(name, spec, cov)
    return list(by_key.values())
