"""Per-sensor status of a live input: rates, latency, clock, dropouts, rejections, staleness."""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass, field

from .clock import ClockEstimate

__all__ = ["RESTART_FRAMES", "SensorStatus"]

#: A frame counter jumping back (or ahead) by more than this many frames is a restart.
RESTART_FRAMES = 10_000


@dataclass
class SensorStatus:
    """Counters of one live input (updated by its receiving thread, read by anyone).

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
        Recent host arrival time minus mapped exposure time [ns].
    clock : ClockEstimate or None
        The tracker-to-host mapping.
    """

    name: str
    protocol: str
    packets: int = 0
    measurements: int = 0
    dropouts: int = 0
    rejections: dict[str, int] = field(default_factory=dict)
    connection: dict[str, int] = field(default_factory=dict)
    latency_ns: deque = field(default_factory=lambda: deque(maxlen=512))
    arrivals_ns: deque = field(default_factory=lambda: deque(maxlen=1024))
    clock: ClockEstimate | None = None
    last_frame: int | None = None
    last_arrival_ns: int | None = None
    connected: bool = False
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

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
        """Account for a frame counter; False (counted "reordered") if it is not new. A jump
        of more than :data:`RESTART_FRAMES` either way is a restarted tracker (an event)."""
        last = self.last_frame
        if last is not None:
            if last - RESTART_FRAMES < number <= last:
                self.reject("reordered or duplicate frame")
                return False
            if number <= last or number - last > RESTART_FRAMES:
                self.event("frame counter restarted")  # a restarted tracker, not a loss
            else:
                self.dropouts += number - last - 1
        self.last_frame = number
        return True

    def measured(self, arrival_ns: int, exposure_ns: int) -> None:
        self.measurements += 1
        self.latency_ns.append(arrival_ns - exposure_ns)
        self.arrivals_ns.append(arrival_ns)
        self.last_arrival_ns = arrival_ns

    def rate_hz(self, now_ns: int, span_s: float = 2.0) -> float:
        """Measurements per second over the last ``span_s`` seconds."""
        lo = now_ns - int(span_s * 1e9)
        n = sum(1 for a in self.arrivals_ns if a >= lo)
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
        conn = ", ".join(f"{k} {v}" for k, v in s["connection"].items())
        conn = f", {conn}" if conn else ""
        return (
            f"{self.name} ({self.protocol}): {s['rate_hz']:.1f} Hz, latency {lat}, clock {off}"
            f"{sig}, dropouts {self.dropouts}, rejected {rej}{conn}{flag}"
        )
