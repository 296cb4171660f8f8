"""Path search whose cost grows gently with the graph (thesis 10.3.9, "bigger setups").

:func:`best_paths` answers a query's path selection:

* Small graphs (the simple paths between the two frames can be listed within a budget of
  search steps): every simple path is scored with the query's evaluation function and the best
  are taken, exactly as the thesis describes it.
* Larger graphs, evaluation function additive over the path's steps (eq. 2.5, latency and
  update rate): Dijkstra's algorithm on the steps' costs gives the best path exactly in
  ``O(E log V)``; fused paths come from further Dijkstra searches with the sensors already used
  removed.
* Larger graphs, any other evaluation function (eq. 6.26, the propagated covariance, or a
  callable): a pruned search. Dijkstra on the function's additive proxy (``step_cost``: the
  edge covariance's weighted trace, exact for identity poses; one per step otherwise) gives
  the proxy's best path and, through every edge, the best path using that edge
  (:func:`via_edge_paths`); the true function scores the cheapest of these candidates and
  the best wins. This is a heuristic: it finds the optimum
  whenever the proxy orders paths like the true function, and always returns a valid path.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable, Iterable

from ..errors import InputError, PlanError
from ._paths import Path, PathStep
from ._srg import Edge, SpatialRelationshipGraph

__all__ = ["DEFAULT_BUDGET", "best_paths", "shortest_path", "via_edge_paths"]

#: Search steps the exhaustive listing of simple paths may take before the scalable search
#: takes over (a few milliseconds of work).
DEFAULT_BUDGET = 2_000
#: Graphs with more edges skip the exhaustive listing (it would exceed the budget anyway).
EXHAUSTIVE_MAX_EDGES = 200
#: Paths a non-additive evaluation function scores exactly on a large graph.
NON_ADDITIVE_CANDIDATES = 16

StepCost = Callable[[Edge, bool], float]


class _BudgetExceeded(Exception):
    pass


def _hop(edge: Edge, inverted: bool) -> float:
    return 1.0


def _all_simple_paths(
    graph: SpatialRelationshipGraph, source: str, target: str, banned: set[str], budget: int
) -> list[Path]:
    """Every simple path avoiding ``banned`` edge names; raises _BudgetExceeded after
    ``budget`` edge visits."""
    found: list[Path] = []
    steps_left = budget
    incident = graph._incident

    def walk(frame: str, visited: set[str], steps: list[tuple]) -> None:
        nonlocal steps_left
        if frame == target:
            found.append(Path(tuple(PathStep(e, inv) for e, inv in steps)))
            return
        for edge, inverted in incident.get(frame, ()):
            steps_left -= 1
            if steps_left < 0:
                raise _BudgetExceeded
            end = edge.source if inverted else edge.target
            if end in visited or edge.name in banned:
                continue
            visited.add(end)
            steps.append((edge, inverted))
            walk(end, visited, steps)
            steps.pop()
            visited.discard(end)

    walk(source, {source}, [])
    return found


def _tree(graph, root: str, step_cost: StepCost, banned: set[str], stop: str | None = None):
    """Dijkstra from ``root``: ``{frame: (cost, hops)}`` and ``{frame: (previous, edge,
    inverted)}``; stops early once ``stop`` is settled. Ties: fewer hops, then edge order."""
    counter = itertools.count(1)
    dist: dict[str, float] = {root: 0.0}
    hop: dict[str, int] = {root: 0}
    back: dict[str, tuple[str, Edge, bool]] = {}
    heap = [(0.0, 0, 0, root)]
    done: set[str] = set()
    incident = graph._incident
    push, pop = heapq.heappush, heapq.heappop
    while heap:
        cost, hops, _, frame = pop(heap)
        if frame in done:
            continue
        done.add(frame)
        if frame == stop:
            break
        hops += 1
        for edge, inverted in incident.get(frame, ()):
            nxt = edge.source if inverted else edge.target
            if nxt in done or edge.name in banned:
                continue
            c = cost + step_cost(edge, inverted)
            old = dist.get(nxt)
            if old is None or c < old or (c == old and hops < hop[nxt]):
                dist[nxt] = c
                hop[nxt] = hops
                back[nxt] = (frame, edge, inverted)
                push(heap, (c, hops, next(counter), nxt))
    return {f: (dist[f], hop[f]) for f in dist}, back


def _steps_from_root(back, frame: str) -> list[PathStep]:
    steps: list[PathStep] = []
    while frame in back:
        frame, edge, inverted = back[frame]
        steps.append(PathStep(edge, inverted))
    return steps[::-1]


def shortest_path(
    graph: SpatialRelationshipGraph,
    source: str,
    target: str,
    step_cost: StepCost = _hop,
    *,
    banned: Iterable[str] = (),
    need_sensor: bool = False,
    candidates: int = 64,
) -> Path | None:
    """The path of least summed ``step_cost`` (Dijkstra; costs must be >= 0).

    Ties are broken by fewer steps, then by the order edges were added. ``banned`` edge names
    are not used. ``need_sensor``: the path must contain at least one measured edge; it is the
    cheapest simple path ``source ~> u -> v ~> target`` through one measured edge ``u -> v``
    (two Dijkstra trees, from ``source`` and from ``target``; the ``candidates`` cheapest
    measured edges are tried in order until the joined path is simple).

    Returns
    -------
    Path or None
        ``None`` when no such path exists (or none was found among the candidates).
    """
    banned = set(banned)
    step_cost = _memo(step_cost)
    if not need_sensor:
        best, back = _tree(graph, source, step_cost, banned, stop=target)
        if target not in best:
            return None
        return Path(tuple(_steps_from_root(back, target)))
    return next(via_edge_paths(graph, source, target, step_cost, banned, True, candidates), None)


def via_edge_paths(
    graph: SpatialRelationshipGraph,
    source: str,
    target: str,
    step_cost: StepCost = _hop,
    banned: Iterable[str] = (),
    measured_only: bool = False,
    candidates: int = 64,
):
    """Distinct simple paths ``source ~> u -> v ~> target``, cheapest first, where ``u -> v``
    runs over the edges (only measured ones with ``measured_only``) and ``~>`` are shortest
    paths: two Dijkstra trees (from ``source`` and from ``target``) and one pass over the
    edges. The ``candidates`` cheapest joins are tried; joins that revisit a frame are
    skipped. A cheap, diverse set of good paths for scoring with a non-additive function."""
    banned = set(banned)
    step_cost = _memo(step_cost)
    d_s, back_s = _tree(graph, source, step_cost, banned)
    if target not in d_s:
        return
    d_t, back_t = _tree(graph, target, step_cost, banned)
    options = []
    for order, edge in enumerate(graph.edges):
        if (measured_only and edge.kind != "measured") or edge.name in banned:
            continue
        for inverted in (False, True):
            u, v = (edge.target, edge.source) if inverted else (edge.source, edge.target)
            if u in d_s and v in d_t:
                c = d_s[u][0] + step_cost(edge, inverted) + d_t[v][0]
                options.append((c, d_s[u][1] + d_t[v][1] + 1, order, inverted, edge))
    options.sort(key=lambda o: o[:4])
    seen: set[tuple] = set()
    for _, _, _, inverted, edge in options[:candidates]:
        head = _steps_from_root(back_s, edge.target if inverted else edge.source)
        tail = [
            PathStep(s.edge, not s.inverted)
            for s in _steps_from_root(back_t, edge.source if inverted else edge.target)[::-1]
        ]
        path = Path((*head, PathStep(edge, inverted), *tail))
        key = tuple((st.edge.name, st.inverted) for st in path.steps)
        if key in seen or len(set(path.frames)) != len(path.frames):
            continue
        seen.add(key)
        yield path


def _memo(step_cost: StepCost) -> StepCost:
    """``step_cost`` computed once per (edge, direction) across the searches of one query,
    and checked to be >= 0."""
    if getattr(step_cost, "_memo", False):
        return step_cost
    cache: dict[tuple[int, bool], float] = {}

    def cost(edge: Edge, inverted: bool) -> float:
        key = (id(edge), inverted)
        c = cache.get(key)
        if c is None:
            c = float(step_cost(edge, inverted))
            if not c >= 0.0:
                raise InputError(f"step cost of edge {edge.name!r} must be >= 0, got {c}")
            cache[key] = c
        return c

    cost._memo = True
    return cost


def _rank(paths: list[Path], evaluate) -> list[Path]:
    return sorted(paths, key=lambda p: (evaluate(p), len(p), str(p)))


def _greedy_disjoint(scored: list[Path]) -> list[Path]:
    """Best first, every path sharing no sensor with an already chosen one (thesis 6.4)."""
    chosen: list[Path] = []
    used: set[str] = set()
    for p in scored:
        if p.sensors & used:
            continue
        if not p.sensors and chosen:
            continue  # a purely static path adds no independent information twice
        chosen.append(p)
        used |= p.sensors
    return chosen


def best_paths(
    graph: SpatialRelationshipGraph,
    source: str,
    target: str,
    evaluate,
    *,
    exclude: Iterable[str] = (),
    fuse: bool = False,
    budget: int = DEFAULT_BUDGET,
) -> list[Path]:
    """The path(s) answering a query, best first (strategies in the module docstring).

    Parameters
    ----------
    evaluate : callable
        ``evaluate(path) -> float``, lower is better. An optional attribute
        ``step_cost(edge, inverted) -> float`` gives an additive per-step cost; with
        ``additive = True`` it is the evaluation itself (summed), otherwise a proxy.
    exclude : iterable of str
        Edge names never used.
    fuse : bool
        Also return every further path sharing no sensor with a better one.
    budget : int
        Search steps of the exhaustive listing before switching to the scalable search
        (graphs of more than ``EXHAUSTIVE_MAX_EDGES`` edges go straight to it unless the
        budget is at least a million).

    Raises
    ------
    ValueError
        Unknown frames, ``source == target``, or no path (the message says whether excluded
        edges are the reason).
    """
    graph.check_frame(source)
    graph.check_frame(target)
    if source == target:
        raise PlanError(f"query from frame {source!r} to itself: the relationship is identity")
    banned = set(exclude)
    paths = None
    if len(graph.edges) <= EXHAUSTIVE_MAX_EDGES or budget >= 10**6:
        try:
            paths = _all_simple_paths(graph, source, target, banned, budget)
        except _BudgetExceeded:
            paths = None
    if paths is not None:
        if not paths:
            _raise_no_path(graph, source, target, banned)
        scored = _rank(paths, evaluate)
        return _greedy_disjoint(scored) if fuse else scored[:1]

    step_cost = _memo(getattr(evaluate, "step_cost", None) or _hop)
    additive = bool(getattr(evaluate, "additive", False))
    first = shortest_path(graph, source, target, step_cost, banned=banned)
    if first is None:
        _raise_no_path(graph, source, target, banned)
    if not additive:
        # pruned search: the true function scores the best paths of its additive proxy
        candidates = [
            first,
            *itertools.islice(
                via_edge_paths(graph, source, target, step_cost, banned), NON_ADDITIVE_CANDIDATES
            ),
        ]
        first = _rank(candidates, evaluate)[0]
    if not fuse:
        return [first]
    chosen = [first]
    used = set(first.sensors)
    while True:
        p = shortest_path(
            graph,
            source,
            target,
            step_cost,
            banned=banned | used,
            need_sensor=True,
        )
        if p is None:
            return chosen
        chosen.append(p)
        used |= p.sensors


def _raise_no_path(graph, source: str, target: str, banned: set[str]):
    if banned and shortest_path(graph, source, target) is not None:
        raise PlanError(
            f"no path from frame {source!r} to frame {target!r} without the excluded edges "
            f"{sorted(banned)}"
        )
    raise PlanError(f"no path from frame {source!r} to frame {target!r} in the graph")
