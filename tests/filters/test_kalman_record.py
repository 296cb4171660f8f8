"""The pose Kalman filter's one-call update (``step_into`` writing the log record) gives
answers bit for bit equal to the per-update composition of kernels it replaced, on a real
recording with gated outliers, resets, position-only updates and out-of-order arrivals."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow import Pose, UncertainPose
from trackflow.filters import MotionModel, PoseKalmanFilter, gating
from trackflow.filters.derivative import kernels as source
from trackflow.filters.derivative import streaming, update_kernels
from trackflow.io import read_stream
from trackflow.math import kernels_for, use_backend

NOISE = (0.0, 30.0, 0.0, 100.0)
C_POSE = np.diag([1e-6] * 3 + [1e-5] * 3)


def _stream(shared_data, n):
    s, _ = read_stream(shared_data / "tumvi" / "dataset-room1_512_16.txt")
    t, p, q = s.times_s[:n], s.position[:n].copy(), s.quaternion[:n]
    p[100::97] += 0.5  # single outliers: gated
    p[600:612] += 2.0  # a burst: gated ten times, then a reset
    return t, p, q


def _reference(f: PoseKalmanFilter, t, p, q, form: str):
    """The old per-update path: predict_into + residual + update from Python, the
    filter's gate/reset rules, then predict_pose 3 ms after each measurement."""
    k = streaming.kernels()
    n_dp, n_do, add, kind, sp, so = f._params
    reset_after = f._policy.reset_after
    x = p_ = None
    run, out, t_prev = 0, [], 0.0
    for i in range(len(t)):
        lp, lo = (0, -1) if i % 13 == 0 else (0, 0)
        pose = Pose(p[i], q[i])  # as the filter gets it (a normalised quaternion)
        zp, zo = pose.position.copy(), pose.quaternion.copy()
        r = C_POSE[:3, :3].copy() if lo < 0 else C_POSE.copy()
        if x is None or gating.reset_due(True, run, reset_after):
            x, p_ = f._x0.copy(), f._p0.copy()
            qq = zo if lo == 0 else x[3 * (n_dp + 1) :][:4]
            rr = k.meas_cov(r, np.ascontiguousarray(qq), lp, lo, add)
            k.initialize(x, p_, n_dp, n_do, add, lp, lo, zp, zo, rr)
            status, run = gating.INITIALIZED, 0
        else:
            ws = k.predict_scratch(n_dp, n_do, add)
            k.predict_into(x, p_, t[i] - t_prev, n_dp, n_do, add, kind, sp, so, ws)
            y, h = kernels_for(update_kernels).residual(x, n_dp, n_do, add, lp, lo, zp, zo)
            rr = k.measurement_cov(r, x, n_dp, lp, lo, add)
            gate = f._gates[3 if lo < 0 else 6]
            status, _ = k.update(x, p_, y, h, rr, gate, n_dp, n_do, add, f._wmax)
            run = gating.next_gated_run(int(status), run)
        t_prev = t[i]
        dt = (t[i] + 0.003) - t[i]  # as the filter computes it
        pos, quat, cov = k.predict_pose(x, p_, dt, n_dp, n_do, add, kind, sp, so)
        out.append((int(status) != gating.GATED, pos, quat, cov))
    return out


def _feed(f: PoseKalmanFilter, t, p, q, order):
    ro = C_POSE.copy()
    ro.flags.writeable = False  # a sensor's nominal noise: read-only, copied once
    out = {}
    for k, i in enumerate(order):
        if i % 13 == 0:
            ok = f.update_position(t[i], p[i], C_POSE[:3, :3])
        else:
            ok = f.update_pose(t[i], UncertainPose(Pose(p[i], q[i]), ro if k % 2 else C_POSE))
        a = f.predict(t[i] + 0.003)
        out[i] = (ok, a.position, a.quaternion, a.covariance)
    return out


