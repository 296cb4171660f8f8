"""KalmanBank: a packet's measurements pushed (and answers pulled) in one call leave every
component exactly as pushing and pulling them one by one does: the same answers to the last
bit, statistics, rejections by reason, first/last times and origins, and the same events seen
by the consumers of a filter that pushes on (kept in order around the batched ones)."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow import Pose, UncertainPose
from trackflow.dataflow import (
    CallbackSink,
    Inference,
    KalmanBank,
    KalmanFilter,
    Measurement,
    Network,
)
from trackflow.graph import MotionSpec
from trackflow.math import quat_exp, use_backend

MOTION = MotionSpec(static=False, n_dp=1, n_do=1, noise=(0.0, 30.0, 0.0, 100.0))
C = np.diag([1e-6] * 3 + [1e-5] * 3)
N = 7


def _network():
    """kf0-kf3 keep their state; kf4 pushes on into an inference that pulls kf1 (so the
    order around it matters); kf5 has a prior; kf6 corrects a stamp offset."""
    net = Network()
    kfs = []
    for i in range(N):
        kw = {}
        if i == 5:
            kw["prior"] = UncertainPose(Pose(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])), C)
        if i == 6:
            kw["stamp_offset_ns"] = 2_000_000
        kfs.append(net.add(KalmanFilter(f"kf{i}", MOTION, **kw)))
    inf = net.add(Inference("chain"))
    out = []
    sink = net.add(CallbackSink("app", out.append))
    net.connect(kfs[1], inf, "pull")
    net.connect(kfs[4], inf, "push")
    net.connect(inf, sink, "push")
    return net, kfs, out


def _packets(n, rng):
    out = []
    for k in range(n):
        t = 1_000_000_000 + k * 4_166_667
        rows = []
        for i in range(N):
            if (k + i) % 11 == 0:
                continue  # occluded
            p = np.array([0.1 * i + 0.2 * np.sin(k * 0.02), 0.3, 0.5]) + rng.normal(0, 1e-3, 3)
            if k % 23 == 9 and i == 2:
                p = p + 1.0  # an outlier: gated
            q = quat_exp(np.array([0.1, 0.2 + 0.003 * k, 0.3 * i]))
            rows.append((i, Measurement(t, UncertainPose._trusted(p, q, C), t - 3_000_000)))
        if k % 17 == 4:  # a late measurement of kf3
            rows.append((3, Measurement(t - 9_000_000, rows[0][1].pose, t - 12_000_000)))
        rng.shuffle(rows)
        out.append(rows)
    return out


def _log(c):
    """A component's filter log: time, status, NIS, gate run and record of every entry."""
    return [(e.t, e.status, repr(e.nis), e.gated_run, e.buf.tobytes()) for e in c.filter._log]


def _answer(m):
    if m is None:
        return None
    return (m.t_ns, m.origin_ns, m.pose.position.tobytes(), m.pose.quaternion.tobytes(),
            m.pose.covariance.tobytes())  # fmt: skip


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_bank_push_and_pull_equal_one_by_one(backend):
    with use_backend(backend):
        packets = _packets(120 if backend == "numba" else 50, np.random.default_rng(5))
        net_a, kf_a, out_a = _network()
        net_b, kf_b, out_b = _network()
        bank = KalmanBank(kf_b)
        for rows in packets:
            for i, m in rows:
                kf_a[i].push(m)
            bank.push(rows)
            t = rows[0][1].t_ns
            # ahead, just behind, before the first data, far ahead (stale)
            asks = [(i, t + dt) for i in range(N) for dt in (1_000_000, -2_000_000)]
            asks += [(0, 900_000_000), (2, t + 10**10)]
            want = [kf_a[i].pull(tq) for i, tq in asks]
            got = bank.pull(asks)
            assert [_answer(m) for m in got] == [_answer(m) for m in want]
        assert net_a.stats() == net_b.stats()
        for a, b in zip(kf_a, kf_b):
            assert (a.first_t, a.last_t, a.last_origin) == (b.first_t, b.last_t, b.last_origin)
        assert [_answer(m) for m in out_a] == [_answer(m) for m in out_b] and out_a
        stats = net_b.stats()
        assert stats["kf2"]["rejections"].get("filter rejected update", 0) > 0
        assert stats["kf0"]["rejections"].get("before first measurement", 0) > 0
        assert stats["kf2"]["rejections"].get("stale", 0) > 0


def test_bank_rebuilds_after_a_network_reset():
    net, kfs, _ = _network()
    bank = KalmanBank(kfs[:2])
    rows = _packets(3, np.random.default_rng(1))
    for r in rows:
        bank.push([(i, m) for i, m in r if i < 2])
    net.reset()  # new filters inside the components
    assert kfs[0].last_t is None
    for r in rows:
        bank.push([(i, m) for i, m in r if i < 2])
    assert kfs[0].stats.events_in == sum(1 for r in rows for i, _ in r if i == 0)
    assert bank.pull([(0, rows[-1][0][1].t_ns)])[0] is not None


