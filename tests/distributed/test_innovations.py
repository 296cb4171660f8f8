"""A remote sensor's advertised covariance checked against its measured innovations: real
Kalman filter states through the wire into a replica, the truth drawn from the filter's own
motion model (seeded Monte Carlo), judged by the statistic's chi-square mean and the
consumer's NEES."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.distributed import RemoteFilter, decode_state
from trackflow.distributed.innovations import (
    WINDOW,
    InnovationCheck,
    correction_statistic,
    threshold,
)
from trackflow.distributed.wire import encode_state
from trackflow.filters import MotionModel, PoseKalmanFilter
from trackflow.filters.derivative.streaming import FilterSnapshot, kernels
from trackflow.filters.factory import make_filter
from trackflow.graph import MotionSpec
from trackflow.math import Pose, UncertainPose, quat_exp, quat_multiply

MOTION = MotionSpec(False, 1, 1, (0.1, 0.1))  # white acceleration 0.1 m/s^2/sqrt(s), rad too
RATE_HZ = 100
SIGMA = (1e-3, np.radians(0.2))  # the sensor's true noise: 1 mm, 0.2 deg
R = np.diag([SIGMA[0] ** 2] * 3 + [SIGMA[1] ** 2] * 3)
POSE = [0, 1, 2, 6, 7, 8]  # the pose block of the constant-velocity error state
T0_NS = 1_700_000_000_000_000_000


class _Sensor:
    """A sensor's filter (no gate: the liar's measurements would all be gated) on a truth
    drawn from the filter's own motion model, its states through the wire to a replica."""

    def __init__(self, seed: int):
        self.rng = np.random.default_rng(seed)
        self.model = make_filter(MOTION, 1.0).model
        self.kf = PoseKalmanFilter(self.model, gate_probability=None)
        self.rep = RemoteFilter("kf_s", MOTION)
        self.x = self.model.initial_state()
        self.x[2] = 1.0
        self.k = 0

    def step(self, lie: float = 1.0) -> tuple[float, float]:
        """One measurement (noise ``R``, advertised ``R / lie``) through the sensor's filter
        and the wire; returns the NEES of the state as sent and of the replica's answer."""
        m, dt = self.model, 1.0 / RATE_HZ
        if self.k:
            self.x, _ = m.transition(self.x, dt)
            noise = self.rng.multivariate_normal(np.zeros(12), m.process_noise(dt, self.x))
            self.x = m.retract(self.x, noise)
        stamp = T0_NS + self.k * 10_000_000
        p = self.x[:3] + self.rng.normal(0.0, SIGMA[0], 3)
        q = quat_multiply(self.x[6:10], quat_exp(self.rng.normal(0.0, SIGMA[1], 3)))
        self.kf.update_pose(stamp * 1e-9, UncertainPose(Pose(p, q), R / lie))
        snap = self.kf.snapshot()
        buf = encode_state(
            snap, seq=self.k + 1, stamp_ns=stamp, host_ns=stamp, origin_ns=stamp, n_dp=1, n_do=1
        )
        assert self.rep.adopt(decode_state(buf))
        self.k += 1
        e = m.local(self.x, snap.x)[POSE]
        sent = float(e @ np.linalg.solve(snap.p[np.ix_(POSE, POSE)], e))
        ans = self.rep.filter.predict(stamp * 1e-9)  # the consumer's answer at the stamp
        dp = self.x[:3] - ans.position
        dth = m.local(self.x, _with_pose(snap.x, ans))[6:9]
        e = np.concatenate([dp, dth])
        return sent, float(e @ np.linalg.solve(ans.covariance, e))


def _with_pose(x, pose: UncertainPose) -> np.ndarray:
    y = np.array(x, dtype=float)
    y[:3], y[6:10] = pose.position, pose.quaternion
    return y


def test_threshold_is_the_quantile_or_the_floor():
    assert threshold(6) > 6.0  # one state: chi2(6) at 1e-9 is 53.3
    assert threshold(6 * WINDOW) == 2.0  # a full window: the floor (the quantile is 1.7)


def test_an_honest_filter_is_never_scaled():
    s = _Sensor(11)
    nees, windows = [], []
    for k in range(10 * WINDOW):
        nees.append(s.step()[1])
        assert s.rep.innovations.scale == 1.0
        if (k + 1) % WINDOW == 0 and k > 0:
            windows.append(s.rep.innovations.mean_ratio)  # disjoint windows
    stat = np.mean(windows[1:])  # sum of chi2(6) over 9 * 32 states: sd of the mean 0.034
    assert abs(stat - 1.0) < 4 * np.sqrt(2 / (6 * 9 * WINDOW)), stat
    assert abs(np.mean(nees[WINDOW:]) / 6 - 1) < 0.25  # the answers are consistent
    c = s.rep.innovations.counts
    assert c["scaled"] == c["above"] == c["degenerate"] == 0
    assert "covariance below its innovations" not in s.rep.stats.rejections


def test_a_liar_is_scaled_to_its_innovations_and_answers_consistently():
    s = _Sensor(12)
    flagged_at, sent, answers, scales = None, [], [], []
    for k in range(12 * WINDOW):
        n_sent, n_ans = s.step(lie=100.0)
        if flagged_at is None and s.rep.innovations.scale > 1.0:
            flagged_at = k
        if k >= 2 * WINDOW:
            sent.append(n_sent)
            answers.append(n_ans)
            scales.append(s.rep.innovations.scale)
    assert flagged_at is not None and flagged_at <= 3  # the second or third state
    # the innovation ratio is the lie where the measurement noise dominates the
    # innovations, less by the prediction's part of them (docs/distributed.md)
    assert 50 < np.median(scales) < 110, np.median(scales)
    assert np.mean(sent) > 50 * 6  # as sent: the NEES of a covariance 100x too small
    assert abs(np.mean(answers) / 6 - 1) < 0.5, np.mean(answers)  # scaled: consistent
    assert s.rep.stats.rejections["covariance below its innovations"] >= 12 * WINDOW - 3


