"""The filter bank (:class:`PoseFilterBank`) gives every filter the answers, log records, gate
decisions and resets it gives on its own, to the last bit, on both backends: on a real
recording replayed as several bodies, with outliers (gated, then a reset after a burst),
bodies missing from packets (occluded), out-of-order arrivals, two measurements of one filter
in one call, past-time queries, and filters the kernels do not run (another formulation,
another noise, a position-only model, another filter class) mixed in; with the poses given
as objects (``update_poses``/``predict_poses``) or as arrays (``update_block``/
``predict_block``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from trackflow import Pose, UncertainPose
from trackflow.filters import (
    FilterStatus,
    MotionModel,
    PoseKalmanFilter,
    RelativeMotionPoseFilter,
)
from trackflow.filters.derivative.bank import PoseFilterBank
from trackflow.io import read_stream
from trackflow.math import use_backend

NOISE = (0.0, 30.0, 0.0, 100.0)
C_POSE = np.diag([1e-6] * 3 + [1e-5] * 3)
BODIES = 6


def _filters():
    """Bodies 0-2 one kind, 3 another noise, 4 the additive formulation, 5 another class;
    a position-only model as a seventh."""
    m = MotionModel(1, 1, noise=NOISE)
    return [
        PoseKalmanFilter(m),
        PoseKalmanFilter(m),
        PoseKalmanFilter(m),
        PoseKalmanFilter(MotionModel(1, 1, noise=(0.0, 10.0, 0.0, 50.0))),
        PoseKalmanFilter(m, formulation="additive"),
        RelativeMotionPoseFilter(900.0, 1e4),
        PoseKalmanFilter(MotionModel(1, -1, noise=(0.0, 30.0))),
    ]


def _packets(shared_data, n):
    """Per packet: ``[(body, t, UncertainPose)]``; a packet's order and content vary."""
    s, _ = read_stream(shared_data / "tumvi" / "dataset-room1_512_16.txt")
    t, p, q = s.times_s[:n], s.position[:n].copy(), s.quaternion[:n]
    p[20::37] += 0.5  # single outliers: gated
    p[40:53] += 2.0  # a burst: gated ten times, then a reset
    ro = C_POSE.copy()
    ro.flags.writeable = False  # a sensor's nominal noise: shared and read-only
    rng = np.random.default_rng(3)
    out = []
    for i in range(n):
        rows = []
        for b in range(BODIES + 1):
            if (i + b) % 17 == 0:
                continue  # occluded in this packet
            pose = UncertainPose._trusted(p[i] + 0.1 * b, q[i], ro if b % 2 else C_POSE.copy())
            rows.append((b, float(t[i]), pose))
        if i % 29 == 5 and i > 10:  # a late measurement of body 1 (out of order)
            rows.append(
                (1, float(t[i - 3]) + 1e-4, UncertainPose(Pose(p[i - 3], q[i - 3]), C_POSE))
            )
        if i % 41 == 7:  # body 2 twice in one packet
            rows.append((2, float(t[i]) + 2e-4, UncertainPose(Pose(p[i], q[i]), C_POSE)))
        if i == 60:  # a non-finite time: refused (False), as update_pose raises
            rows.append((0, math.nan, UncertainPose(Pose(p[i], q[i]), C_POSE)))
        order = rng.permutation(len(rows))
        out.append([rows[k] for k in order])
    return out


def _same(a, b):
    if a is None or b is None:
        return a is None and b is None
    return (
        np.array_equal(a.position, b.position)
        and np.array_equal(a.quaternion, b.quaternion)
        and np.array_equal(a.covariance, b.covariance)
    )


def _log(f):
    if not isinstance(f, PoseKalmanFilter):
        return None
    return [
        (e.t, e.status, np.float64(e.nis).tobytes(), e.gated_run, e.buf.tobytes()) for e in f._log
    ]


def _update(bank, api, rows):
    index, times, poses = [r[0] for r in rows], [r[1] for r in rows], [r[2] for r in rows]
    if api == "objects":
        return bank.update_poses(index, times, poses)
    return bank.update_block(
        index, times, np.stack([u.position for u in poses]),
        np.stack([u.quaternion for u in poses]), np.stack([u.covariance for u in poses]),
        defer=api == "deferred",
    )  # fmt: skip


def _poses(res):
    assert all(np.isnan(res.position[k]).all() for k, ok in enumerate(res.ok) if not ok)
    return [
        UncertainPose._trusted(p, q, c) if ok else None
        for ok, p, q, c in zip(res.ok, res.position, res.quaternion, res.covariance)
    ]


