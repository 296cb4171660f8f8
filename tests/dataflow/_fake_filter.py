"""A test double with the ``trackflow.filters.PoseKalmanFilter`` interface (update/predict).

It interpolates between buffered measurements and extrapolates linearly from the last two,
gating jumps larger than 5 cm from the prediction. Used only where a test must not depend on
the real filter's tuning (for example bit-identity and scheduler tests).
"""

from __future__ import annotations

import numpy as np

from trackflow import Pose, UncertainPose


class InterpolatingFilter:
    def __init__(self, motion, history_s: float = 1.0):
        self.static = motion.static
        self.history = history_s
        self.t: list[float] = []
        self.poses: list[UncertainPose] = []
        self.stats = {"updates": 0, "rejected": 0}
        self.misses = 0

    def update_pose(self, t: float, z: UncertainPose) -> bool:
        if self.t and t <= self.t[-1]:
            self.stats["rejected"] += 1
            return False
        if len(self.t) >= 2 and not self.static and self.misses < 2:
            guess = self.poses[-1]  # gate against the last accepted measurement
            if np.linalg.norm(guess.position - z.position) > 0.05:
                self.stats["rejected"] += 1
                self.misses += 1
                return False
        self.misses = 0
        self.t.append(t)
        self.poses.append(z)
        while self.t[0] < t - self.history and len(self.t) > 2:
            self.t.pop(0)
            self.poses.pop(0)
        self.stats["updates"] += 1
        return True

    def predict(self, t: float) -> UncertainPose:
        if not self.t:
            raise ValueError("no measurement yet")
        if self.static:
            stack = Pose(
                np.array([p.position for p in self.poses]),
                np.array([p.quaternion for p in self.poses]),
                normalize=True,
            )
            if len(self.poses) < 2:
                return self.poses[0]
            mean = UncertainPose.from_samples(stack)
            return UncertainPose(mean.pose, mean.covariance / len(self.poses))
        if len(self.t) == 1:
            return self.poses[0]
        i = int(np.searchsorted(self.t, t)) - 1
        i = min(max(i, 0), len(self.t) - 2)
        t0, t1 = self.t[i], self.t[i + 1]
        s = (t - t0) / (t1 - t0)
        a, b = self.poses[i], self.poses[i + 1]
        pose = a.pose.interpolate(b.pose, s)
        return UncertainPose(pose, b.covariance)


def factory(motion, history_s):
    return InterpolatingFilter(motion, history_s)
