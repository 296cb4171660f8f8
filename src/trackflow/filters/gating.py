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

import functools
import math
from dataclasses import dataclass

from ..errors import InputError
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


@functools.lru_cache(maxsize=256)  # gates are asked per measurement; a few (p, dof) pairs
def chi2_gate(probability: float | None, dof: int) -> float:
    """Mahalanobis (NIS) threshold passing ``probability`` of consistent innovations: the
    chi-square quantile, ``P(X <= gate) = probability`` for ``X ~ chi2(dof)``.

    Solved on the closed-form survival function (:func:`chi2_survival`) by bisection to
    double precision, so that a filter does not import scipy (0.3 s at every command start).
    """
    if probability is None:
        return math.inf
    if not (0.0 <= probability <= 1.0 and int(dof) == dof and dof >= 1):
        raise InputError(
            f"need 0 <= probability <= 1 and an integer dof >= 1, got {probability}, {dof}"
        )
    if probability == 1.0:
        return math.inf
    if probability == 0.0:
        return 0.0
    tail = 1.0 - probability
    lo, hi = 0.0, float(dof)
    while chi2_survival(hi, dof) > tail:
        lo, hi = hi, 2.0 * hi
    for _ in range(200):  # the survival function is strictly decreasing in x
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            break
        lo, hi = (mid, hi) if chi2_survival(mid, dof) > tail else (lo, mid)
    return 0.5 * (lo + hi)


def chi2_survival(x: float, dof: int) -> float:
    """``P(X > x)`` for ``X ~ chi2(dof)``, integer ``dof >= 1``, in closed form.

    With ``h = x / 2``: even ``dof = 2m``: ``exp(-h) sum_{i<m} h^i / i!``; odd ``dof = 2m + 1``:
    ``erfc(sqrt(h)) + exp(-h) sum_{i<m} h^(i + 1/2) / Gamma(i + 3/2)``.
    """
    if x <= 0.0:
        return 1.0
    h = 0.5 * x
    m, odd = divmod(int(dof), 2)
    if odd:
        total = math.erfc(math.sqrt(h))
        term = math.sqrt(h) * math.exp(-h) / math.gamma(1.5)
        offset = 1.5
    else:
        total, term, offset = 0.0, math.exp(-h), 1.0
    for i in range(m):
        total += term
        term *= h / (i + offset)
    return total


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
            raise InputError(f"gate_probability must be in (0, 1] or None, got {p}")
        if int(self.reset_after) < 1:
            raise InputError(f"reset_after must be >= 1, got {self.reset_after}")
        object.__setattr__(self, "reset_after", int(self.reset_after))

    def threshold(self, dof: int) -> float:
        """NIS threshold for a measurement of ``dof`` dimensions."""
        return chi2_gate(self.gate_probability, dof)