def _predict(bank, api, queries):
    index, times = [q[0] for q in queries], [q[1] for q in queries]
    if api == "objects":
        return bank.predict_poses(index, times)
    if api == "arrays":
        return _poses(bank.predict_block(index, times))
    out = [None] * len(queries)  # deferred: ahead while the logs wait, then the past
    for ahead in (True, False):
        ks = [k for k, q in enumerate(queries) if q[2] == ahead]
        res = bank.predict_block([index[k] for k in ks], [times[k] for k in ks])
        for k, pose in zip(ks, _poses(res)):
            out[k] = pose
    return out


@pytest.mark.parametrize("api", ["objects", "arrays", "deferred"])
@pytest.mark.parametrize("backend", ["numba", pytest.param("numpy", marks=pytest.mark.slow)])
def test_bank_equals_separate_filters_to_the_last_bit(shared_data, backend, api):
    """The bank's answers, logs and states equal separate filters' to the bit, through the
    object API, the array API, and the array API with the logs deferred (answers ahead
    before they are written; a past answer or the next update writes them)."""
    with use_backend(backend):
        packets = _packets(shared_data, 220 if backend == "numba" else 90)
        alone, banked = _filters(), _filters()
        bank = PoseFilterBank(banked)
        assert bank.kinds == 3  # (0-2), 3 and 4; 5 and 6 through their own methods
        statuses = set()
        deferred = 0  # updates whose logs waited
        for n, rows in enumerate(packets):
            ok_alone = []
            for b, t, pose in rows:
                try:
                    ok_alone.append(alone[b].update_pose(t, pose))
                except ValueError:
                    ok_alone.append(False)
            assert _update(bank, api, rows) == ok_alone, n
            deferred += bool(bank._unlogged)
            # answers 3 ms ahead and 20 ms back (smoothed), and before any data
            queries = [
                (b, rows[0][1] + dt, dt > 0) for b in range(len(alone)) for dt in (3e-3, -2e-2)
            ]
            got = _predict(bank, api, queries)
            for (b, t, _), g in zip(queries, got):
                try:
                    want = alone[b].predict(t)
                except ValueError:
                    want = None
                assert _same(g, want), (n, b, t)
            for fa in alone:
                if isinstance(fa, PoseKalmanFilter):
                    statuses.update(e.status for e in fa._log)
        for fa, fb in zip(alone, banked):
            assert fa.stats == fb.stats
            assert _log(fa) == _log(fb)
            if isinstance(fa, PoseKalmanFilter):
                xa, pa = fa.state
                xb, pb = fb.state
                assert np.array_equal(xa, xb) and np.array_equal(pa, pb)
        # the scenario reached every decision the bank has to report
        assert {FilterStatus.ACCEPTED, FilterStatus.GATED, FilterStatus.RESET} <= statuses
        assert banked[0].stats["rejected_gate"] > 0 and banked[0].stats["resets"] >= 1
        assert banked[1].stats["out_of_order"] > 0
        assert (deferred > 0) == (api == "deferred")
        # and the bank ran them: the kernels' filters hold rows of its arrays
        assert all(banked[b]._x.base is not None for b in (0, 3, 4))


def test_a_filter_reset_outside_the_bank_is_taken_back(shared_data):
    f = PoseKalmanFilter(MotionModel(1, 1, noise=NOISE))
    g = PoseKalmanFilter(MotionModel(1, 1, noise=NOISE))
    bank = PoseFilterBank([f])
    u = UncertainPose(Pose(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])), C_POSE)
    for k in range(5):
        assert bank.update_poses([0], [0.01 * k], [u]) == [g.update_pose(0.01 * k, u)]
    f.reset()  # new state arrays, not the bank's rows
    g.reset()
    for k in range(5):
        assert bank.update_poses([0], [0.01 * k], [u]) == [g.update_pose(0.01 * k, u)]
        assert _same(bank.predict_poses([0], [0.01 * k + 0.002])[0], g.predict(0.01 * k + 0.002))
    assert np.array_equal(f.state[1], g.state[1])


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_a_step_that_diverges_in_a_packet_layout_is_the_filters_own(backend):
    """Filters updated together packet after packet (a lane: looked up once): a step the
    kernel finds diverged (an innovation covariance that is not positive definite) is
    handled for every filter of the call as their own updates handle it, the next packets
    go on from there, and the answers ahead, logs and states stay equal to the bit."""
    with use_backend(backend):
        _diverge_in_a_lane()


