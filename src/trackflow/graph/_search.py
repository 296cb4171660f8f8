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
  edge covariance's weighted trace, exact for identity poses; one per step otherwise) gives a
  first path; each of its edges in turn is removed to give alternatives; the true function
  scores these candidates and the best wins. This is a heuristic: it finds the optimum
  whenever the proxy orders paths like the true function, and always returns a valid path.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable, Iterable

from ._paths import Path, PathStep
from ._srg import Edge, SpatialRelationshipGraph

__all__ = ["best_paths", "shortest_path", "DEFAULT_BUDGET"]

#: Search steps the exhaustive listing of simple paths may take before the scalable search
#: takes over (a few milliseconds of work).
DEFAULT_BUDGET = 2_000

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
    counter = itertools.count()
    best: dict[str, tuple[float, int]] = {root: (0.0, 0)}
    back: dict[str, tuple[str, Edge, bool]] = {}
    heap = [(0.0, 0, 0, root)]
    done: set[str] = set()
    incident = graph._incident
    while heap:
        cost, hops, _, frame = heapq.heappop(heap)
        if frame in done:
            continue
        done.add(frame)
        if frame == stop:
            break
        for edge, inverted in incident.get(frame, ()):
            if edge.name in banned:
                continue
            nxt = edge.source if inverted else edge.target
            if nxt in done:
                continue
            c = float(step_cost(edge, inverted))
            if not c >= 0.0:
                raise ValueError(f"step cost of edge {edge.name!r} must be >= 0, got {c}")
            new = (cost + c, hops + 1)
            old = best.get(nxt)
            if old is None or new < old:
                best[nxt] = new
                back[nxt] = (frame, edge, inverted)
                heapq.heappush(heap, (new[0], new[1], next(counter), nxt))
    return best, back


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
    if not need_sensor:
        best, back = _tree(graph, source, step_cost, banned, stop=target)
        if target not in best:
            return None
        return Path(tuple(_steps_from_root(back, target)))
    d_s, back_s = _tree(graph, source, step_cost, banned)
    d_t, back_t = _tree(graph, target, step_cost, banned)
    options = []
    for order, edge in enumerate(graph.edges):
        if edge.kind != "measured" or edge.name in banned:
            continue
        for inverted in (False, True):
            u, v = (edge.target, edge.source) if inverted else (edge.source, edge.target)
            if u in d_s and v in d_t:
                c = d_s[u][0] + float(step_cost(edge, inverted)) + d_t[v][0]
                options.append((c, d_s[u][1] + d_t[v][1] + 1, order, inverted, edge))
    options.sort(key=lambda o: o[:4])
    for _, _, _, inverted, edge in options[:candidates]:
        head = _steps_from_root(back_s, edge.target if inverted else edge.source)
        tail = [
            PathStep(s.edge, not s.inverted)
            for s in _steps_from_root(back_t, edge.source if inverted else edge.target)[::-1]
        ]
        steps = [*head, PathStep(edge, inverted), *tail]
        path = Path(tuple(steps))
        if len(set(path.frames)) == len(path.frames):
            return path
    return None


def _memo(step_cost: StepCost) -> StepCost:
    """``step_cost`` computed once per (edge, direction) across the searches of one query."""
    cache: dict[tuple[int, bool], float] = {}

    def cost(edge: Edge, inverted: bool) -> float:
        key = (id(edge), inverted)
        c = cache.get(key)
        if c is None:
            c = cache[key] = float(step_cost(edge, inverted))
        return c

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
        Search steps of the exhaustive listing before switching to the scalable search.

    Raises
    ------
    ValueError
        Unknown frames, ``source == target``, or no path (the message says whether excluded
        edges are the reason).
    """
    graph.check_frame(source)
    graph.check_frame(target)
    if source == target:
        raise ValueError(f"query from frame {source!r} to itself: the relationship is identity")
    banned = set(exclude)
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
        candidates = [first]
        for step in first.steps:
            alt = shortest_path(graph, source, target, step_cost, banned=banned | {step.edge.name})
            if alt is not None:
                candidates.append(alt)
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
        raise ValueError(
            f"no path from frame {source!r} to frame {target!r} without the excluded edges "
            f"{sorted(banned)}"
        )
    raise ValueError(f"no path from frame {source!r} to frame {target!r} in the graph")
