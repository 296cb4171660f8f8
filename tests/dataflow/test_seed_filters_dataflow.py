"""The seed papers' filters as dataflow filters (``trackflow.filters.relative_motion`` /
``quaternion_space`` streaming adapters and ``factory``, issue 6).

Each adapter is plugged into a planned network through ``filter_factory`` (the synthetic
tracker + camera world of ``_scenario``), run, and compared with the default pose Kalman filter
on the same sensors: finite outputs with PSD covariances, accuracy and NEES in the default's
range, and the protocol's rejections counted.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
from _scenario import T_A_M, graph, sensors

from trackflow import Pose, UncertainPose
from trackflow.dataflow import KalmanFilter, Network, PullSink, RecordingPlayer, plan_query
from trackflow.filters import (
    QuaternionSpacePoseFilter,
    RelativeMotionPoseFilter,
    constant_velocity_densities,
    quaternion_space_factory,
    relative_motion_factory,
)
from trackflow.filters.quaternion_space.streaming import _PoseTerm
from trackflow.graph import MotionSpec, Query
from trackflow.math import quat_conjugate, quat_exp, quat_log, quat_multiply

FACTORIES = {
    "relative_motion": relative_motion_factory(),
    "quaternion_space": quaternion_space_factory(),
}
ADAPTERS = {
    "relative_motion": RelativeMotionPoseFilter,
    "quaternion_space": QuaternionSpacePoseFilter,
}
OFFSETS = {"predict": 0.0, "interpolate": -0.1}  # query time offsets: future / past requests


@pytest.fixture(autouse=True)
def _quiet_filter_resets():
    logging.getLogger("trackflow.filters").setLevel(logging.ERROR)


def run_query(factory, offset_s: float):
    q = Query("A", "M", mode="push", rate_hz=60, time_offset_s=offset_s)
    net, rec = plan_query(graph(), q).build(sensors(end_s=3.0), filter_factory=factory)
    net.run()
    return net, rec


def metrics(rec, t_min_s: float = 0.5) -> dict:
    """RMS position [m] / angle [rad] errors and mean NEES of the query output vs the truth."""
    ev = [m for m in rec.events if m.t_ns >= int(t_min_s * 1e9)]
    dp, da, nees = [], [], []
    for m in ev:
        e = np.concatenate(
            [
                T_A_M.position - m.pose.position,
                quat_log(quat_multiply(quat_conjugate(m.pose.quaternion), T_A_M.quaternion)),
            ]
        )  # t_true = t + dt, R_true = R Exp(dtheta)
        dp.append(np.linalg.norm(e[:3]))
        da.append(np.linalg.norm(e[3:]))
        nees.append(e @ np.linalg.solve(m.pose.covariance, e))
    return {
        "n": len(ev),
        "pos": float(np.sqrt(np.mean(np.square(dp)))),
        "ang": float(np.sqrt(np.mean(np.square(da)))),
        "nees": float(np.mean(nees)),
    }


@pytest.fixture(scope="module")
def runs():
    out = {}
    for mode, off in OFFSETS.items():
        out["default", mode] = run_query(None, off)
        for name, fac in FACTORIES.items():
            out[name, mode] = run_query(fac, off)
    return out


@pytest.mark.parametrize("mode", OFFSETS)
@pytest.mark.parametrize("name", FACTORIES)
def test_seed_filter_in_a_planned_network(runs, name, mode):
    net, rec = runs[name, mode]
    _, rec_default = runs["default", mode]
    # the network really runs the adapter behind both sensors
    for kf in ("kf_art", "kf_cam"):
        assert isinstance(net.components[kf].filter, ADAPTERS[name])
        assert net.components[kf].filter.stats["updates"] > 50
    assert len(rec.events) >= 0.95 * len(rec_default.events) > 100
    for m in rec.events:
        assert isinstance(m.pose, UncertainPose)
        assert np.all(np.isfinite(m.pose.position)) and np.all(np.isfinite(m.pose.covariance))
        c = m.pose.covariance
        assert np.allclose(c, c.T, atol=1e-15)
        assert np.linalg.eigvalsh(c)[0] > 0
    got, ref = metrics(rec), metrics(rec_default)
    # Same sensors, same constant-velocity noise densities: accuracy in the default's range.
    assert got["pos"] < 2.0 * ref["pos"], (got, ref)
    assert got["ang"] < 2.0 * ref["ang"], (got, ref)
    # Covariances as consistent as the default's (the outputs are correlated, so compare the
    # mean NEES with the default filter's, not with a chi-square band).
    assert ref["nees"] / 3 < got["nees"] < 3 * ref["nees"], (got, ref)


def test_the_adapters_beat_the_naive_chain(runs):
    """Time alignment matters more than the filter: every adapter beats the latest-value chain
    when interpolating 100 ms in the past (noise-free-ish world isolates simultaneity)."""
    q = Query("A", "M", mode="push", rate_hz=60, time_offset_s=-0.1)
    net, naive = plan_query(graph(), q, align=False).build(sensors(end_s=3.0))
    net.run()
    e_naive = metrics(naive)["pos"]
    for name in FACTORIES:
        assert metrics(runs[name, "interpolate"][1])["pos"] < e_naive


COV = np.diag([1e-6] * 3 + [1e-5] * 3)


def moving(t: float) -> UncertainPose:
    """A body moving at 0.5 m/s along x, turning at 1 rad/s about z."""
    return UncertainPose(Pose([0.5 * t, 0.1, 1.0], quat_exp(np.array([0.0, 0.0, t]))), COV)


@pytest.mark.parametrize("name", FACTORIES)
def test_protocol_rejections_are_counted(name):
    f = FACTORIES[name](MotionSpec(n_dp=1, n_do=1, noise=(1.0, 3.0)), 0.5)
    assert not f.initialized and f.time is None
    with pytest.raises(ValueError, match="no measurement yet"):
        f.predict(0.0)
    for k in range(30):
        assert f.update_pose(0.01 * k, moving(0.01 * k))
    assert f.initialized and f.time == pytest.approx(0.29)
    # NaN cannot be constructed through the checked API; it can only come from upstream maths
    bad = UncertainPose._trusted(np.array([np.nan, 0, 0]), np.array([0, 0, 0, 1.0]), COV)
    assert not f.update_pose(0.30, bad)  # NaN position
    assert not f.update_pose(np.nan, moving(0.30))  # NaN time
    assert not f.update_pose(0.20, moving(0.20))  # time going backwards
    far = UncertainPose(Pose(moving(0.30).position + [0.5, 0, 0], moving(0.30).quaternion), COV)
    assert not f.update_pose(0.30, far)  # an outlier 0.5 m off: the gate
    assert f.update_pose(0.31, moving(0.31))
    s = f.stats
    assert s["updates"] == 31
    assert s["rejected_invalid"] == 2
    assert s["rejected_old"] == 1
    assert s["rejected_gate"] == 1
    assert s["resets"] == 0
    with pytest.raises(ValueError, match="single UncertainPose"):
        f.update_pose(0.4, moving(0.4).pose)
    with pytest.raises(ValueError, match="older than the stored history"):
        f.predict(0.31 - 0.6)
    with pytest.raises(ValueError, match="finite"):
        f.predict(np.inf)
    # future and past answers follow the motion
    for t in (0.15, 0.255, 0.31, 0.36):
        p = f.predict(t)
        truth = moving(t)
        assert np.linalg.norm(p.position - truth.position) < 5e-3
        assert (
            np.linalg.norm(quat_log(quat_multiply(quat_conjugate(p.quaternion), truth.quaternion)))
            < 0.02
        )
    # a lost filter restarts after reset_after (10) consecutive gated measurements
    for k in range(11):
        t = 0.4 + 0.01 * k
        z = UncertainPose(Pose(moving(t).position + [2.0, 0, 0], moving(t).quaternion), COV)
        f.update_pose(t, z)
    assert f.stats["rejected_gate"] == 11 and f.stats["resets"] == 1
    assert np.linalg.norm(f.predict(0.5).position - (moving(0.5).position + [2.0, 0, 0])) < 1e-3


@pytest.mark.parametrize("name", FACTORIES)
def test_rejections_reach_the_dataflow_counters(name):
    """A player with an outlier and a repeated stamp: the component counts what the filter
    refused, and the filter's own stats say why."""
    t = np.arange(40) * 10_000_000
    truth = [moving(k * 0.01) for k in range(40)]
    pos = np.array([z.position for z in truth])
    quat = np.array([z.quaternion for z in truth])
    pos[25] += [0.3, 0.0, 0.0]  # outlier
    net = Network()
    p = net.add(RecordingPlayer("p", t, pos, quat, COV))
    kf = net.add(KalmanFilter("kf", MotionSpec(), filter_factory=FACTORIES[name]))
    sink = net.add(PullSink("app"))
    net.connect(p, kf)
    net.connect(kf, sink)
    net.run()
    assert kf.stats.rejections == {"filter rejected update": 1}
    assert kf.filter.stats["rejected_gate"] == 1
    assert kf.filter.stats["updates"] == 39
    m = sink.get(int(0.2 * 1e9))
    assert m is not None and np.linalg.norm(m.pose.position - moving(0.2).position) < 5e-3


