"""One gate and reset policy for every filter family and both drivers.

A kernel source (:mod:`trackflow.math._backend`): the scalar decisions below run inside the
compiled offline loops and are called, unchanged, by the streaming filters. The policy:

* an innovation whose normalised square (NIS) exceeds the chi-square quantile of
  ``gate_probability`` is rejected (``GATED``) and leaves the state untouched;
* after ``reset_after`` consecutive gated measurements the next absolute measurement
  re-initialises the filter (``RESET``): a lost filter recovers instead of gating forever;
* any accepted (or initialising) measurement ends a gated run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from scipy.special import chdtri

from .contract import FilterStatus

KERNELS = ("reset_due", "next_gated_run", "is_gated")
KERNEL_SOURCES = ()

ACCEPTED = int(FilterStatus.ACCEPTED)
GATED = int(FilterStatus.GATED)
DIVERGED = int(FilterStatus.DIVERGED)
INVALID = int(FilterStatus.INVALID)
INITIALIZED = int(FilterStatus.INITIALIZED)
RESET = int(FilterStatus.RESET)


def reset_due(initialized, gated_run, reset_after):
    """Whether the next absolute measurement must (re-)initialise the filter."""
    return (not initialized) or gated_run >= reset_after


def next_gated_run(status, gated_run):
    """Length of the run of consecutive gated measurements after one with ``status``."""
    return gated_run + 1 if status == GATED else 0


def is_gated(nis, gate):
    """Whether an innovation with this NIS is rejected (a NaN NIS is rejected too)."""
    return not nis <= gate


def chi2_gate(probability: float | None, dof: int) -> float:
    """Mahalanobis (NIS) threshold passing ``probability`` of consistent innovations."""
    if probability is None or probability >= 1.0:
        return math.inf
    # chdtri is the inverse survival function of chi-square; it avoids importing scipy.stats
    # (about a second at every command-line start).
    return float(chdtri(dof, 1.0 - probability))


@dataclass(frozen=True)
class GatePolicy:
    """Validated gate and reset settings (see the module docstring).

    Parameters
    ----------
    gate_probability : float or None
        Probability mass of consistent innovations that passes the gate; ``None`` disables it.
    reset_after : int
        Consecutive gated measurements after which the filter re-initialises (>= 1).
    """

    gate_probability: float | None = 0.999
    reset_after: int = 10

    def __post_init__(self):
        p = self.gate_probability
        if p is not None and not (0.0 < p <= 1.0):
            raise ValueError(f"gate_probability must be in (0, 1] or None, got {p}")
        if int(self.reset_after) < 1:
            raise ValueError(f"reset_after must be >= 1, got {self.reset_after}")
        object.__setattr__(self, "reset_after", int(self.reset_after))

    def threshold(self, dof: int) -> float:
        """NIS threshold for a measurement of ``dof`` dimensions."""
        return chi2_gate(self.gate_probability, dof)
