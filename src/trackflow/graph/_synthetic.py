"""Synthetic spatial relationship graphs for scaling tests and benchmarks."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..math import Pose
from ._srg import SpatialRelationshipGraph

__all__ = ["random_graph"]


def random_graph(
    n_frames: int, n_edges: int, rng: np.random.Generator, static_fraction: float = 0.3
) -> SpatialRelationshipGraph:
    """A connected random SRG: a random spanning tree plus random extra edges.

    Frames are ``F0 .. F<n-1>``; edges ``e0 ..`` are measured (latency 1-50 ms, rate 30-240 Hz,
    position sigma 0.1-5 mm, orientation sigma 0.01-1 deg) or, with probability
    ``static_fraction``, static with a random pose. Several edges may join one frame pair.

    Parameters
    ----------
    n_frames, n_edges : int
        ``n_edges >= n_frames - 1`` (the spanning tree).
    rng : numpy.random.Generator
    """
    if n_frames < 2 or n_edges < n_frames - 1:
        raise InputError("need n_frames >= 2 and n_edges >= n_frames - 1")
    g = SpatialRelationshipGraph()
    order = rng.permutation(n_frames)
    pairs = [(int(order[rng.integers(0, i)]), int(order[i])) for i in range(1, n_frames)]
    while len(pairs) < n_edges:
        a, b = rng.choice(n_frames, size=2, replace=False)
        pairs.append((int(a), int(b)))
    for k, (a, b) in enumerate(pairs):
        if rng.random() < 0.5:
            a, b = b, a
        sp = rng.uniform(0.1, 5.0) * 1e-3
        so = np.radians(rng.uniform(0.01, 1.0))
        cov = np.diag([sp**2] * 3 + [so**2] * 3)
        if rng.random() < static_fraction:
            pose = Pose(rng.normal(size=3), rng.normal(size=4), normalize=True)
            g.add_static(f"e{k}", f"F{a}", f"F{b}", pose, cov)
        else:
            g.add_measured(
                f"e{k}",
                f"F{a}",
                f"F{b}",
                latency_s=rng.uniform(0.001, 0.05),
                rate_hz=rng.uniform(30.0, 240.0),
                covariance=cov,
            )
    return g