def test_a_sensor_honest_again_is_unscaled():
    s = _Sensor(13)
    for _ in range(4 * WINDOW):
        s.step(lie=100.0)
    assert s.rep.innovations.scale > 10
    back = None
    for k in range(6 * WINDOW):
        s.step()
        if back is None and s.rep.innovations.scale == 1.0:
            back = k
        if back is not None:
            assert s.rep.innovations.scale == 1.0, k  # and stays unscaled
    assert back is not None and back <= 2 * WINDOW, back


def _snap(t, x, p, start=False):
    return FilterSnapshot(t, np.asarray(x, dtype=float), np.asarray(p, dtype=float), start)


def test_degenerate_and_garbage_states_are_counted_never_a_crash():
    model = make_filter(MOTION, 1.0).model
    check = InnovationCheck(model)
    x0 = model.initial_state()
    p0 = np.eye(12) * 1e-4
    check.check(_snap(0.0, x0, p0))
    x_pred, p_pred = kernels().predict(x0, p0, 0.01, *check.params)
    # a gated measurement: the predicted state itself, nothing learned, nothing counted
    assert check.check(_snap(0.01, x_pred, p_pred)) == 1.0
    assert check.counts == {"checked": 0, "scaled": 0, "above": 0, "degenerate": 0}
    # moved without learning anything: degenerate
    x_pred, p_pred = kernels().predict(x_pred, p_pred, 0.01, *check.params)
    moved = x_pred.copy()
    moved[0] += 0.1
    check.check(_snap(0.02, moved, p_pred))
    assert check.counts["degenerate"] == 1
    # a covariance above its prediction: counted, no verdict
    x_pred, p_pred = kernels().predict(moved, p_pred, 0.01, *check.params)
    check.check(_snap(0.03, x_pred, p_pred * 2))
    assert check.counts["above"] == 1 and check.scale == 1.0
    # garbage: random SPD covariances and states, older states, resets
    rng = np.random.default_rng(3)
    t = 0.03
    for _ in range(200):
        a = rng.normal(size=(12, 12)) * 10.0 ** rng.uniform(-6, 3)
        x = model.initial_state()
        x[:6] = rng.normal(size=6) * 10.0 ** rng.uniform(-3, 3)
        t += rng.choice([0.0, 0.01, -0.02, 5.0])
        scale = check.check(_snap(t, x, a @ a.T + 1e-12 * np.eye(12), rng.random() < 0.1))
        assert np.isfinite(scale) and 1.0 <= scale <= 1e4
    stat, dof, above = correction_statistic(np.ones(6), np.full((6, 6), np.nan), np.eye(6))
    assert np.isnan(stat) and dof == 0


@pytest.mark.parametrize(
    "n_dp, n_do, formulation, pose",
    [
        (0, 0, "error_state", [0, 1, 2, 3, 4, 5]),
        (-1, 1, "error_state", [0, 1, 2]),
        (2, -1, "error_state", [0, 1, 2]),
        (1, 1, "additive", [0, 1, 2, 6, 7, 8, 9]),  # the quaternion's 4 components (rank 3)
    ],
)
def test_other_models_are_judged_on_their_pose_block(n_dp, n_do, formulation, pose):
    model = MotionModel(n_dp, n_do)
    kf = PoseKalmanFilter(model, gate_probability=None, formulation=formulation)
    check = InnovationCheck(model, formulation)
    assert check._pose.tolist() == pose
    rng = np.random.default_rng(4)
    for k in range(2 * WINDOW):  # a resting body measured with its true noise
        p = np.array([0.0, 0.0, 1.0]) + rng.normal(0.0, SIGMA[0], 3)
        q = quat_exp(rng.normal(0.0, SIGMA[1], 3))
        kf.update_pose(k * 0.01, UncertainPose(Pose(p, q), R))
        assert check.check(kf.snapshot()) == 1.0
    assert check._dof == WINDOW * (3 * (n_dp >= 0) + 3 * (n_do >= 0))


def test_the_agent_counts_the_reason_and_shows_the_scale():
    from types import SimpleNamespace

    from trackflow.distributed.remote_inputs import RemoteInputs
    from trackflow.distributed.wire import Rejections

    s = _Sensor(14)
    agent = SimpleNamespace(cfg=SimpleNamespace(reorder_ms=0.0), rejections=Rejections())
    inputs = RemoteInputs(agent, None, None, {}, {"s": s.rep})
    s.rep = RemoteFilter("kf_s", MOTION)  # the sensor's own replica: a bystander here
    replica = inputs.filters["s"]
    for k in range(WINDOW):
        s.step(lie=100.0)
        snap = s.kf.snapshot()
        stamp = T0_NS + k * 10_000_000
        buf = encode_state(
            snap, seq=k + 1, stamp_ns=stamp, host_ns=stamp, origin_ns=stamp, n_dp=1, n_do=1
        )
        inputs.deliver("s", decode_state(buf), 0, 0.0)
    counted = agent.rejections.counts["covariance below its innovations"]
    assert counted == replica.stats.rejections["covariance below its innovations"] >= WINDOW - 3
    shown = inputs.status()["replicas"]["s"]["innovations"]
    assert shown["scale"] == replica.innovations.scale > 10 and shown["scaled"] == counted