@pytest.mark.parametrize("form", ["error_state", "additive"])
def test_one_call_update_equals_the_per_update_kernels(shared_data, form):
    t, p, q = _stream(shared_data, 1500)
    f = PoseKalmanFilter(MotionModel(1, 1, noise=NOISE), formulation=form)
    ref = _reference(f, t, p, q, form)
    got = _feed(f, t, p, q, range(len(t)))
    assert f.stats["resets"] >= 1 and f.stats["rejected_gate"] >= 20
    for i, (ok, pos, quat, cov) in enumerate(ref):
        g = got[i]
        assert g[0] == ok, i
        for a, b in zip(g[1:], (pos, quat, cov)):
            assert a.tobytes() == b.tobytes(), i


def test_out_of_order_arrivals_refilter_to_the_in_order_answers(shared_data):
    t, p, q = _stream(shared_data, 900)
    order = np.arange(len(t))
    for i in range(0, len(order) - 3, 40):  # swap neighbours two apart
        order[i], order[i + 2] = order[i + 2], order[i]
    model = MotionModel(1, 1, noise=NOISE)
    a, b = PoseKalmanFilter(model), PoseKalmanFilter(model)
    _feed(a, t, p, q, order)
    _feed(b, t, p, q, range(len(t)))
    assert a.stats["out_of_order"] > 0
    for tq in np.linspace(t[-1] - 0.9, t[-1] + 0.01, 37):  # smoothed past and predicted
        pa, pb = a.predict(tq), b.predict(tq)
        assert pa.position.tobytes() == pb.position.tobytes()
        assert pa.covariance.tobytes() == pb.covariance.tobytes()
    assert a.nis == b.nis or (np.isnan(a.nis) and np.isnan(b.nis))


def test_record_layout_and_no_record():
    """``step_into`` records x, P, zp, zo and r; with an empty record it is ``step``."""
    model = MotionModel(1, 1, noise=NOISE)
    f = PoseKalmanFilter(model)
    n_dp, n_do, add, kind, sp, so = f._params
    zp, zo = np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.0, 0.0, 1.0])
    with use_backend("numpy"):
        k = streaming.kernels()
        x, p = f._x0.copy(), f._p0.copy()
        k.initialize(x, p, n_dp, n_do, add, 0, 0, zp, zo, C_POSE)
        x2, p2 = x.copy(), p.copy()
        log = np.full(source.log_size(n_dp, n_do, add, 6), np.nan)
        s1 = k.step_into(x, p, 0.01, n_dp, n_do, add, kind, sp, so, 0, 0, zp + 0.001, zo,
                         C_POSE, 20.0, 50.0, log)  # fmt: skip
        s2 = k.step(x2, p2, 0.01, n_dp, n_do, add, kind, sp, so, 0, 0, zp + 0.001, zo,
                    C_POSE, 20.0, 50.0)  # fmt: skip
    assert s1 == s2 and np.array_equal(x, x2) and np.array_equal(p, p2)
    nx, nc = x.size, p.shape[0]
    assert np.array_equal(log[:nx], x)
    assert np.array_equal(log[nx : nx + nc * nc].reshape(nc, nc), p)
    o = nx + nc * nc
    assert np.array_equal(log[o : o + 3], zp + 0.001)
    assert np.array_equal(log[o + 3 : o + 7], zo)
    assert np.array_equal(log[o + 7 :].reshape(6, 6), C_POSE)


def test_snapshot_arrays_survive_out_of_order_refiltering(shared_data):
    """Re-filtering replaces a log record instead of rewriting it, so a state handed out by
    ``snapshot`` keeps its values (``adopt`` replicas hold them)."""
    t, p, q = _stream(shared_data, 60)
    f = PoseKalmanFilter(MotionModel(1, 1, noise=NOISE))
    for i in range(0, 60, 2):
        f.update_pose(t[i], UncertainPose(Pose(p[i], q[i]), C_POSE))
    snap = f.snapshot()
    x, cov = snap.x.copy(), snap.p.copy()
    f.update_pose(t[51], UncertainPose(Pose(p[51], q[51]), C_POSE))  # older than the snapshot
    assert f.stats["out_of_order"] == 1
    assert np.array_equal(snap.x, x) and np.array_equal(snap.p, cov)
    assert not np.array_equal(f.snapshot().x, x)  # the newest state did change
    g = PoseKalmanFilter(MotionModel(1, 1, noise=NOISE))
    assert g.adopt(snap) and np.array_equal(g.snapshot().x, x)
