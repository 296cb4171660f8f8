"""Per-sensor status of a live input: rates, latency, clock, dropouts, rejections, staleness."""

from __future__ import annotations

import threading
from collections import deque

from ..errors import InputError
from ..timesync import ClockEstimate

__all__ = ["RESTART_FRAMES", "SensorStatus", "StatusGroup"]

#: A frame counter jumping back (or ahead) by more than this many frames is a restart.
RESTART_FRAMES = 10_000
#: ... and is taken as a restart when a frame within this many after the jump follows it.
CONFIRM_FRAMES = 10

_UNKNOWN = object()  # StatusGroup.common_frame when the bodies' frame numbers may differ


class SensorStatus:
    """Counters of one live input (updated by its receiving thread, read by anyone).

    A status may belong to a :class:`StatusGroup` (the bodies of one connection), which
    counts what a packet does to every body of the group at once; every attribute below reads
    the same figures as if each body had been counted on its own.

    Attributes
    ----------
    packets : int
        Datagrams / stream messages received.
    measurements : int
        Poses handed to the dataflow.
    dropouts : int
        Frames missing from the tracker's frame counter (gaps).
    rejections : dict
        Counted rejections of packets or poses by reason (garbage, truncated, not tracked,
        reordered ...).
    connection : dict
        Connection events by kind (connection failed, lost, closed; socket errors).
    latency_ns : deque
        Recent host arrival time minus mapped exposure time [ns] (the last 512).
    arrivals_ns : deque
        Host arrival times of the recent measurements [ns] (the last 1024).
    clock : ClockEstimate or None
        The tracker-to-host mapping.
    last_frame, last_arrival_ns : int or None
        The tracker's last frame number; the host arrival time of the last measurement [ns].
    connected : bool
    notes : dict
        What the input has learnt that a user should read, by topic (``"seen"``: the ids the
        tracker sends; ``"hint"``: why this sensor's body may be missing). Replaced whole.
    """

    def __init__(self, name: str, protocol: str):
        self.name = name
        self.protocol = protocol
        self.dropouts = 0
        self.rejections: dict[str, int] = {}
        self.connection: dict[str, int] = {}
        self.clock: ClockEstimate | None = None
        self.connected = False
        self.notes: dict[str, str] = {}
        self._packets = 0
        self._measurements = 0
        self._latency_ns: deque = deque(maxlen=512)
        self._arrivals_ns: deque = deque(maxlen=1024)
        self._last_frame: int | None = None
        self._jump: int | None = None  # a counter jump waiting for its confirmation
        self._last_arrival_ns: int | None = None
        self._group: StatusGroup | None = None
        self._lock = threading.Lock()

    def __repr__(self) -> str:
        return (
            f"SensorStatus({self.name!r}, {self.protocol!r}, packets={self.packets}, "
            f"measurements={self.measurements}, dropouts={self.dropouts}, "
            f"rejections={self.rejections})"
        )

    def _sync(self) -> None:
        """Apply what the group counted for every body (before this status is read or
        changed on its own)."""
        g = self._group
        if g is not None and g.pending:
            g.flush()

    def _own(self) -> None:
        """This status changes on its own: the group's figures first; the group no longer
        knows a frame number common to every body."""
        g = self._group
        if g is not None:
            if g.pending:
                g.flush()
            g.common_frame = _UNKNOWN

    @property
    def packets(self) -> int:
        self._sync()
        return self._packets

    @packets.setter
    def packets(self, value: int) -> None:
        self._sync()
        self._packets = value

    @property
    def measurements(self) -> int:
        self._sync()
        return self._measurements

    @measurements.setter
    def measurements(self, value: int) -> None:
        self._sync()
        self._measurements = value

    @property
    def latency_ns(self) -> deque:
        self._sync()
        return self._latency_ns

    @property
    def arrivals_ns(self) -> deque:
        self._sync()
        return self._arrivals_ns

    @property
    def last_frame(self) -> int | None:
        self._sync()
        return self._last_frame

    @last_frame.setter
    def last_frame(self, value: int | None) -> None:
        self._own()
        self._last_frame = value

    @property
    def last_arrival_ns(self) -> int | None:
        self._sync()
        return self._last_arrival_ns

    @last_arrival_ns.setter
    def last_arrival_ns(self, value: int | None) -> None:
        self._sync()
        self._last_arrival_ns = value

    def reject(self, reason: str) -> None:
        with self._lock:
            self.rejections[reason] = self.rejections.get(reason, 0) + 1

    def event(self, kind: str) -> None:
        """Count a connection event (not a rejected packet)."""
        with self._lock:
            self.connection[kind] = self.connection.get(kind, 0) + 1

    @property
    def rejected(self) -> int:
        return sum(self.rejections.values())

    def frame(self, number: int) -> bool:
        """Account for a frame counter; False (a counted rejection) if it repeats one of the
        last :data:`CONFIRM_FRAMES`, or if it goes back further or jumps ahead by more than
        :data:`RESTART_FRAMES` and is not yet confirmed. A
        jump is a restarted tracker (an event, not a loss) once the next frame follows it
        (within :data:`CONFIRM_FRAMES`); one bogus counter between real frames is rejected
        and changes nothing."""
        self._own()
        last = self._last_frame
        if last is not None:
            # a counter a little behind the last is a reordered or duplicated frame; one
            # further back (a tracker restarted after fewer than RESTART_FRAMES frames counts
            # from 1 again) is a jump like any other: a restart once the next frame follows
            # it. A late copy never gets here: the inputs refuse a send stamp not after the
            # newest before they look at the counter (LiveInput._new_stamp).
            if last - CONFIRM_FRAMES < number <= last:
                self.reject("reordered or duplicate frame")
                return False
            if number <= last or number - last > RESTART_FRAMES:
                jump = self._jump
                if jump is None or not jump < number <= jump + CONFIRM_FRAMES:
                    self._jump = number
                    self.reject("frame counter jump not confirmed")
                    return False
                self.event("frame counter restarted")
            else:
                self.dropouts += number - last - 1
        self._jump = None
        self._last_frame = number
        return True

    def measured(self, arrival_ns: int, exposure_ns: int) -> None:
        self._sync()
        self._measurements += 1
        self._latency_ns.append(arrival_ns - exposure_ns)
        self._arrivals_ns.append(arrival_ns)
        self._last_arrival_ns = arrival_ns

    def rate_hz(self, now_ns: int, span_s: float = 2.0) -> float:
        """Measurements per second over the last ``span_s`` seconds."""
        lo = now_ns - int(span_s * 1e9)
        arrivals = list(self.arrivals_ns)  # one copy: the receiving thread may append meanwhile
        n = sum(1 for a in arrivals if a >= lo)
        return n / span_s

    def stale(self, now_ns: int, after_s: float) -> bool:
        """No measurement for ``after_s`` seconds (or never)."""
        return self.last_arrival_ns is None or now_ns - self.last_arrival_ns > after_s * 1e9

    def summary(self, now_ns: int, stale_s: float = 0.5) -> dict:
        lat = sorted(self.latency_ns)
        c = self.clock
        return {
            "protocol": self.protocol,
            "packets": self.packets,
            "measurements": self.measurements,
            "rate_hz": self.rate_hz(now_ns),
            "latency_ms_p50": lat[len(lat) // 2] * 1e-6 if lat else None,
            "clock_offset_ms": None if c is None else c.offset_ns * 1e-6,
            "clock_drift_ppm": None if c is None else c.drift * 1e6,
            "clock_sigma_ms": None if c is None else c.sigma_ns * 1e-6,
            # the minimum transit delay found by round trips (NatNet echo), subtracted
            "clock_transit_us": c.transit_ns * 1e-3 if c and c.transit_sigma_ns else None,
            "dropouts": self.dropouts,
            "rejections": dict(sorted(self.rejections.items())),
            "connection": dict(sorted(self.connection.items())),
            "stale": self.stale(now_ns, stale_s),
            "notes": dict(self.notes),
        }

    def line(self, now_ns: int, stale_s: float = 0.5) -> str:
        """One status line: rate, latency, clock offset, dropouts, rejections, stale."""
        s = self.summary(now_ns, stale_s)
        lat = "-" if s["latency_ms_p50"] is None else f"{s['latency_ms_p50']:.2f} ms"
        off = "-" if s["clock_offset_ms"] is None else f"{s['clock_offset_ms']:+.3f} ms"
        sig = "" if s["clock_sigma_ms"] is None else f" +-{s['clock_sigma_ms'] * 1e3:.0f} us"
        if s["clock_transit_us"] is not None:
            sig += f" (transit {s['clock_transit_us']:.0f} us)"
        rej = ", ".join(f"{k} {v}" for k, v in s["rejections"].items()) or "0"
        flag = " STALE" if s["stale"] else ""
        if s["notes"]:
            flag += f" [{'; '.join(s['notes'].values())}]"
        conn = ", ".join(f"{k} {v}" for k, v in s["connection"].items())
        conn = f", {conn}" if conn else ""
        return (
            f"{self.name} ({self.protocol}): {s['rate_hz']:.1f} Hz, latency {lat}, clock {off}"
            f"{sig}, dropouts {self.dropouts}, rejected {rej}{conn}{flag}"
        )


class StatusGroup:
    """The statuses of the bodies of one connection, counted once per packet for all of them.

    A packet counts for every body (:meth:`packet`), a frame number that follows every
    body's last one (:meth:`next_frame`) and a packet that measured every body at once
    (:meth:`measured`) are kept here, in order, and applied to each status when it is read or
    changed on its own (or after :attr:`FLUSH_AT` packets), so every reader sees the figures
    that counting each body on its own gives, for a few operations per packet instead of a
    few per body.
    """

    #: packets measured by every body kept before they are applied
    FLUSH_AT = 256

    def __init__(self):
        self.members: list[SensorStatus] = []
        self.pending = False
        #: the last frame number of every member, or _UNKNOWN (they may differ)
        self.common_frame = _UNKNOWN
        self._packets = 0
        self._arrivals: list[int] = []
        self._latencies: list[int] = []
        self._frame: int | None = None
        self._set_frame = False
        self._lock = threading.Lock()

    def add(self, status: SensorStatus) -> None:
        """Count ``status`` with the group from now on (it belongs to one group at most)."""
        if status._group is not None:
            raise InputError(f"status of {status.name!r} is already in a group")
        self.flush()
        status._group = self
        self.members.append(status)
        self.common_frame = _UNKNOWN

    def packet(self) -> None:
        """A packet for every member (:attr:`SensorStatus.packets`)."""
        with self._lock:
            self._packets += 1
            self.pending = True

    def next_frame(self, number: int) -> bool:
        """If ``number`` follows every member's last frame number: make it their last one and
        return True (no gap, no restart, nothing to count); else False, nothing changed."""
        common = self.common_frame
        if common is _UNKNOWN:
            self.flush()
            last = {s._last_frame for s in self.members}
            common = self.common_frame = last.pop() if len(last) == 1 else _UNKNOWN
        if common is _UNKNOWN or common != number - 1:
            return False
        with self._lock:
            self._frame, self._set_frame = number, True
            self.common_frame = number
            self.pending = True
        return True

    def measured(self, arrival_ns: int, exposure_ns: int) -> None:
        """:meth:`SensorStatus.measured` for every member."""
        with self._lock:
            self._arrivals.append(arrival_ns)
            self._latencies.append(arrival_ns - exposure_ns)
            self.pending = True
            if len(self._arrivals) >= self.FLUSH_AT:
                self._apply()

    def flush(self) -> None:
        """Apply what is kept to every member."""
        with self._lock:
            self._apply()

    def _apply(self) -> None:
        if not self.pending:
            return
        arrivals, latencies = self._arrivals, self._latencies
        for s in self.members:
            s._packets += self._packets
            if arrivals:
                s._measurements += len(arrivals)
                s._latency_ns.extend(latencies)
                s._arrivals_ns.extend(arrivals)
                s._last_arrival_ns = arrivals[-1]
            if self._set_frame:
                s._last_frame = self._frame
        self._packets = 0
        self._arrivals, self._latencies = [], []
        self._set_frame = False
        self.pending = False
