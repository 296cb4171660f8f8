"""Plausibility of another agent's well-formed filter states, checked after decoding.

A state that decodes can still be impossible: stamped far in the future (a wrong or
hostile clock would make every later real state look old), with a covariance beyond any
physical tracker (``P[0,0] = 1e300`` is a sigma of 1e150 m), or with a sequence number
that leaps (fake numbers would count millions of lost messages). Each such state is a
counted rejection with its reason; none can stop the real stream that follows it.

* **Future stamps.** The state's time mapped onto this agent's clock may lie after now by
  at most :data:`FUTURE_NS` plus five times the clock mapping's sigma.
* **Covariance bounds.** Every variance of the state at most :data:`MAX_VARIANCE` (a sigma
  of 1 km, 1 km/s, ... or 1000 rad: far beyond any tracker, far below garbage).
* **Sequence jumps.** A sequence number more than :data:`SEQUENCE_JUMP` ahead of the last
  is refused until the next state follows it (within ten); a number not ahead of the last
  is a restarted sender and starts the count again.
"""

from __future__ import annotations

import numpy as np

__all__ = ["FUTURE_NS", "MAX_VARIANCE", "SEQUENCE_JUMP", "Sequences", "state_problem"]

#: how far after now a state's mapped stamp may lie, besides the clock's uncertainty [ns]
FUTURE_NS = 50_000_000
#: the largest variance a state may carry (units of its state: m^2, rad^2, ...)
MAX_VARIANCE = 1e6
#: a sequence number this far ahead of the last is a jump, not a loss
SEQUENCE_JUMP = 100_000


def state_problem(t_ns: int, now_ns: int, clock_sigma_s: float, covariance) -> str | None:
    """The reason a state at ``t_ns`` (this agent's clock) with ``covariance`` (n, n) is
    implausible at ``now_ns``, or ``None``."""
    if t_ns - now_ns > FUTURE_NS + 5e9 * clock_sigma_s:
        return "stamp in the future"
    if float(np.max(np.diagonal(covariance), initial=0.0)) > MAX_VARIANCE:
        return "covariance beyond physical bounds"
    return None


class Sequences:
    """The sequence numbers of each remote sensor's states: messages lost (gaps) and jumps
    (refused until confirmed)."""

    def __init__(self):
        self._last: dict[str, int] = {}
        self._jump: dict[str, int] = {}
        #: messages missing from the sequences (gaps of up to SEQUENCE_JUMP)
        self.lost = 0

    def take(self, edge: str, seq: int) -> bool:
        """Account for state ``seq`` of ``edge``; False for a jump not yet confirmed."""
        last = self._last.get(edge)
        if last is not None and seq - last > SEQUENCE_JUMP:
            jump = self._jump.get(edge)
            if jump is None or not jump < seq <= jump + 10:
                self._jump[edge] = seq
                return False
        elif last is not None and seq > last + 1:
            self.lost += seq - last - 1
        self._jump.pop(edge, None)
        self._last[edge] = seq
        return True
