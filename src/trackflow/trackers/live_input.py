"""A live input's common part: one connection to a tracker feeding the samples of its bodies.

Each input has a pure part, :meth:`LiveInput.handle` (bytes + host arrival time -> samples;
keeps the protocol state: handshake, model names, frame counter, clock mapping) that tests
drive without sockets, and a transport (:meth:`LiveInput.start`) on stdlib sockets with
timeouts that feeds it from a thread. Exposure times come from the protocol wherever it has
them (NatNet mid-exposure/transmit ticks, DTrack ``ts2`` latency, the VRPN source stamp);
a packet is never stamped on arrival when the protocol has better. The protocols' inputs
are :mod:`.dtrack_input`, :mod:`.natnet_input`, :mod:`.vrpn_input` and :mod:`.feed`;
:mod:`.inputs` makes them from a setup's specs.
"""

from __future__ import annotations

import math
import socket
import struct
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np

from ..dataflow import NETWORK_PROTOCOLS, InputSpec
from ..errors import InputError
from ..math import check_covariance
from ..timesync import ClockMapper
from ._packet import PacketError
from .axes import BoundaryConversion
from .status import SensorStatus, StatusGroup
from .waiting import DueWait
from .wire_checks import near_unit

__all__ = [
    "Body",
    "CheckedSample",
    "LiveInput",
    "Sample",
    "SampleBlock",
    "Sink",
    "enable_kernel_stamps",
    "host_ns",
    "recv_stamped",
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

    def __init__(self, spec: InputSpec):
        self.spec = spec
        self.options = spec.options
        self.bodies: list[Body] = []
        #: the bodies' statuses, counted once per packet where a packet counts for every body
        self.statuses = StatusGroup()
        self.clock = ClockMapper()
        self._last_tx: int | None = None  # the newest send stamp mapped [ns, tracker clock]
        self.packets = 0
        self._stop = threading.Event()
        self.ready = threading.Event()  # set once the sockets are open (or failed)
        self.kernel_stamps = False  # arrival times from the kernel (UDP on Linux)
        self._threads: list[threading.Thread] = []
        self._socks: list[socket.socket] = []
        #: added to every exposure time this input makes [ns]: an online delay correction
        #: (:mod:`trackflow.trackers.online_offsets`), changed on the receiving thread only
        self.shift_ns = 0
        self._shift_request: tuple | None = None

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
        if spec.protocol == "ros2":  # one per topic (its sensors differ by their frames)
            keys = ("connect", "zenoh_config", "insecure", "domain", "node", "topic", "type")
            return (spec.protocol, *(o[k] for k in keys))
        if keys is None:
            return (spec.protocol, spec.vrpn_address[1:], o["timeout_ms"])
        return (spec.protocol, *(o[k] for k in keys))

    def add_body(self, name: str, spec: InputSpec, covariance) -> Body:
        if self.connection_key(spec) != self.connection_key(self.spec):
            raise InputError(f"sensor {name!r}: another connection than {self.spec.options}")
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
        if self._shift_request is not None:
            self._take_shift(arrival_ns)
        try:
            out = self._handle(data, arrival_ns)
        except PacketError as exc:
            for b in self.bodies:
                b.status.reject(exc.reason)
            return []
        shift = self.shift_ns
        if shift and out:
            if type(out) is SampleBlock:
                out.t_ns += shift
            else:
                out = [(i, s._replace(t_ns=s.t_ns + shift)) for i, s in out]
        return out

    def request_shift(self, shift_ns: int, on_applied: Callable[[int], None] | None = None):
        """From any thread: from the next packet on, add ``shift_ns`` [ns] (in all, not in
        addition to the present shift) to every exposure time this input makes.
        ``on_applied(arrival_ns)`` is called on the receiving thread before that packet is
        decoded, so what it does (a log line, forgetting the samples made before) falls
        between two packets. A second request before the next packet replaces the first."""
        self._shift_request = (int(shift_ns), on_applied)

    def _take_shift(self, arrival_ns: int) -> None:
        request, self._shift_request = self._shift_request, None
        if request is not None:
            self.shift_ns = request[0]
            if request[1] is not None:
                request[1](arrival_ns)

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
        by the envelope fit, minus the protocol's exposure-to-send latency. A stamp that
        steps off the fit is refused (PacketError) until the next ones confirm the step; one
        that jumps below it is mapped by the fit but kept out of it until confirmed
        (:class:`~trackflow.timesync.ClockMapper`), so one corrupted stamp moves nothing."""
        clock = self.clock
        if not clock.add(tx_ns, arrival_ns):
            raise PacketError("clock jump not confirmed", f"stamp {tx_ns} ns")
        if self._last_tx is None or tx_ns > self._last_tx:
            self._last_tx = tx_ns
        est = clock.estimate  # never None after an accepted add
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
        if not near_unit(n2):
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

    def _new_stamp(self, tx_ns: int) -> None:
        """Refuse a send stamp (tracker clock) not after the newest one mapped, unless it lies
        further back than a clock step (a restart, left to the counter and clock checks): a
        duplicated or reordered datagram, or a copy whose frame number was changed on the
        way, never reaches the frame counter."""
        last = self._last_tx
        if last is not None and last - self.clock.step_ns < tx_ns <= last:
            raise PacketError("stamp not after the last", f"{(last - tx_ns) * 1e-6:.3f} ms back")

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
            self._last_tx = None
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
        """The receiving thread's wait for a periodic stream (option ``spin_us``)."""
        wait = self.waiting = DueWait(self.options["spin_us"] * 1e-6)
        return wait

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
