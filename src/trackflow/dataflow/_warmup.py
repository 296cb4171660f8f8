"""Warm-up before a live run: compile (or load) every kernel its filters will run."""

from __future__ import annotations

import numpy as np

from ..filters import PoseFilterBank
from ..math import Pose, UncertainPose
from ._processing import KalmanFilter

__all__ = ["warm_up"]


def warm_up(net) -> None:
    """Run every Kalman filter kind of ``net`` once on throwaway copies, alone and in a
    filter bank (as a packet of several bodies runs them), so that compiling their kernels
    (numba, first use in a process) happens before any live event is dispatched."""
    seen = set()
    for c in net.components.values():
        if not isinstance(c, KalmanFilter) or (c.motion, c.history_s) in seen:
            continue
        seen.add((c.motion, c.history_s))
        f = c.filter_factory(c.motion, c.history_s)
        u = UncertainPose(Pose(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])), np.eye(6) * 1e-6)
        f.update_pose(0.0, u)
        f.update_pose(0.01, u)
        f.predict(0.02)
        bank = PoseFilterBank([c.filter_factory(c.motion, c.history_s) for _ in range(2)])
        for t in (0.0, 0.01):
            bank.update_poses([0, 1], [t, t], [u, u])
        bank.predict_poses([0, 1], [0.02, 0.02])
        z = [np.stack([a, a]) for a in (u.position, u.quaternion, u.covariance)]
        bank.update_block([0, 1], [0.02, 0.02], *z, defer=True, predict_at=0.025)
        bank.settle()  # a packet with its answers (trackers' LiveSources.deliver_block)
