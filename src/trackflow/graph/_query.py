"""Queries: which relationship an application wants, how it is judged and delivered."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..errors import InputError, PlanError
from ._evaluation import EvaluationFunction, resolve_evaluation
from ._paths import Path
from ._requirements import Requirements
from ._search import best_paths
from ._srg import SpatialRelationshipGraph

__all__ = ["Query", "select_paths"]


@dataclass(frozen=True)
class Query:
    """An application's request for ``T_source_target``.

    Parameters
    ----------
    source, target : str
        Frames of the wanted relationship.
    evaluation : callable, str or None
        Path evaluation (lower is better); see :func:`resolve_evaluation`.
    mode : {"pull", "push"}
        ``pull``: the application calls ``get(t)`` at any time. ``push``: results are sent at
        ``rate_hz``, each valid at the tick time plus ``time_offset_s`` (negative values
        interpolate in the past, positive ones predict; thesis 7.3.4).
    rate_hz : float or None
        Push rate [1/s] (required for push).
    time_offset_s : float
        Prediction distance [s] added to each sample time.
    fuse : bool
        Fuse all independent paths (paths that share no sensor) instead of using the best.
    static : bool
        The wanted relationship is known to be rigid (for example a calibration to estimate
        from data, thesis 7.4.1): the result is a static estimate over all measurements.
        Relationships whose paths consist of static edges only are static anyway.
    exclude : tuple of str
        Edge names the path search must not use (such as the very edge being estimated).
    name : str
    failover : bool
        Plan fallback paths (sharing no sensor with the better ones) and answer from the best
        live one (:class:`trackflow.dataflow.PathSwitch`); not with ``fuse`` or ``static``.
    hold_s : float
        Failover: how long a better path must have been live before the answers return to it.
    refused_down : int
        Failover: a sensor whose filter refused this many measurements in a row is down.
    rescore : bool
        Failover: re-score the candidate paths with the sensors' measured rate, latency and
        noise while running, and prefer the one that scores best.
    require : Requirements, optional
        What the answers need (latency, sigmas, rate): only paths meeting it are planned, and
        a running query checks its answers against it.
    """

    source: str
    target: str
    evaluation: object = None
    mode: str = "pull"
    rate_hz: float | None = None
    time_offset_s: float = 0.0
    fuse: bool = False
    static: bool = False
    exclude: tuple[str, ...] = ()
    name: str = "query"
    failover: bool = True
    hold_s: float = 2.0
    refused_down: int = 5
    rescore: bool = True
    require: Requirements | None = None
    evaluate: EvaluationFunction = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        if self.mode not in ("pull", "push"):
            raise InputError(f"query {self.name!r}: mode must be 'pull' or 'push'")
        if self.mode == "push":
            if self.rate_hz is None or not (0 < self.rate_hz < math.inf):
                raise InputError(f"query {self.name!r}: push delivery needs a rate_hz > 0")
        if not math.isfinite(self.time_offset_s):
            raise InputError(f"query {self.name!r}: time_offset_s must be finite")
        if not (0 <= self.hold_s < math.inf):
            raise InputError(f"query {self.name!r}: hold_s must be finite and >= 0")
        if not (isinstance(self.refused_down, int) and self.refused_down >= 1):
            raise InputError(f"query {self.name!r}: refused_down must be an integer >= 1")
        object.__setattr__(self, "exclude", tuple(self.exclude))
        object.__setattr__(self, "evaluate", resolve_evaluation(self.evaluation))


def select_paths(graph: SpatialRelationshipGraph, query: Query) -> list[Path]:
    """The path(s) answering a query, best first.

    Without ``fuse`` the single best path under the query's evaluation function; with
    ``fuse`` greedily every path (best first) sharing no sensor with an already chosen one.
    Ties are broken by path length and then by the path's text, so the choice is
    deterministic. Small graphs are searched exhaustively; large ones with Dijkstra on the
    evaluation function where it is additive and a pruned search where it is not
    (:func:`trackflow.graph.best_paths`).
    """
    req = query.require
    if req is None:
        return best_paths(
            graph, query.source, query.target, query.evaluate, exclude=query.exclude,
            fuse=query.fuse,
        )  # fmt: skip
    paths = best_paths(
        graph, query.source, query.target, _meeting(query.evaluate, req),
        exclude=query.exclude, fuse=query.fuse,
    )  # fmt: skip
    paths = [p for p in paths if req.path_broken(p) is None]
    if not paths:  # the best path as if nothing were required says what no path meets
        best = best_paths(graph, query.source, query.target, query.evaluate, exclude=query.exclude)[
            0
        ]
        raise PlanError(f"query {query.name!r}: no path meets {req.path_broken(best)}")
    return paths


def _meeting(evaluate: EvaluationFunction, req: Requirements) -> EvaluationFunction:
    """``evaluate``, infinite for a path that does not meet ``req`` (not additive any more:
    the search scores its candidates with it; the step costs stay a proxy)."""

    def meeting(path: Path) -> float:
        return math.inf if req.path_broken(path) is not None else evaluate(path)

    meeting.__name__ = getattr(evaluate, "__name__", "evaluation")
    step_cost = getattr(evaluate, "step_cost", None)
    if step_cost is not None:
        meeting.step_cost = step_cost
    meeting.additive = False
    return meeting