@pytest.mark.parametrize("answer", [False, True])
@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_bank_block_push_and_pull_equal_one_by_one(backend, answer):
    """push_block/pull_block (a packet's poses as arrays, one time) leave every component as
    pushing and pulling one by one does; a packet with a component that pushes on or has a
    prior takes the per-measurement path, in order. With ``answer``, push_block hands the
    packet's answers 1 ms ahead to a callback before the filters' logs are written: the same
    answers, and the same logs and statistics once it returns."""
    with use_backend(backend):
        rng = np.random.default_rng(7)
        net_a, kf_a, out_a = _network()
        net_b, kf_b, out_b = _network()
        bank = KalmanBank(kf_b)
        answered = 0
        for k in range(100 if backend == "numba" else 40):
            t = 1_000_000_000 + k * 4_166_667
            index = [i for i in range(N) if (k + i) % 11]
            if k % 3:
                index = [i for i in index if i < 4]  # plain components only: the arrays
            m = len(index)
            pos = np.array([[0.1 * i + 0.2 * np.sin(k * 0.02), 0.3, 0.5] for i in index])
            pos += rng.normal(0, 1e-3, pos.shape)
            if k % 23 == 9:
                pos[0] += 1.0  # an outlier: gated
            quat = quat_exp(np.array([[0.1, 0.2 + 0.003 * k, 0.3 * i] for i in index]))
            cov = np.stack([C] * m)
            for j, i in enumerate(index):
                kf_a[i].push(Measurement(t, UncertainPose._trusted(pos[j], quat[j], cov[j]), t))
            if answer:
                delivered = []
                bank.push_block(index, t, pos, quat, cov, (t + 1_000_000, delivered.append))
                (early,) = delivered
                for j, i in enumerate(index):
                    w = kf_a[i].pull(t + 1_000_000)
                    assert early.ok[j] == (w is not None)
                    if w is not None:
                        assert early.position[j].tobytes() == w.pose.position.tobytes()
                        assert early.covariance[j].tobytes() == w.pose.covariance.tobytes()
                        answered += 1
                for i in index:  # the logs written after the callback, as one by one
                    assert _log(kf_b[i]) == _log(kf_a[i])
            else:
                bank.push_block(index, t, pos, quat, cov)
            asks = [(i, t + dt) for i in range(N) for dt in (1_000_000, -2_000_000)]
            asks += [(0, 900_000_000), (2, t + 10**10)]
            want = [kf_a[i].pull(tq) for i, tq in asks]
            got = bank.pull_block([a[0] for a in asks], [a[1] for a in asks])
            for j, w in enumerate(want):
                assert got.ok[j] == (w is not None)
                if w is not None:
                    assert np.array_equal(got.position[j], w.pose.position)
                    assert np.array_equal(got.quaternion[j], w.pose.quaternion)
                    assert np.array_equal(got.covariance[j], w.pose.covariance)
        assert net_a.stats() == net_b.stats()
        for a, b in zip(kf_a, kf_b):
            assert (a.first_t, a.last_t, a.last_origin) == (b.first_t, b.last_t, b.last_origin)
        assert [_answer(m) for m in out_a] == [_answer(m) for m in out_b] and out_a
        assert net_b.stats()["kf0"]["rejections"].get("filter rejected update", 0) > 0
        assert (answered > 0) == answer


class _Labelled(KalmanFilter):
    """A subclass keeping KalmanFilter's push and pull: batched."""

    kind = "labelled kalman"


class _Counting(KalmanFilter):
    """A subclass with a push of its own: pushed through it, never batched."""

    def push(self, m, port: int = 0) -> None:
        self.pushed = getattr(self, "pushed", 0) + 1
        super().push(m, port)


def test_subclasses_are_batched_by_capability_not_by_type():
    """``bankable`` follows the class's push and pull: a subclass keeping them is batched
    (its filter is run by the bank's kernel) with a plain component's results and counts;
    one with its own push has it called for every measurement."""
    from trackflow.dataflow import InertialKalmanFilter
    from trackflow.distributed.replica import RemoteFilter, RemoteGet

    assert KalmanFilter.bankable and _Labelled.bankable
    assert not any(c.bankable for c in (_Counting, InertialKalmanFilter, RemoteFilter, RemoteGet))
    classes = (KalmanFilter, _Labelled, _Counting)
    plain, lab, cnt = (cls(f"kf{i}", MOTION) for i, cls in enumerate(classes))
    bank = KalmanBank([lab, cnt])
    q = quat_exp(np.array([0.1, 0.2, 0.3]))
    for k in range(6):
        t = 1_000_000_000 + k * 4_166_667
        pos = np.array([[0.01 * k, 0.3, 0.5]] * 2)
        plain.push(Measurement(t, UncertainPose._trusted(pos[0], q, C), t))
        bank.push_block([0, 1], t, pos, np.stack([q, q]), np.stack([C, C]))
    assert lab.filter._x.base is not None  # a view of the bank's row: the kernel ran it
    assert cnt.pushed == 6
    for c in (lab, cnt):
        assert _log(c) == _log(plain)
        assert c.stats.events_in == plain.stats.events_in == 6
        assert c.stats.events_out == plain.stats.events_out
        assert (c.first_t, c.last_t, c.last_origin) == (
            plain.first_t,
            plain.last_t,
            plain.last_origin,
        )
