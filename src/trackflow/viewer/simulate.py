"""Simulated sensors for the measured edges of a setup that name no recording.

Each measured edge ``T_source_target`` gets a smooth, bounded ground-truth motion (the target
circling 0.3 m from the source with a slow rotation wobble, phases differing per edge) sampled
by a :class:`trackflow.dataflow.SimulatedSensor` with the edge's rate, latency, timestamp
offset, confidence (as the outlier rate) and covariance (its diagonal). Edges with a
``recording`` play that recording instead (:meth:`trackflow.dataflow.Setup.players`).
"""

from __future__ import annotations

import numpy as np

from ..dataflow import RecordingPlayer, Setup, SimulatedSensor
from ..math import Pose, quat_exp

__all__ = ["edge_motion", "setup_sources"]


def edge_motion(index: int):
    """Ground truth ``truth(t_s (N,)) -> Pose (N,)`` of the ``index``-th simulated edge."""
    phase = 1.3 * index
    w = 2 * np.pi * np.array([0.21, 0.33, 0.17]) * (1.0 + 0.1 * index)

    def truth(t: np.ndarray) -> Pose:
        t = np.asarray(t, float)
        pos = np.stack(
            [
                0.5 + 0.15 * np.cos(w[0] * t + phase),
                0.15 * np.sin(w[1] * t + phase),
                0.3 + 0.05 * np.sin(w[2] * t),
            ],
            axis=-1,
        )
        rotvec = np.stack(
            [0.3 * np.sin(w[2] * t + phase), 0.2 * np.sin(w[0] * t), 0.5 * np.sin(w[1] * t)],
            axis=-1,
        )
        return Pose(pos, quat_exp(rotvec))

    return truth


def setup_sources(setup: Setup, duration_s: float, seed: int = 0) -> dict[str, RecordingPlayer]:
    """One player per measured edge: its recording, or a simulated sensor of ``duration_s``."""
    out: dict[str, RecordingPlayer] = dict(setup.players())
    rng = np.random.default_rng(seed)
    k = 0
    for edge in setup.graph.edges:
        if edge.kind == "static" or edge.name in out:
            continue
        var = np.clip(np.diag(edge.covariance), 0.0, None)
        out[edge.name] = SimulatedSensor(
            edge.name,
            edge_motion(k),
            rate_hz=float(edge.rate_hz),
            latency_s=max(float(edge.latency_s), float(edge.stamp_offset_s), 0.0),
            sigma_pos=float(np.sqrt(var[:3].mean())),
            sigma_ori=np.sqrt(var[3:]),
            rng=rng,
            start_s=0.0,
            end_s=float(duration_s),
            stamp_offset_s=float(edge.stamp_offset_s),
            outlier_rate=float(np.clip(1.0 - edge.confidence, 0.0, 1.0)),
        )
        k += 1
    return out
