"""Mapping a remote clock onto the host clock: offset and drift from a lower envelope.

Every packet gives a pair (remote stamp ``x`` of an event, host receive time ``h``); the remote
clock is a tracker's, say. The difference ``y = h - x`` is the clock offset (``host - remote``,
the convention of :mod:`trackflow.timesync`) plus the transport delay, and the delay is never
negative: the smallest ``y`` over time are the packets that came through fastest. The estimator
fits the line ``y = a + b (x - x_ref)`` from below (the lower envelope): the drift ``b`` is the
slope of the line that lies below every point of a sliding window and maximises the sum of its
values (linear programming; the edge of the lower convex hull above the mean of ``x``), and the
offset ``a`` puts the line through the lowest point of the last seconds, so that mapping a new
stamp extrapolates over seconds, not over the whole window. Delay spikes sit above the envelope
and never move it; until the window spans ``min_span_s`` the drift is taken as zero. The mapped
host time of a stamp is ``x + a + b (x - x_ref)``; it includes the minimum transport delay (on
loopback tens of microseconds), which no one-way method can separate from the offset. Its
scatter is the gap between the two smallest delays of the anchoring seconds
(:attr:`ClockEstimate.scatter_ns`): the smallest of many delays is as far from the true
minimum, on average and in spread, as it is from the second smallest.

Points are reduced to per-bin minima (``bin_s``) so a refit costs ``O(window / bin)``, done
once per closed bin; between refits a new point below the line lowers the line at once.

Round trips (:meth:`ClockMapper.add_round_trip`, NatNet's echo requests) separate the two: a
request sent at host time ``s``, answered at remote time ``x`` and received at ``r`` bounds the
offset to ``[s - x, r - x]``; with equal delays both ways it is the midpoint, within half the
round trip time (:func:`~trackflow.timesync.round_trip_offset`). Of the round trips in the
window, the shortest one gives the minimum transport delay
``transit = line(x) - ((s + r) / 2 - x)`` (at least 0), which the published mapping subtracts.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..errors import InputError, StateError
from ..math import frozen, kernels_for
from . import _kernels
from ._round_trip import round_trip_offset

__all__ = ["ClockEstimate", "ClockMapper", "lower_envelope"]

#: samples a fit takes before one below its line is suspect (ClockMapper's ``confirm``)
YOUNG = 8


@dataclass(frozen=True, slots=True)
class ClockEstimate:
    """The current clock mapping.

    Attributes
    ----------
    offset_ns : float
        ``host - remote`` at remote time ``ref_ns`` [ns] (offset plus minimum delay).
    drift : float
        ``d(host) / d(remote) - 1`` (dimensionless; 1e-6 = 1 ppm).
    ref_ns : int
        Remote time of the reference point [ns].
    sigma_ns : float
        Median height of the per-bin minima above the envelope [ns]: how far a typical
        fastest packet sits above the fitted line, the scale of the mapping's uncertainty
        (a median, so that one stalled bin does not inflate it).
    points : int
        Bins in the fit.
    transit_ns : float
        Minimum transport delay found by round trips [ns], subtracted by :meth:`to_host`
        (0 without round trips).
    transit_sigma_ns : float
        Half the shortest round trip time [ns]: the bound on ``transit_ns`` if the delays
        both ways differ (0 without round trips).
    scatter_ns : float
        Standard deviation of the envelope's offset [ns]: the height of the second lowest
        bin minimum above the line's anchor (module docstring; 0 with one bin).
    """

    offset_ns: float
    drift: float
    ref_ns: int
    sigma_ns: float
    points: int
    transit_ns: float = 0.0
    transit_sigma_ns: float = 0.0
    scatter_ns: float = 0.0

    @property
    def offset_sigma_ns(self) -> float:
        """Standard deviation of the mapped host time [ns]: the envelope's scatter and the
        shortest round trip's uniform error (``transit_sigma_ns / sqrt 3``) together. Without
        round trips the mapping is in addition late by the minimum transport delay."""
        return math.hypot(self.scatter_ns, self.transit_sigma_ns / math.sqrt(3.0))

    def to_host(self, remote_ns: int) -> int:
        """Host time [ns] of a remote time [ns]."""
        dx = remote_ns - self.ref_ns
        return remote_ns + int(round(self.offset_ns - self.transit_ns + self.drift * dx))


def lower_envelope(x, y) -> tuple[float, float]:
    """``(a, b)`` of the line ``a + b (x - mean(x))`` below every point with the largest sum.

    ``x`` must be increasing. One point (or all at one ``x``): the lowest, ``b = 0``
    (:func:`trackflow.timesync._kernels.lower_envelope`).
    """
    if len(x) == 0:
        raise InputError("no points")
    a, b = kernels_for(_kernels).lower_envelope(frozen(x), frozen(y))
    return float(a), float(b)


class ClockMapper:
    """Online remote-to-host clock mapping (see the module docstring).

    Parameters
    ----------
    window_s : float
        Span of remote time kept for the fit [s].
    bin_s : float
        Width of the bins whose minima are fitted [s].
    min_span_s : float
        Drift is estimated only once the bins span this long [s] (before: offset only).
    max_drift : float
        Larger fitted drifts are clipped (a real oscillator is within 1e-4).
    anchor_s : float
        The line is anchored on the lowest bin of the last ``anchor_s`` seconds [s] ...
    stall_s : float
        ... unless that bin sits more than ``3 x`` the usual height of bins above the
        window's envelope plus ``stall_s`` [s] (every recent packet late: a stall); then on
        the window's envelope.
    step_s : float
        A stamp earlier than the newest one by more than this, or an offset sample below
        the line by more than this [s], is a step of the remote clock (a restart). It is
        refused (:meth:`add` returns False) until confirmed; then the fit starts again from
        the confirming samples.
    jump_s : float
        An offset sample below the line by more than this [s] (a packet faster than every
        packet before it by that much) is a jump: mapped by the current estimate, but kept
        out of the fit until confirmed; then it enters the fit.
    confirm : int
        A step or jump is confirmed by this many suspect samples in a row that agree with
        each other (stamps increasing, offsets within ``jump_s``, for steps ``step_s``).
        Suspects are counted in :attr:`suspects`. One corrupted stamp therefore never moves
        the mapping, and one stamped far off is never mapped. During the first
        :data:`YOUNG` samples of a fit a sample below the line is not suspect (the first
        packets may have come slowly).
    max_rtt_s : float
        Longer round trips (and negative ones) are rejected and counted [s].
    """

    def __init__(
        self,
        window_s: float = 30.0,
        bin_s: float = 0.1,
        min_span_s: float = 10.0,
        max_drift: float = 5e-4,
        anchor_s: float = 3.0,
        stall_s: float = 1e-4,
        step_s: float = 0.05,
        jump_s: float = 1e-3,
        confirm: int = 3,
        max_rtt_s: float = 0.1,
    ):
        if not (window_s > 0 and bin_s > 0 and window_s > bin_s):
            raise InputError("clock mapper: need window_s > bin_s > 0")
        self.window_ns = int(window_s * 1e9)
        self.bin_ns = int(bin_s * 1e9)
        self.min_span_ns = int(min_span_s * 1e9)
        self.anchor_ns = int(anchor_s * 1e9)
        self.stall_ns = float(stall_s * 1e9)
        self.step_ns = int(step_s * 1e9)
        self.jump_ns = int(jump_s * 1e9)
        if confirm < 1:
            raise InputError("clock mapper: confirm must be at least 1")
        self.confirm = int(confirm)
        #: samples refused as an unconfirmed step or jump
        self.suspects = 0
        self._held: list[tuple[int, int]] = []  # the suspect samples in a row, in order
        self._fitted = 0  # samples in the fit since the last reset
        self.max_rtt_ns = int(max_rtt_s * 1e9)
        #: clock steps detected (the fit restarted from the data after the step)
        self.steps = 0
        self.max_drift = float(max_drift)
        #: the closed bins' minima, remote ns and host - remote ns, in the order closed
        self._tx = np.empty(int(window_s / bin_s) + 8, np.int64)
        self._y = np.empty_like(self._tx)
        self._nbins = 0
        self._unordered = False  # a bin closed before the one closed previously
        self._cur: tuple[int, int] | None = None
        self._cur_bin: int | None = None
        self._env: ClockEstimate | None = None  # the envelope fit alone
        #: the published mapping (the envelope minus the transit found by round trips)
        self.estimate: ClockEstimate | None = None
        self._published: tuple | None = None  # (envelope, round trip) of the estimate
        self.round_trips: deque[tuple[int, int, int]] = deque()  # (remote, rtt, offset)
        #: round trips rejected (negative or longer than ``max_rtt_s``)
        self.rejected_round_trips = 0
        self.count = 0
        self._newest = 0

    def reset(self) -> None:
        """Forget everything (the remote clock restarted)."""
        self._nbins = 0
        self._unordered = False
        self._cur = self._cur_bin = self._env = self.estimate = self._published = None
        self.round_trips.clear()
        self._newest = 0
        self._held = []
        self._fitted = 0

    def add(self, remote_ns: int, host_ns: int) -> bool:
        """Add one (remote stamp, host receive time) pair [ns]; False if the stamp is
        refused as an unconfirmed step (``step_s``, ``jump_s``, ``confirm``): then it must
        not be mapped."""
        self.count += 1
        kind = self._suspect(remote_ns, host_ns - remote_ns)
        if kind is None:
            self._held = []
            self._add(remote_ns, host_ns)
            return True
        held = self._held
        tol = self.step_ns if kind == "step" else self.jump_ns
        if held and not (
            held[-1][0] < remote_ns
            and abs((held[-1][1] - held[-1][0]) - (host_ns - remote_ns)) <= tol
        ):  # not the same new regime as the suspects before: start again from this one
            held = []
        held.append((remote_ns, host_ns))
        if len(held) < self.confirm:
            self._held = held
            self.suspects += 1
            return kind == "jump"  # mapped by the current estimate, not in the fit
        self._held = []
        if kind == "step":  # a restarted remote clock: the fit starts from the new samples
            self.reset()
            self.steps += 1
        for r, h in held:
            self._add(r, h)
        return True

    def _suspect(self, remote_ns: int, y: int) -> str | None:
        """``"step"``, ``"jump"`` or None (an ordinary sample) for offset sample ``y``."""
        e = self._env
        if e is None:
            return None
        if remote_ns < self._newest - self.step_ns:
            return "step"
        if self._fitted < YOUNG:
            return None
        below = e.offset_ns + e.drift * (remote_ns - e.ref_ns) - y  # the envelope at this x
        if below > self.step_ns:
            return "step"
        return "jump" if below > self.jump_ns else None

    def _add(self, remote_ns: int, host_ns: int) -> None:
        """Add an ordinary sample to the fit."""
        self._fitted += 1
        y = host_ns - remote_ns
        e = self._env
        line = 0.0
        if e is not None:
            line = e.offset_ns + e.drift * (remote_ns - e.ref_ns)
        if self._env is None or remote_ns > self._newest:
            self._newest = remote_ns
        k = remote_ns // self.bin_ns
        if self._cur_bin is None or k != self._cur_bin:
            if self._cur is not None:
                self._close_bin(remote_ns)
                self._refit()
            self._cur_bin, self._cur = k, (remote_ns, y)
        elif y < self._cur[1]:
            self._cur = (remote_ns, y)
        e2 = self._env
        if e2 is None:
            self._env = ClockEstimate(float(y), 0.0, remote_ns, 0.0, 1)
        else:
            if e2 is not e:  # refitted or reset: the new envelope at this x
                line = e2.offset_ns + e2.drift * (remote_ns - e2.ref_ns)
            if y < line:  # below the envelope: lower it now, keep the slope
                self._env = ClockEstimate(
                    e2.offset_ns - (line - y),
                    e2.drift,
                    e2.ref_ns,
                    e2.sigma_ns,
                    e2.points,
                    scatter_ns=min(e2.scatter_ns, line - y) if e2.points > 1 else line - y,
                )
        self._publish()

    @staticmethod
    def warm_up() -> None:
        """Run the fit's kernels once, so that compiling them (numba, first use in a process)
        happens before a tracker is listened to."""
        c = ClockMapper(window_s=3.0, bin_s=0.1, min_span_s=0.2)
        for k in range(6):
            c.add(k * 100_000_000, k * 100_000_000 + 5_000)
        if c.estimate is None or c.estimate.points < 2:
            raise StateError("the clock fit made no estimate")

    def _close_bin(self, remote_ns: int) -> None:
        """The open bin's minimum into the window; the bins older than the window go."""
        n, tx, y = self._nbins, self._tx, self._y
        if n == len(tx):
            tx = self._tx = np.concatenate([tx, np.empty_like(tx)])
            y = self._y = np.concatenate([y, np.empty_like(y)])
        x_c, y_c = self._cur
        if n and x_c < tx[n - 1]:
            self._unordered = True
        tx[n], y[n] = x_c, y_c
        n += 1
        old = 0
        while old < n and remote_ns - int(tx[old]) > self.window_ns:
            old += 1
        if old:
            tx[: n - old] = tx[old:n].copy()
            y[: n - old] = y[old:n].copy()
            n -= old
        self._nbins = n

    def _refit(self) -> None:
        n = self._nbins
        if not n:
            return
        tx, y = self._tx[:n], self._y[:n]
        if self._unordered:  # a bin closed out of order (maybe gone from the window since)
            if n > 1 and (tx[1:] < tx[:-1]).any():  # by time
                order = np.lexsort((y, tx))
                tx, y = tx[order], y[order]
            else:
                self._unordered = False
        # with the envelope's slope, the line through the lowest recent bin (it extrapolates
        # over seconds instead of the whole window) unless every recent packet was late
        a, b, sigma, scatter = kernels_for(_kernels).envelope_fit(
            frozen(tx, np.int64), frozen(y), self.min_span_ns, self.max_drift, self.anchor_ns,
            self.stall_ns,
        )  # fmt: skip
        a, b, sigma, ref_ns = float(a), float(b), float(sigma), int(tx[-1])
        scatter = float(scatter)
        self._env = ClockEstimate(a, b, ref_ns, sigma, n, scatter_ns=scatter)
        if self._cur is not None:  # the open bin may already hold a lower point
            x_c, y_c = self._cur
            line = a + b * (x_c - ref_ns)
            if y_c < line:
                self._env = ClockEstimate(a - (line - y_c), b, ref_ns, sigma, n, 0.0, 0.0,
                                          min(scatter, line - y_c))  # fmt: skip

    def add_round_trip(self, send_host_ns: int, remote_ns: int, recv_host_ns: int) -> bool:
        """Add one round trip: a request sent at host time ``send_host_ns``, answered at
        remote time ``remote_ns`` and received at ``recv_host_ns`` [ns] (module docstring).
        False (counted in :attr:`rejected_round_trips`) if its time is negative or longer
        than ``max_rtt_s``, or, once the fit is past its first samples, if its offset lies
        off the envelope by more than half its time plus ``jump_s`` (a corrupted stamp or
        token: the shortest round trip would otherwise shift every mapped time by it)."""
        rtt = recv_host_ns - send_host_ns
        if not 0 <= rtt <= self.max_rtt_ns:
            self.rejected_round_trips += 1
            return False
        mid = round_trip_offset(send_host_ns, remote_ns, recv_host_ns)[0]
        e = self._env
        if e is not None and self._fitted >= YOUNG:
            transit = e.offset_ns + e.drift * (remote_ns - e.ref_ns) - mid
            if abs(transit) > rtt / 2 + self.jump_ns:
                self.rejected_round_trips += 1
                return False
        self.round_trips.append((remote_ns, rtt, mid))
        newest = max(t for t, _, _ in self.round_trips)
        while self.round_trips and newest - self.round_trips[0][0] > self.window_ns:
            self.round_trips.popleft()
        self._best = min(self.round_trips, key=lambda r: r[1])
        self._publish()
        return True

    def _publish(self) -> None:
        """:attr:`estimate`: the envelope fit minus the transit of the shortest round trip."""
        e = self._env
        if e is None or not self.round_trips:
            self.estimate = e
            return
        if self._published == (e, self._best):  # neither changed: the same estimate
            return
        x, rtt, mid = self._best
        transit = max(e.offset_ns + e.drift * (x - e.ref_ns) - mid, 0.0)
        self.estimate = ClockEstimate(
            e.offset_ns, e.drift, e.ref_ns, e.sigma_ns, e.points, transit, rtt / 2, e.scatter_ns
        )
        self._published = (e, self._best)

    def to_host(self, remote_ns: int) -> int:
        """Host time [ns] of a remote time [ns] (the latest estimate)."""
        if self.estimate is None:
            raise InputError("clock mapper: no samples yet")
        return self.estimate.to_host(remote_ns)
