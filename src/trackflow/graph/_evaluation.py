"""Evaluation functions: a scalar per path, lower is better (thesis 2.1.2 and 6.4).

An evaluation function may carry ``step_cost(edge, inverted) -> float`` (an additive cost per
step, >= 0) and ``additive`` (True when the evaluation *is* the sum of the step costs). The path
search uses them to scale to large graphs (:func:`trackflow.graph.best_paths`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..errors import InputError
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
        raise InputError(f"lambda must be finite and >= 0, got {lam}")

    def step_cost(edge, inverted: bool = False) -> float:
        return edge.latency_s + lam / edge.rate_hz

    def evaluate(path: Path) -> float:
        return float(sum(step_cost(s.edge) for s in path.steps))

    evaluate.__name__ = f"latency_rate(lambda={lam:g})"
    evaluate.step_cost = step_cost  # the evaluation is this sum: exact shortest-path search
    evaluate.additive = True
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

    def step_cost(edge, inverted: bool = False) -> float:
        c = edge.covariance
        return float(c.trace() if a is None else (a @ c @ a.T).trace())

    evaluate.__name__ = "covariance_trace" if a is None else "covariance_trace(A)"
    # The squared evaluation is this sum when every pose is identity; lever arms make it a
    # proxy only (the path search prunes with it and scores candidates exactly).
    evaluate.step_cost = step_cost
    evaluate.additive = False
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
    raise InputError(
        f"unknown evaluation function {spec!r} (use 'latency', 'latency:<lambda>', "
        "'covariance' or a callable)"
    )