def test_static_motion_falls_back_to_the_default_filter():
    from trackflow.filters import PoseKalmanFilter

    for fac in FACTORIES.values():
        assert isinstance(fac(MotionSpec.make_static(), 1.0), PoseKalmanFilter)


def test_noise_mapping_from_motion_specs():
    assert constant_velocity_densities(MotionSpec(noise=2.0)) == (4.0, 4.0)
    assert constant_velocity_densities(MotionSpec(noise=(1.0, 3.0))) == (1.0, 9.0)
    assert constant_velocity_densities(MotionSpec(noise=(0.0, 2.0, 0.0, 5.0))) == (4.0, 25.0)
    with pytest.raises(ValueError, match="constant-velocity"):
        constant_velocity_densities(MotionSpec(n_dp=0, n_do=1, noise=(1.0, 2.0, 3.0)))


def test_pose_term_jacobian_matches_finite_differences(rng):
    z = UncertainPose(Pose(rng.normal(size=3), quat_exp(rng.normal(size=3))), COV)
    term = _PoseTerm(z)
    p = z.position + rng.normal(scale=0.1, size=3)
    q = quat_multiply(quat_exp(rng.normal(scale=0.4, size=3)), z.quaternion)
    r0, J = term.residual(p, q)
    eps = 1e-6
    J_fd = np.zeros((6, 6))
    for i in range(6):
        d = np.zeros(6)
        d[i] = eps
        r1, _ = term.residual(p + d[:3], quat_multiply(quat_exp(d[3:]), q))  # p + dp, Exp(dphi) q
        J_fd[:, i] = (r1 - r0) / eps
    assert np.allclose(J, J_fd, atol=1e-5)


def test_pose_term_adjustment_is_the_kalman_update():
    """With a pose measurement the Gauss-Newton adjustment of eq. 24 is exact: its covariance
    (eq. 30) equals the linear Kalman (Joseph form) update of the prediction's covariance."""
    f = QuaternionSpacePoseFilter(1.0, 9.0, gate_probability=None)
    for k in range(5):
        f.update_pose(0.01 * k, moving(0.01 * k))
    pred = f.filter.predict(f.state, 0.05)
    z = moving(0.05)
    f.update_pose(0.05, z)
    R = _PoseTerm.world_covariance(z)
    P = pred.covariance
    H = np.hstack([np.eye(6), np.zeros((6, 6))])
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    I_KH = np.eye(12) - K @ H
    P_post = I_KH @ P @ I_KH.T + K @ R @ K.T
    sd = np.sqrt(np.diag(P_post))
    assert np.allclose(f.state.covariance / np.outer(sd, sd), P_post / np.outer(sd, sd), atol=1e-3)
