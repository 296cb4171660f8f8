"""Spatial relationship graph: path search, evaluation functions, motion inference, queries."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow import Pose, UncertainPose
from trackflow.graph import (
    Edge,
    MotionSpec,
    Query,
    SpatialRelationshipGraph,
    covariance_trace,
    find_paths,
    infer_motion,
    latency_rate,
    select_paths,
)

COV = np.diag([1e-6] * 3 + [1e-4] * 3)


def demo_like() -> SpatialRelationshipGraph:
    g = SpatialRelationshipGraph()
    g.add_static("projector", "P", "A", Pose.identity(), COV)
    g.add_measured("art", "A", "T", latency_s=0.02, rate_hz=60, covariance=COV)
    g.add_static("mount", "T", "C", Pose.identity(), COV)
    g.add_measured("cam", "C", "M", latency_s=0.05, rate_hz=30, covariance=4 * COV)
    return g


def test_path_walks_edges_backwards():
    g = demo_like()
    (p,) = find_paths(g, "M", "P")
    assert p.frames == ("M", "C", "T", "A", "P")
    assert all(s.inverted for s in p.steps)
    (q,) = find_paths(g, "P", "M")
    assert not any(s.inverted for s in q.steps)
    assert p.sensors == q.sensors == {"art", "cam"}


def test_cycles_terminate_and_paths_are_simple():
    g = SpatialRelationshipGraph()
    for name, a, b in [("ab", "A", "B"), ("bc", "B", "C"), ("ca", "C", "A"), ("cd", "C", "D")]:
        g.add_measured(name, a, b, rate_hz=10)
    paths = find_paths(g, "A", "D")
    # A->B->C->D and A<-C(ca inverted)->D: exactly two simple paths.
    assert sorted(str(p) for p in paths) == sorted(
        ["A->B[ab] . B->C[bc] . C->D[cd]", "C<-A[ca] . C->D[cd]"]
    )
    for p in paths:
        assert len(set(p.frames)) == len(p.frames)


@pytest.mark.parametrize(
    ("src", "dst", "match"),
    [("P", "X", "unknown frame 'X'"), ("P", "P", "to itself"), ("P", "Z", "no path")],
)
def test_bad_queries_raise(src, dst, match):
    g = demo_like()
    g.add_frame("Z")
    with pytest.raises(ValueError, match=match):
        find_paths(g, src, dst)


def test_latency_rate_is_eq_2_5():
    g = demo_like()
    (p,) = find_paths(g, "P", "M")
    lam = 0.5
    expected = (0.02 + lam / 60) + (0.05 + lam / 30)  # static edges add nothing
    assert latency_rate(lam)(p) == pytest.approx(expected, rel=1e-12)


def test_covariance_trace_is_eq_6_26():
    # At identity poses every compose/inverse Jacobian is +-I, so covariances simply add.
    g = demo_like()
    (p,) = find_paths(g, "M", "P")
    total = COV + COV + COV + 4 * COV
    assert covariance_trace()(p) == pytest.approx(np.sqrt(np.trace(total)), rel=1e-9)
    A = np.hstack([np.eye(3), np.zeros((3, 3))])  # position only
    assert covariance_trace(A)(p) == pytest.approx(np.sqrt(np.trace(total[:3, :3])), rel=1e-9)


def test_covariance_trace_uses_lever_arms():
    # A rotation error on a 1 m lever arm becomes position error: the propagated trace grows.
    g = SpatialRelationshipGraph()
    rot_only = np.diag([0, 0, 0, 1e-4, 1e-4, 1e-4])
    g.add_static("s1", "A", "B", Pose.identity(), rot_only)
    g.add_static("s2", "B", "C", Pose([1.0, 0, 0], [0, 0, 0, 1]), np.zeros((6, 6)))
    (p,) = find_paths(g, "A", "C")
    A = np.hstack([np.eye(3), np.zeros((3, 3))])
    # dt = -R [t_b]x dtheta: y and z pick up 1e-4 each.
    assert covariance_trace(A)(p) == pytest.approx(np.sqrt(2e-4), rel=1e-9)


def test_evaluation_function_chooses_the_path():
    g = SpatialRelationshipGraph()
    g.add_measured("fast_noisy", "A", "B", latency_s=0.001, rate_hz=200, covariance=100 * COV)
    g.add_measured("slow_precise", "A", "B", latency_s=0.1, rate_hz=10, covariance=COV)
    fast = select_paths(g, Query("A", "B", evaluation="latency"))
    precise = select_paths(g, Query("A", "B", evaluation="covariance"))
    assert fast[0].sensors == {"fast_noisy"}
    assert precise[0].sensors == {"slow_precise"}
    custom = select_paths(g, Query("A", "B", evaluation=lambda p: -p.steps[0].edge.latency_s))
    assert custom[0].sensors == {"slow_precise"}
    both = select_paths(g, Query("A", "B", fuse=True))
    assert [p.sensors for p in both] == [{"fast_noisy"}, {"slow_precise"}]


def test_fuse_takes_only_sensor_disjoint_paths():
    g = demo_like()
    g.add_measured("cam2", "A", "M", latency_s=0.03, rate_hz=30, covariance=COV)
    g.add_measured("art_again", "A", "T", latency_s=0.02, rate_hz=60, covariance=COV)
    paths = select_paths(g, Query("P", "M", fuse=True))
    sensors = [p.sensors for p in paths]
    for i in range(len(sensors)):
        for j in range(i):
            assert not sensors[i] & sensors[j]
    assert {"cam2"} in sensors


def test_motion_inference():
    g = SpatialRelationshipGraph()
    g.add_static("s1", "A", "B", Pose.identity())
    g.add_static("s2", "B", "C", Pose.identity())
    g.add_measured("m", "C", "D", motion=MotionSpec(n_dp=2, n_do=1, noise=0.5))
    g.add_measured("n", "D", "E", motion=MotionSpec(n_dp=1, n_do=2, noise=1.5))
    (static_path,) = find_paths(g, "A", "C")
    assert infer_motion(static_path).static
    (p,) = find_paths(g, "A", "E")
    m = infer_motion(p)
    assert (m.static, m.n_dp, m.n_do, m.noise) == (False, 2, 2, 2.0)


def test_edge_validation():
    with pytest.raises(ValueError, match="itself"):
        Edge("A", "A", "loop")
    with pytest.raises(ValueError, match="rate_hz"):
        Edge("A", "B", "x", rate_hz=0)
    with pytest.raises(ValueError, match="needs a pose"):
        Edge("A", "B", "x", kind="static")
    with pytest.raises(ValueError, match="NaN"):
        Edge("A", "B", "x", covariance=np.full((6, 6), np.nan))
    g = demo_like()
    with pytest.raises(ValueError, match="duplicate"):
        g.add_measured("art", "A", "B")
    with pytest.raises(ValueError, match="push delivery needs"):
        Query("A", "B", mode="push")
    with pytest.raises(ValueError, match="unknown evaluation"):
        Query("A", "B", evaluation="cheapest")


def test_path_value_chains_static_edges(rng):
    g = SpatialRelationshipGraph()
    a = Pose(rng.normal(size=3), rng.normal(size=4), normalize=True)
    b = Pose(rng.normal(size=3), rng.normal(size=4), normalize=True)
    g.add_static("a", "X", "Y", a, COV)
    g.add_static("b", "Z", "Y", b, COV)
    (p,) = find_paths(g, "X", "Z")
    expected = UncertainPose(a, COV) @ UncertainPose(b, COV).inverse()
    v = p.value()
    assert np.allclose(v.position, expected.position)
    assert np.allclose(v.covariance, expected.covariance)