def _diverge_in_a_lane():
    m = MotionModel(1, 1, noise=NOISE)
    alone = [PoseKalmanFilter(m) for _ in range(3)]
    bank = PoseFilterBank([PoseKalmanFilter(m) for _ in range(3)])
    q = np.array([0.0, 0.0, 0.6, 0.8])
    statuses = []
    for k in range(12):
        t = 0.01 * k
        pos = np.array([[0.1 * b + 0.01 * k, 0.0, 0.0] for b in range(3)])
        cov = np.stack([C_POSE] * 3)
        if k == 6:
            cov[1] = -np.eye(6)  # trusted as given: the step diverges
        ok_alone = []
        for b, f in enumerate(alone):
            try:
                ok_alone.append(f.update_pose(t, UncertainPose._trusted(pos[b], q, cov[b])))
            except ValueError:
                ok_alone.append(False)
        ok, ahead = bank.update_block(
            [0, 1, 2], [t] * 3, pos, np.stack([q] * 3), cov, defer=True, predict_at=t + 3e-3
        )
        assert ok == ok_alone, k
        for b, f in enumerate(alone):
            if ahead.ok[b]:
                want = f.predict(t + 3e-3)
                assert ahead.position[b].tobytes() == want.position.tobytes(), (k, b)
                assert ahead.covariance[b].tobytes() == want.covariance.tobytes(), (k, b)
        bank.settle()
        statuses.append([e.status for e in bank.filters[1]._log][-1:])
    assert (0, 1, 2) in bank._lanes  # the lane was taken
    assert statuses[6] == [FilterStatus.DIVERGED] and statuses[-1] == [FilterStatus.ACCEPTED]
    for fa, fb in zip(alone, bank.filters):
        assert fa.stats == fb.stats
        assert _log(fa) == _log(fb)
        xa, pa = fa.state
        xb, pb = fb.state
        assert xa.tobytes() == xb.tobytes() and pa.tobytes() == pb.tobytes()


def test_layouts_are_made_once_each_and_bounded():
    """A layout's value (``None`` too) is made on its first call only; past ``limit``
    layouts the collection starts afresh."""
    from trackflow.filters import Layouts

    made = []

    def make(key):
        made.append(key)
        return None if key == (9,) else sum(key)

    lay = Layouts(make, limit=3)
    assert [lay((1, 2)), lay((9,)), lay((1, 2)), lay((9,))] == [3, None, 3, None]
    assert made == [(1, 2), (9,)] and (9,) in lay
    lay((4,))
    assert lay((5,)) == 5 and made[-1] == (5,) and (1, 2) not in lay  # the fourth: afresh
    assert lay((1, 2)) == 3 and made[-1] == (1, 2)


class _Labelled(PoseKalmanFilter):
    """A subclass that keeps the filter's update: banked like its base class."""


class _Unbatched(PoseKalmanFilter):
    """A subclass that does more in its update: it says so, and the bank calls it."""

    calls = 0

    @property
    def batchable(self) -> bool:
        return False

    def update_pose(self, t, measurement):
        type(self).calls += 1
        return super().update_pose(t, measurement)


def test_subclasses_are_banked_by_capability_not_by_type():
    """A subclass of the filter runs in the bank's kernel (its state is a row of the bank)
    with the plain filter's results to the bit; one that is not ``batchable`` takes its own
    ``update_pose`` for every measurement."""
    m = MotionModel(1, 1, noise=NOISE)
    alone = PoseKalmanFilter(m)
    filters = [_Labelled(m), _Unbatched(m)]
    bank = PoseFilterBank(filters)
    assert bank.kinds == 1
    q = np.array([0.0, 0.0, 0.6, 0.8])
    for k in range(8):
        t = 0.01 * k
        u = UncertainPose._trusted(np.array([0.01 * k, 0.0, 0.0]), q, C_POSE)
        want = alone.update_pose(t, u)
        assert bank.update_poses([0, 1], [t, t], [u, u]) == [want, want]
    assert filters[0]._x.base is not None  # a view of the bank's row: the kernel ran it
    assert _Unbatched.calls == 8
    for f in filters:
        assert _log(f) == _log(alone) and f.stats == alone.stats


def test_step_api_refuses_what_update_pose_does_otherwise():
    """``step_time`` gives a step only where ``update_pose`` is one plain kernel step: not
    before the first measurement, not for an older time or a non-finite one, not with a
    reset due, and not on arrays the filter does not hold."""
    m = MotionModel(1, 1, noise=NOISE)
    f = PoseKalmanFilter(m, reset_after=2)
    u = UncertainPose(Pose(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])), C_POSE)
    assert f.step_time(0.0) is None
    f.update_pose(0.0, u)
    assert f.step_time(0.01) == 0.01
    assert f.step_time(-0.01) is None and f.step_time(math.nan) is None
    assert f.step_time(math.inf) is None
    x, p = np.empty(f.kernel_settings.x0.shape), np.empty(f.kernel_settings.p0.shape)
    assert f.step_time(0.01, x, p) is None
    f.bind_state(x, p)
    assert f.holds_state(x, p) and f.step_time(0.01, x, p) == 0.01
    assert np.array_equal(f.state[0], x)
    far = UncertainPose(Pose(np.full(3, 5.0), np.array([0.0, 0.0, 0.0, 1.0])), C_POSE)
    assert not f.update_pose(0.01, far) and not f.update_pose(0.02, far)  # gated twice
    assert f.step_time(0.03) is None  # the next one resets the filter
