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

With ``rehearse_s`` and a :attr:`DueWait.rehearse` callable, the wait also wakes once per
datagram to call it (a :class:`~trackflow.trackers.rehearsal.Rehearsal` of the packet's path,
which warms the code the datagram will run), timed to be over ``rehearse_s`` before the
datagram is due: it starts that long plus its own recent duration (the longest of the last
few calls, measured) before. The code cools again while the thread sleeps, so the closer the
better, as long as the rehearsal is over when the datagram comes.
"""

from __future__ import annotations

import math
import select
import statistics
import time
from collections import deque
from collections.abc import Callable

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
    rehearse_s : float
        How long before the due time :attr:`rehearse` should be over [s]; 0: never called.
    """

    #: the assumed duration of a rehearsal before one was measured [s]
    FIRST_REHEARSAL_S = 1e-3

    MIN_INTERVALS = 3  # intervals seen before a period is trusted

    def __init__(
        self,
        spin_s: float,
        history: int = 15,
        clock=time.time,
        nap=None,
        rehearse_s: float = 0.0,
    ):
        if not spin_s >= 0:
            raise InputError(f"spin_s must be >= 0, got {spin_s}")
        if not rehearse_s >= 0:
            raise InputError(f"rehearse_s must be >= 0, got {rehearse_s}")
        self.spin_s = float(spin_s)
        self.rehearse_s = float(rehearse_s)
        #: called once per datagram, to be over ``rehearse_s`` before it is due, with a
        #: callable telling whether a datagram is already waiting (then cut it short)
        self.rehearse: Callable[[Callable[[], bool]], object] | None = None
        self.rehearsed = 0  # calls of rehearse
        self.rehearsals_s: deque[float] = deque(maxlen=8)  # their recent durations [s]
        self._rehearsed_due: float | None = None
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
        if self.rehearse_s and self.rehearse is not None and due is not None:
            if due != self._rehearsed_due:  # once per datagram, and not when it is late
                start = due - self.rehearse_s - self.rehearsal_s()
                if now < start:  # asleep until the rehearsal
                    self._nap(sel, min(timeout, start - now))
                    ready = sel.select(0)
                    if ready:
                        return ready
                    now = clock()
                    if now < start:  # the timeout first: the caller's loop comes back
                        return []
                if now < due - self.rehearse_s:  # else it would run into the datagram
                    self._rehearsed_due = due
                    self.rehearse(lambda: bool(sel.select(0)))
                    self.rehearsed += 1
                    end = clock()
                    self.rehearsals_s.append(end - now)
                    now = end
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

    def rehearsal_s(self) -> float:
        """How long a rehearsal is expected to take [s]: the longest of the recent ones."""
        return max(self.rehearsals_s, default=self.FIRST_REHEARSAL_S)

    def arrived(self, t: float) -> None:
        """A datagram of the stream arrived at ``t`` [s] (the ``clock``'s time); nothing
        to learn when neither polling nor rehearsing."""
        if not (self.spin_s or self.rehearse_s):
            return
        if self._last is not None:
            gap = t - self._last
            if 0.0 < gap < 1.0:  # not a pause of the stream
                self._gaps.append(gap)
                if len(self._gaps) >= self.MIN_INTERVALS:
                    self.period_s = statistics.median(self._gaps)
        self._last = t
