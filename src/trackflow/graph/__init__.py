"""Spatial relationship graphs: frames, measured and static edges, paths and queries.

An edge ``a -> b`` is the relationship ``T_a_b`` (maps frame b into a); see
``docs/conventions.md``. Paths may walk edges backwards (inversion). Evaluation functions
follow the thesis: eq. 2.5 (latency and update rate) and eq. 6.26 (propagated covariance).
"""

from ._evaluation import EvaluationFunction, covariance_trace, latency_rate, resolve_evaluation
from ._paths import Path, PathStep, find_paths, infer_motion
from ._query import Query, select_paths
from ._requirements import Requirements
from ._search import best_paths, shortest_path
from ._srg import Edge, MotionSpec, SpatialRelationshipGraph
from ._synthetic import random_graph

__all__ = [
    "Edge",
    "EvaluationFunction",
    "MotionSpec",
    "Path",
    "PathStep",
    "Query",
    "Requirements",
    "SpatialRelationshipGraph",
    "best_paths",
    "covariance_trace",
    "find_paths",
    "infer_motion",
    "latency_rate",
    "random_graph",
    "resolve_evaluation",
    "select_paths",
    "shortest_path",
]
