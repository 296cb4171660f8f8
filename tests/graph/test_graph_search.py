"""The scalable path search: exact where the evaluation is additive, valid everywhere."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from trackflow.graph import (
    Query,
    SpatialRelationshipGraph,
    best_paths,
    covariance_trace,
    latency_rate,
    random_graph,
    select_paths,
    shortest_path,
)


def _check_path(graph, path, source, target, banned=()):
    assert path.source == source and path.target == target
    assert len(set(path.frames)) == len(path.frames)
    for a, b in zip(path.steps, path.steps[1:]):
        assert a.end == b.start
    assert not {s.edge.name for s in path.steps} & set(banned)
    for s in path.steps:
        assert graph.edge(s.edge.name) is s.edge


def _scipy_latency(graph, source, target, lam=1.0) -> float:
    """Reference shortest latency-rate cost with scipy's Dijkstra on the undirected graph."""
    idx = {f: i for i, f in enumerate(graph.frames)}
    n = len(idx)
    w = np.full((n, n), np.inf)
    for e in graph.edges:
        c = e.latency_s + lam / e.rate_hz
        i, j = idx[e.source], idx[e.target]
        w[i, j] = w[j, i] = min(w[i, j], c)
    # zero costs (static edges) must stay edges in a sparse matrix: shift by a tiny epsilon
    eps = 1e-15
    m = csr_matrix(np.where(np.isfinite(w), w + eps, 0.0))
    d = dijkstra(m, directed=False, indices=idx[source])
    return float(d[idx[target]])


@pytest.mark.parametrize("seed", range(8))
def test_dijkstra_matches_exhaustive_search_on_small_graphs(seed):
    rng = np.random.default_rng(seed)
    g = random_graph(9, 16, rng)
    ev = latency_rate(0.5)
    exhaustive = best_paths(g, "F0", "F8", ev, budget=10**7)
    fast = best_paths(g, "F0", "F8", ev, budget=0)
    assert ev(fast[0]) == pytest.approx(ev(exhaustive[0]), rel=1e-12, abs=1e-15)
    _check_path(g, fast[0], "F0", "F8")


@pytest.mark.parametrize("seed", range(4))
def test_fused_paths_share_no_sensor_and_excluded_edges_stay_out(seed):
    rng = np.random.default_rng(100 + seed)
    g = random_graph(40, 120, rng)
    excluded = ("e3", "e7")
    paths = best_paths(g, "F1", "F30", latency_rate(), exclude=excluded, fuse=True, budget=0)
    used: set[str] = set()
    for k, p in enumerate(paths):
        _check_path(g, p, "F1", "F30", excluded)
        assert not p.sensors & used
        if k:
            assert p.sensors
        used |= p.sensors
    assert len(paths) >= 2


def test_large_graph_best_path_is_optimal():
    g = random_graph(1000, 3000, np.random.default_rng(7))
    q = Query("F0", "F999", evaluation="latency")
    (p,) = select_paths(g, q)
    _check_path(g, p, "F0", "F999")
    assert q.evaluate(p) == pytest.approx(_scipy_latency(g, "F0", "F999"), rel=1e-9)


def test_non_additive_evaluation_scores_candidates_exactly():
    g = random_graph(300, 900, np.random.default_rng(3))
    ev = covariance_trace()
    (p,) = best_paths(g, "F5", "F250", ev, budget=0)
    _check_path(g, p, "F5", "F250")
    proxy_best = shortest_path(g, "F5", "F250", ev.step_cost)
    assert ev(p) <= ev(proxy_best)
    # a callable without any step cost is searched by hops, then scored
    (h,) = best_paths(g, "F5", "F250", lambda path: float(len(path)), budget=0)
    assert len(h) == len(shortest_path(g, "F5", "F250"))


def test_need_sensor_skips_purely_static_paths():
    from trackflow import Pose

    g = SpatialRelationshipGraph()
    g.add_static("s", "A", "B", Pose.identity())
    g.add_measured("m1", "A", "C", rate_hz=10)
    g.add_measured("m2", "C", "B", rate_hz=10)
    assert shortest_path(g, "A", "B").sensors == frozenset()
    assert shortest_path(g, "A", "B", need_sensor=True).sensors == {"m1", "m2"}
    fused = best_paths(g, "A", "B", latency_rate(), fuse=True, budget=0)
    assert [p.sensors for p in fused] == [frozenset(), {"m1", "m2"}]


def test_no_path_reasons():
    from trackflow import Pose

    g = SpatialRelationshipGraph()
    g.add_static("s", "A", "B", Pose.identity())
    g.add_frame("Z")
    for budget in (0, 10**6):
        with pytest.raises(ValueError, match="without the excluded edges"):
            best_paths(g, "A", "B", latency_rate(), exclude=["s"], budget=budget)
        with pytest.raises(ValueError, match="no path from frame 'A' to frame 'Z'"):
            best_paths(g, "A", "Z", latency_rate(), budget=budget)
