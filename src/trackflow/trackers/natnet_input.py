"""The live input of an OptiTrack Motive (NatNet) server: handshake, frames, round trips."""

from __future__ import annotations

import math
import selectors
import time

import numpy as np

from ..math import frozen, kernels_for
from . import kernels as _kernels
from . import natnet
from ._packet import PacketError
from .live_input import Body, CheckedSample, LiveInput, Sample, SampleBlock, host_ns, recv_stamped
from .wire_checks import near_unit

__all__ = ["NatNetInput"]


class NatNetInput(LiveInput):
    """NatNet rigid bodies: CONNECT/SERVERINFO handshake, MODELDEF for names, unicast
    KEEPALIVE (or multicast), exposure from the mid-exposure and transmit ticks.

    From NatNet 3.0 on, ECHOREQUEST round trips (a few at the start, then one a second)
    measure the transit delay, which the clock mapping then subtracts
    (:meth:`ClockMapper.add_round_trip`); a server that does not know them (UNRECOGNIZED)
    is not asked again.

    While a sensor's body name is not in the model definitions (none yet, a description
    skipped as malformed, a body added in Motive later), MODELDEF is asked for again, with
    the wait doubling from 0.5 s to 8 s. A server that does not answer the handshake within
    :attr:`HANDSHAKE_WAIT_S` is reported (event and status note), as is a name the
    definitions do not hold. A unicast server silent for :attr:`REHANDSHAKE_S` after the
    handshake is connected to again (a restarted Motive has forgotten its clients)."""

    protocol = "natnet"
    #: round trips at the start, then the period between them [s]
    ECHO_FIRST, ECHO_PERIOD_S = 8, 1.0
    #: the first and the longest wait between MODELDEF requests while a name is unknown [s]
    MODELDEF_FIRST_S, MODELDEF_MAX_S = 0.5, 8.0
    #: a server silent this long after the first CONNECT is reported [s]
    HANDSHAKE_WAIT_S = 2.0
    #: a unicast server silent this long after the handshake is asked again (CONNECT): a
    #: restarted Motive streams only to clients that connect to it [s]
    REHANDSHAKE_S = 2.0

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
        self._missing: tuple = (False, None)  # (a name unknown, the definitions it is of)

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
            if self.models.skipped:
                self._reject_all("model description skipped")
            self._note_names()
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
        freq = self.server.clock_frequency
        if natnet.exposure_and_latency(f, freq) is not None:
            tx_ns = self._ticks_ns(f.transmit)
            lat_ns = (f.transmit - f.mid_exposure) * 1_000_000_000 // freq
        else:  # before NatNet 3.0: the frame timestamp, latency unknown
            tx_ns, lat_ns = int(round(f.timestamp * 1e9)), 0
        self._new_stamp(tx_ns)
        if not self._frame(f.frame):
            return []
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
        freq = self.server.clock_frequency
        lat_ns = natnet.latency_ticks(mid, tx, freq) * 1_000_000_000 // freq
        tx_ns = self._ticks_ns(tx)
        self._new_stamp(tx_ns)
        if not self._frame(number - (number >> 31 << 32)):  # the frame number's i32 bits
            return []
        t = self._map(tx_ns, lat_ns, arrival_ns)
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
            unit = near_unit(n2)
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

    def names_missing(self) -> bool:
        """Some sensor selects its body by a name the model definitions do not (yet) hold."""
        missing, of = self._missing
        if of is not self.models or of is None:  # new definitions (or none yet): look again
            m = self.models
            missing = any(
                isinstance(b.options["body"], str)
                and (m is None or m.id_of(b.options["body"]) is None)
                for b in self.bodies
            )
            self._missing = (missing, m)
        return missing

    def _note_names(self) -> None:
        """After new model definitions: a note on every sensor whose name is not in them."""
        m = self.models
        names = ", ".join(d.name for d in m.rigid_bodies) or "none"
        for b in self.bodies:
            sel = b.options["body"]
            notes = {k: v for k, v in b.status.notes.items() if k != "hint"}
            if isinstance(sel, str) and m.id_of(sel) is None:
                notes["hint"] = f"body {sel!r} not in the model definitions (bodies: {names})"
            if notes != b.status.notes:
                b.status.notes = notes

    def _no_handshake(self) -> None:
        """The server has not answered CONNECT: say so, with what to check."""
        o = self.options
        self._event_all("handshake not answered")
        for b in self.bodies:
            b.status.notes = {
                **b.status.notes,
                "hint": f"no answer from {o['server']}:{o['command_port']} to CONNECT for "
                f"{self.HANDSHAKE_WAIT_S:g} s: is Motive streaming, is the command port right?",
            }

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
        modeldef_wait = self.MODELDEF_FIRST_S
        silent_since = time.monotonic()  # the first CONNECT; None once answered or reported
        heard = time.monotonic()  # the last datagram from the server
        wait = self._due_wait()
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                if not mc and self.server is not None and now - heard > self.REHANDSHAKE_S:
                    # a silent unicast server may have restarted and forgotten this client
                    self.server = None
                    self._event_all("server silent: handshake again")
                    heard, next_cmd = now, 0.0
                try:
                    if now >= next_cmd and self.server is None:
                        cmd.sendto(natnet.encode_connect(), server)
                        next_cmd = now + 0.5
                        if silent_since is not None and now - silent_since >= self.HANDSHAKE_WAIT_S:
                            self._no_handshake()
                            silent_since = None
                    elif now >= next_cmd and self.names_missing():
                        cmd.sendto(natnet.encode_message(natnet.REQUEST_MODELDEF), server)
                        next_cmd = now + modeldef_wait
                        modeldef_wait = min(2 * modeldef_wait, self.MODELDEF_MAX_S)
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
                    heard = time.monotonic()
                    had_server = self.server is not None
                    sink(self, raw, arrival)
                    if raw[:2] == _FRAME_ID:  # the stream's period is the frames'
                        wait.arrived(arrival * 1e-9)
                    if connected is not (self.server is not None):
                        connected = self.server is not None
                        self._connected(connected)
                    if not had_server and connected:
                        next_cmd = 0.0  # ask for the model definitions at once
                        silent_since = None
                        for b in self.bodies:  # the handshake hint no longer holds
                            b.status.notes = {
                                k: v for k, v in b.status.notes.items() if k != "hint"
                            }
        finally:
            sel.close()


_FRAME_ID = natnet.FRAMEOFDATA.to_bytes(2, "little")  # a NatNet frame's first bytes


#: no plan for the one pass (:meth:`NatNetInput._frame_pass`): no ids, rows or bounds
_NO_ROWS = frozen(np.empty(0, np.int64), np.int64)
_NO_BOUNDS = frozen(np.empty((3, 0)))
