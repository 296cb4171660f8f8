"""The live input of an A.R.T. DTrack tracker (UDP output, optional TCP command channel)."""

from __future__ import annotations

import selectors
import socket

import numpy as np

from . import dtrack
from ._packet import PacketError
from .live_input import Body, LiveInput, recv_stamped

__all__ = ["DTrackInput"]

_NONE: frozenset = frozenset()  # no id of a kind seen yet


class DTrackInput(LiveInput):
    """DTrack bodies from the UDP output (``ts2`` latency preferred, else ``ts`` with the
    configured ``latency_ms``); the optional TCP command channel sends
    ``dtrack2 tracking start``.

    A sensor's ``kind`` picks the line its ``body`` id is looked up in: ``body`` (``6d``,
    with its ``6dcov`` covariance when sent), ``flystick`` (``6df2``), ``tool`` (``6dmt2``:
    the tip's position covariance replaces the nominal position block) or ``hand`` (``gl``,
    the back of the hand). The newest ``st`` line is kept in :attr:`tracker_status`.

    ``body`` is the id on the wire, which counts from 0; the DTrack GUI counts from 1. The
    ids the tracker sends are in each sensor's status notes (``"6d ids seen: 0, 1"``), with a
    hint on a sensor whose id has not been seen.
    """

    protocol = "dtrack"

    def __init__(self, spec):
        super().__init__(spec)
        self.days = dtrack.DayUnwrapper()
        self.tracker_status: dtrack.DTrackStatus | None = None
        #: the ids seen so far, by kind (``body``, ``flystick``, ``tool``, ``hand``)
        self.seen: dict[str, set[int]] | None = None

    def _handle(self, data, arrival_ns):
        f = dtrack.decode_dtrack(data)
        if f.ts2 is None and f.ts is None:  # refused before it touches frame counter or clock
            raise PacketError("no timestamp", "the DTrack output has neither ts nor ts2")
        if f.ts2 is not None:
            stamp = f.ts2[0] * 1_000_000_000 + f.ts2[1] * 1000
            lat = f.ts2[2] * 1000
        else:
            stamp = int(round(self.days.peek(f.ts) * 1e9))
            lat = int(round(self.options["latency_ms"] * 1e6))
        self._new_stamp(stamp + lat)
        if f.frame is not None and not self._frame(f.frame):
            return []
        t = self._map(stamp + lat, lat, arrival_ns)
        if f.ts2 is None:
            self.days(f.ts)  # the day follows the stamps the clock took, no others
        if f.status is not None:
            self.tracker_status = f.status
        lines = {"body": f.bodies, "flystick": f.flysticks, "tool": f.tools, "hand": f.hands}
        by_id = {k: {x.id: x for x in v} for k, v in lines.items() if v}
        seen = self.seen
        if seen is None or any(not ids.keys() <= seen.get(k, _NONE) for k, ids in by_id.items()):
            self._saw(by_id)
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

    _LINE = {"body": "6d", "flystick": "6df2", "tool": "6dmt2", "hand": "gl"}

    def _saw(self, by_id: dict) -> None:
        """New ids in the output: every sensor's notes say which ids are sent, and hint at
        the 0-based ids where the sensor's own is not among them."""
        seen = self.seen = self.seen or {}
        for kind, ids in by_id.items():
            seen.setdefault(kind, set()).update(ids)
        for b in self.bodies:
            kind, want = b.options["kind"], b.options["body"]
            ids = sorted(seen.get(kind, ()))
            line = self._LINE[kind]
            notes = {"seen": f"{line} ids seen: {', '.join(map(str, ids)) or 'none'}"}
            if want not in ids:
                notes["hint"] = (
                    f"{kind} {want} not in the output; DTrack ids count from 0 on the wire "
                    f"(the DTrack GUI counts from 1)"
                )
            b.status.notes = notes

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
                    wait.arrived(arrival * 1e-9)  # one datagram per frame
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
