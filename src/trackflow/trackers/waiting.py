"""Waiting for a periodic stream's next datagram: asleep until shortly before it is due.

A tracker sends its frames at a steady rate (240 Hz: every 4.17 ms). A receiving thread that
sleeps in its selector until a datagram arrives is woken by the kernel, and on a virtual
machine an idle core's wake-up costs about a tenth of a millisecond before the thread runs
(``bench/trackers.py`` splits it out as "receipt -> packet in the receiving thread").
:class:`DueWait` predicts when the next datagram is due (the last arrival plus the stream's
period, the median of its recent intervals, so a lost frame or a late one does not move it;
the arrivals are the kernel's receive stamps on the host clock, so the thread's own delays
do not shift the prediction) and sleeps only until ``spin_s`` before that; from then it polls
the sockets without blocking until the datagram comes, or until ``spin_s`` after it was due,
when it sleeps again. The price is CPU: about ``spin_s`` of polling per frame (7 % of a core
for 0.3 ms at 240 Hz), counted in :attr:`DueWait.polled_s`. Off (``spin_s = 0``) it is the
selector's plain wait.
"""

from __future__ import annotations

import math
import select
import statistics
import time
from collections import deque

from ..errors import InputError

__all__ = ["DueWait", "select_nap"]


#: select(2) takes no file descriptor from this one on (FD_SETSIZE)
_SELECT_LIMIT = 1024


def select_nap(sel, seconds: float) -> None:
    """Wait up to ``seconds`` for one of the files of selector ``sel`` to be readable, with
    select(2)'s microsecond timeout (a selector's epoll rounds up to a whole millisecond). A
    descriptor select(2) cannot take: the selector, for the whole milliseconds below
    ``seconds`` (the window then opens up to a millisecond early: more polling)."""
    fds = list(sel.get_map())
    if fds and max(fds) < _SELECT_LIMIT:
        select.select(fds, [], [], seconds)
    elif seconds >= 1e-3:
        sel.select(math.floor(seconds * 1e3) * 1e-3)


class DueWait:
    """A selector wait that polls around the due time of a periodic stream's next datagram.

    Parameters
    ----------
    spin_s : float
        Half-width of the polling window around the due time [s]; 0 turns polling off.
    history : int
        Number of recent intervals whose median is the stream's period.
    clock : callable
        The time [s] the arrivals are given in: the host clock (``time.time``), that of the
        kernel's receive stamps.
    nap : callable
        ``nap(selector, seconds)`` waits up to ``seconds`` for one of the selector's files to
        be readable (:func:`select_nap`).
    """

    MIN_INTERVALS = 3  # intervals seen before a period is trusted

    def __init__(
        self,
        spin_s: float,
        history: int = 15,
        clock=time.time,
        nap=None,
    ):
        if not spin_s >= 0:
            raise InputError(f"spin_s must be >= 0, got {spin_s}")
        self.spin_s = float(spin_s)
        self.period_s: float | None = None  # the stream's period, once known
        self.polled_s = 0.0  # time spent polling [s]
        self.caught = 0  # datagrams that arrived while polling
        self._clock = clock
        self._nap = select_nap if nap is None else nap
        self._last: float | None = None
        self._gaps: deque[float] = deque(maxlen=history)

    def due(self) -> float | None:
        """When the next datagram is due [s] (the ``clock``'s time), if known."""
        if self.period_s is None or self._last is None:
            return None
        return self._last + self.period_s

    def select(self, sel, timeout: float) -> list:
        """``sel.select(timeout)``, polling instead of sleeping from ``spin_s`` before the
        next datagram is due to ``spin_s`` after; may return early with nothing ready (the
        caller's loop comes back)."""
        due, clock = self.due(), self._clock
        now = clock()
        if not self.spin_s or due is None or now > due + self.spin_s:
            return sel.select(timeout)
        start = due - self.spin_s
        if start > now:  # asleep until the window opens
            self._nap(sel, min(timeout, start - now))
            ready = sel.select(0)
            if ready:
                return ready
            now = clock()
        begin, end = now, due + self.spin_s
        while True:
            ready = sel.select(0)
            now = clock()
            if ready or now >= end:
                break
        self.polled_s += now - begin
        self.caught += bool(ready)
        return ready

    def arrived(self, t: float) -> None:
        """A datagram of the stream arrived at ``t`` [s] (the ``clock``'s time); nothing
        to learn when not polling."""
        if not self.spin_s:
            return
        if self._last is not None:
            gap = t - self._last
            if 0.0 < gap < 1.0:  # not a pause of the stream
                self._gaps.append(gap)
                if len(self._gaps) >= self.MIN_INTERVALS:
                    self.period_s = statistics.median(self._gaps)
        self._last = t
