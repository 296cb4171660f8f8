"""Evaluation functions: a scalar per path, lower is better (thesis 2.1.2 and 6.4)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..math import evaluate_covariance
from ._paths import Path

__all__ = ["EvaluationFunction", "covariance_trace", "latency_rate", "resolve_evaluation"]

EvaluationFunction = Callable[[Path], float]


def latency_rate(lam: float = 1.0) -> EvaluationFunction:
    """Eq. 2.5: ``e = sum over edges of lag(q) + lambda / rate(q)`` [s].

    Static edges contribute nothing (no lag, infinite rate). ``lam`` weights the sample
    interval against latency.
    """
    if not np.isfinite(lam) or lam < 0:
        raise ValueError(f"lambda must be finite and >= 0, got {lam}")

    def evaluate(path: Path) -> float:
        return float(sum(s.edge.latency_s + lam / s.edge.rate_hz for s in path.steps))

    evaluate.__name__ = f"latency_rate(lambda={lam:g})"
    return evaluate


def covariance_trace(weights=None) -> EvaluationFunction:
    """Eq. 6.26: ``e = sqrt(trace(A C A^T))`` of the covariance propagated along the path.

    The edge covariances (over ``(dt, dtheta)``, ``t_true = t + dt``, ``R_true = R Exp(dtheta)``)
    are chained with the first-order compose/inverse Jacobians at the edges' static values or
    nominal poses (identity where unknown). ``weights`` is the application's matrix ``A``
    (k, 6); identity if omitted.
    """
    a = None if weights is None else np.asarray(weights, dtype=float)

    def evaluate(path: Path) -> float:
        return float(evaluate_covariance(path.value().covariance, a))

    evaluate.__name__ = "covariance_trace" if a is None else "covariance_trace(A)"
    return evaluate


def resolve_evaluation(spec) -> EvaluationFunction:
    """An evaluation function from a callable or a name: ``"latency"`` (eq. 2.5, lambda=1),
    ``"latency:<lambda>"`` or ``"covariance"`` (eq. 6.26)."""
    if spec is None:
        return latency_rate(1.0)
    if callable(spec):
        return spec
    if isinstance(spec, str):
        name, _, arg = spec.partition(":")
        if name == "latency":
            return latency_rate(float(arg) if arg else 1.0)
        if name == "covariance" and not arg:
            return covariance_trace()
    raise ValueError(
        f"unknown evaluation function {spec!r} (use 'latency', 'latency:<lambda>', "
        "'covariance' or a callable)"
    )
