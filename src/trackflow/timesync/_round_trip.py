"""Clock offset from round trips (Cristian's method).

The host reads its clock when it sends a request (``t0``) and when the answer arrives
(``t1``); the answer carries the remote clock's reading ``r``, taken at an unknown host time in
``[t0, t1]``. With the convention of :mod:`trackflow.timesync` (``offset = host - remote``)::

    offset = (t0 + t1) / 2 - r
    |error| <= (t1 - t0) / 2          (uniform: sigma = rtt / (2 sqrt 3))

Of a window of round trips, the one with the shortest round trip time bounds the offset best
and is the estimate (:class:`RoundTripOffset`).
"""

from __future__ import annotations

import math
import threading
from collections import deque

from ..errors import InputError

__all__ = ["RoundTripOffset", "round_trip_offset"]


def round_trip_offset(send_host_ns: int, remote_ns: int, recv_host_ns: int) -> tuple[int, float]:
    """``(offset_ns, sigma_ns)`` of one round trip (module docstring).

    Parameters
    ----------
    send_host_ns, recv_host_ns : int
        Host clock when the request left and when the answer arrived [ns].
    remote_ns : int
        The remote clock's reading in the answer [ns].

    Returns
    -------
    offset_ns : int
        ``host - remote`` [ns] (the midpoint of the round trip minus the remote reading,
        rounded down).
    sigma_ns : float
        Its standard deviation [ns] when the reading falls uniformly inside the round trip.

    Raises
    ------
    ValueError
        The answer arrived before the request left.
    """
    rtt = int(recv_host_ns) - int(send_host_ns)
    if rtt < 0:
        raise InputError(f"round trip ends before it starts ({rtt} ns)")
    offset = (int(send_host_ns) + int(recv_host_ns)) // 2 - int(remote_ns)
    return offset, rtt / (2.0 * math.sqrt(3.0))


class RoundTripOffset:
    """Offset of one remote clock from the host clock, from a window of round trips.

    Parameters
    ----------
    window : int
        Round trips kept; the one with the shortest round trip time gives the estimate.

    Safe to update from one thread while others read the estimate.
    """

    def __init__(self, window: int = 32):
        self._trips: deque[tuple[int, int]] = deque(maxlen=int(window))  # (rtt, offset)
        self._lock = threading.Lock()
        self._best_trip: tuple[int, int] | None = None  # read without the lock (atomic)

    def add_round_trip(self, send_host_ns: int, remote_ns: int, recv_host_ns: int) -> None:
        """One exchange: host clock before, remote reading, host clock after [ns]."""
        offset, _ = round_trip_offset(send_host_ns, remote_ns, recv_host_ns)
        rtt = int(recv_host_ns) - int(send_host_ns)
        with self._lock:
            self._trips.append((rtt, offset))
            self._best_trip = min(self._trips)

    @property
    def known(self) -> bool:
        """Whether a round trip was added."""
        return self._best_trip is not None

    def _best(self) -> tuple[int, int]:
        best = self._best_trip
        if best is None:
            raise InputError("no clock round trip yet")
        return best

    @property
    def offset_ns(self) -> int:
        """Host clock minus remote clock [ns]."""
        return self._best()[1]

    @property
    def sigma_ns(self) -> float:
        """Standard deviation of the offset [ns] (uniform over the best round trip)."""
        return self._best()[0] / (2.0 * math.sqrt(3.0))

    @property
    def sigma_s(self) -> float:
        """Standard deviation of the offset [s]."""
        return self.sigma_ns * 1e-9

    def to_host(self, remote_ns: int) -> int:
        """A remote stamp on the host clock [ns]."""
        return int(remote_ns) + self.offset_ns

    def to_remote(self, host_ns: int) -> int:
        """A host time on the remote clock [ns]."""
        return int(host_ns) - self.offset_ns
