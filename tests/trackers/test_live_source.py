"""LiveSource.deliver: plainly valid samples are taken without copies, anything else goes
through the full checks, and bad samples are counted rejections with a reason."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.dataflow import Measurement
from trackflow.math import Pose, UncertainPose
from trackflow.trackers.inputs import Sample
from trackflow.trackers.runtime import LiveSource

COV = np.diag([1e-6] * 3 + [1e-4] * 3)


class _Sink:
    def __init__(self):
        self.got: list[Measurement] = []

    def push(self, m, port=0):
        self.got.append(m)


def _source():
    src, sink = LiveSource("s"), _Sink()
    src.consumers.append((sink, 0))
    return src, sink


def _sample(t, p=(1.0, 2.0, 3.0), q=(0.0, 0.0, 0.6, 0.8), c=COV):
    return Sample(t, t + 5, np.array(p, dtype=float), np.array(q, dtype=float), c)


def test_plain_samples_are_shared_and_equal_the_checked_pose():
    src, sink = _source()
    nominal = COV.copy()
    nominal.flags.writeable = False  # as a body's nominal covariance
    s = _sample(10, c=nominal)
    pose = src.deliver(s)
    assert pose.position is s.position and pose.covariance is nominal  # no copies
    checked = UncertainPose(Pose(s.position, s.quaternion), s.covariance)
    np.testing.assert_array_equal(pose.quaternion, checked.quaternion)
    np.testing.assert_array_equal(pose.covariance, checked.covariance)
    assert sink.got == [Measurement(10, pose, 10)]
    assert src.deliver(_sample(11, c=nominal)) is not None  # the read-only one again


def test_other_samples_take_the_full_checks():
    src, _ = _source()
    q = np.array([0.0, 0.0, 0.6, 0.8]) * (1 + 4e-7)  # within the unit tolerance: normalised
    pose = src.deliver(_sample(1, q=q))
    assert abs(np.linalg.norm(pose.quaternion) - 1.0) < 1e-15 and pose.quaternion is not q
    lists = Sample(2, 2, [1.0, 2.0, 3.0], [0.0, 0.0, 0.0, 1.0], COV.tolist())
    assert src.deliver(lists).position.tolist() == [1.0, 2.0, 3.0]
    assert src.stats.rejections == {}


def test_bad_samples_are_counted_with_a_reason():
    src, sink = _source()
    bad_psd = COV.copy()
    bad_psd[0, 0] = -1.0
    assert src.deliver(_sample(1, p=(np.nan, 0.0, 0.0))) is None
    assert src.deliver(_sample(2, q=(0.0, 0.0, 0.0, 2.0))) is None
    assert src.deliver(_sample(3, c=bad_psd)) is None
    assert src.deliver(_sample(4)) is not None
    assert src.deliver(_sample(4)) is None
    assert src.stats.rejections == {"invalid pose or covariance": 3, "timestamp backwards": 1}
    assert len(sink.got) == 1


def _sources(tap: bool):
    from trackflow.dataflow import KalmanFilter
    from trackflow.graph import MotionSpec
    from trackflow.trackers.runtime import LiveSources

    motion = MotionSpec(static=False, n_dp=1, n_do=1, noise=(0.0, 30.0, 0.0, 100.0))
    sources = {f"s{k}": LiveSource(f"s{k}") for k in range(4)}
    filters = [KalmanFilter(f"kf{k}", motion) for k in range(4)]
    for src, kf in zip(sources.values(), filters):
        src.consumers.append((kf, 0))
    sink = _Sink()
    if tap:  # another consumer on s2: its samples cannot go to the bank as arrays
        sources["s2"].consumers.append((sink, 0))
    return LiveSources(sources), filters, sink


def _block(index, t, rng):
    from trackflow.math import quat_exp
    from trackflow.trackers.inputs import SampleBlock

    nominal = COV.copy()
    nominal.flags.writeable = False
    m = len(index)
    pos = np.array([[0.1 * i, 0.2, 0.3] for i in index]) + rng.normal(0, 1e-3, (m, 3))
    quat = quat_exp(rng.normal(0, 0.1, (m, 3)))
    covs = (nominal,) * m
    return SampleBlock(tuple(index), t, t + 3_000_000, pos, quat, np.stack(covs), covs)


@pytest.mark.parametrize("answer", [False, True])
def test_a_block_is_delivered_as_its_samples_one_by_one(answer):
    """LiveSources.deliver_block leaves sources and filters as deliver of the block's samples
    (dispatched at a, a + 1, ...): statistics, "timestamp backwards" rejections of some of
    a block's samples, filter states; a source with another consumer takes the per-sample
    path, and its consumer sees the same measurements. With ``answer``, the block's answers
    (the filters' poses at its arrival) come to a callback, equal to pulling them after."""
    for tap in (False,) if answer else (False, True):
        (blocks, kf_b, sink_b), (samples, kf_s, sink_s) = _sources(tap), _sources(tap)
        rng = np.random.default_rng(2)
        t0 = 1_700_000_000_000_000_000
        script = [((0, 1, 2, 3), t0 + k * 4_166_667) for k in range(30)]
        script.insert(12, ((0, 1), t0 + 13 * 4_166_667))  # s0, s1 ahead: later block rejected
        got_b, got_s = [], []
        for index, t in script:
            block = _block(index, t, rng)
            names = [f"s{i}" for i in index]
            a = block.arrival_ns
            delivered = []
            ask = (a, delivered.append) if answer else None
            got_b.append(blocks.deliver_block(names, block, a, answer=ask))
            items = [(n, s._replace(arrival_ns=a + k)) for k, (n, (_, s)) in
                     enumerate(zip(names, block))]  # fmt: skip
            got_s.append([p is not None for p in samples.deliver(items)])
            if answer:
                (early,) = delivered
                want = samples.filters.pull_block([samples.row[n] for n in names], [a] * len(names))
                assert early.ok == want.ok and all(want.ok)
                assert early.position.tobytes() == want.position.tobytes()
                assert early.covariance.tobytes() == want.covariance.tobytes()
        assert got_b == got_s and not all(all(g) for g in got_b)
        for a, b in zip(kf_b, kf_s):
            assert a.stats.summary() == b.stats.summary()
            xa, pa = a.filter.state
            xb, pb = b.filter.state
            assert xa.tobytes() == xb.tobytes() and pa.tobytes() == pb.tobytes()
        for name in blocks.sources:
            sa, sb = blocks.sources[name].stats, samples.sources[name].stats
            assert sa.summary() == sb.summary()
        assert blocks.sources["s0"].stats.rejections == {"timestamp backwards": 2}  # k = 12, 13
        assert [m.t_ns for m in sink_b.got] == [m.t_ns for m in sink_s.got]
        assert len(sink_b.got) == (30 if tap else 0)


def test_answers_need_sources_that_feed_one_filter():
    blocks, _, _ = _sources(tap=True)  # s2 feeds its filter and a tap
    block = _block((1, 2), 1_700_000_000_000_000_000, np.random.default_rng(0))
    with pytest.raises(ValueError, match="s2: answers need a source that feeds one filter"):
        blocks.deliver_block(["s1", "s2"], block, block.arrival_ns, answer=(0, print))
    assert blocks.sources["s1"].stats.events_in == 0  # nothing delivered


def test_a_packet_layout_taken_again_falls_back_where_anything_changed():
    """The layout a tracker sends again and again is looked up once (its lane), and each
    packet checks what may have changed since: a sample not after its source's last one, a
    source given another consumer, a filter reset from outside, a reset due after gated
    measurements, a refused answer ("stale"). Every packet's answers, and every source,
    component and filter afterwards, equal the one-by-one path's to the bit."""
    (blocks, kf_b, sink_b), (samples, kf_s, _) = _sources(False), _sources(False)
    rng = np.random.default_rng(5)
    t0 = 1_700_000_000_000_000_000
    period = 4_166_667
    refused = 0
    script = [((0, 1, 2, 3), t0 + k * period) for k in range(60)]
    script.insert(20, ((0,), t0 + 20 * period + period // 2))  # s0 ahead: rejects the next
    for k, (index, t) in enumerate(script):
        block = _block(index, t, rng)
        if 8 <= k < 8 + 12:  # s2 far away, again and again: gated, then a reset is due
            block.position[2] += 5.0
        for kfs in (kf_b, kf_s):
            if k == 30:  # from outside: new state arrays, not the bank's rows
                kfs[3].filter.reset()
            if k == 36:  # answers 3 ms after a sample are stale from now on for kf1
                kfs[1].max_extrapolation_ns = 1_000_000
            if k == 44:
                kfs[1].max_extrapolation_ns = 500_000_000
        if k == 50:  # another consumer on s2: its samples leave the lane
            for srcs in (blocks, samples):
                srcs.sources["s2"].consumers.append((sink_b, 0))
        names = [f"s{i}" for i in index]
        a = block.arrival_ns
        delivered = []
        ok_b = blocks.deliver_block(names, block, a, answer=(a, delivered.append))
        items = [(n, s._replace(arrival_ns=a + j)) for j, (n, (_, s)) in
                 enumerate(zip(names, block))]  # fmt: skip
        ok_s = [p is not None for p in samples.deliver(items)]
        assert ok_b == ok_s, k
        (early,) = delivered
        want = samples.filters.pull_block([samples.row[n] for n in names], [a] * len(names))
        assert early.ok == want.ok, k
        refused += not all(want.ok)
        assert early.position.tobytes() == want.position.tobytes(), k
        assert early.quaternion.tobytes() == want.quaternion.tobytes(), k
        assert early.covariance.tobytes() == want.covariance.tobytes(), k
    assert refused == 8  # the answers of kf1 between packets 36 and 44
    for a, b in zip(kf_b, kf_s):
        assert a.stats.summary() == b.stats.summary()
        assert (a.first_t, a.last_t, a.last_origin) == (b.first_t, b.last_t, b.last_origin)
        assert a.filter.stats == b.filter.stats
        xa, pa = a.filter.state
        xb, pb = b.filter.state
        assert xa.tobytes() == xb.tobytes() and pa.tobytes() == pb.tobytes()
        assert [e.buf.tobytes() for e in a.filter._log] == [e.buf.tobytes() for e in b.filter._log]
    for name in blocks.sources:
        assert blocks.sources[name].stats.summary() == samples.sources[name].stats.summary()
    assert kf_b[2].filter.stats["resets"] >= 1 and kf_b[2].filter.stats["rejected_gate"] > 0
    assert blocks.sources["s0"].stats.rejections == {"timestamp backwards": 1}
    # the lanes were taken (by the layouts the test sends)
    assert ("s0", "s1", "s2", "s3") in blocks._lanes and (0, 1, 2, 3) in blocks.filters._lanes


def test_the_backlog_window_is_judged_on_the_trackers_own_times():
    """A block that arrives more than BACKLOG_NS after it was taken (a stalled tracker's
    backlog) is dropped and counted on the block path as on the one-by-one path. An online
    correction that moves a tracker's times 600 ms earlier (it was found that much slower
    than its stamps) leaves its frames in the window: the window is judged on the time
    before the correction, so every frame after a large negative correction still arrives."""
    from trackflow.dataflow import BACKLOG_NS

    (blocks, kf_b, _), (samples, kf_s, _) = _sources(False), _sources(False)
    rng = np.random.default_rng(7)
    t0, period, shift = 1_700_000_000_000_000_000, 4_166_667, -600_000_000
    names = [f"s{i}" for i in range(4)]
    script = [(t0 + k * period, 3_000_000, 0) for k in range(5)]
    script.append((t0 + 5 * period, BACKLOG_NS + 1_000_000, 0))  # the backlog: dropped
    # after the correction: taken 600 ms before the stamps said, arrived 3 ms after the stamps
    script += [(t0 + k * period + shift, 3_000_000 - shift, shift) for k in range(200, 210)]
    for t, age, s in script:
        block = _block(range(4), t, rng)
        a = t + age
        ok_b = blocks.deliver_block(names, block, a, shift_ns=s)
        items = [(n, x._replace(arrival_ns=a + j)) for j, (n, (_, x)) in
                 enumerate(zip(names, block))]  # fmt: skip
        ok_s = [p is not None for p in samples.deliver(items, shift_ns=s)]
        assert ok_b == ok_s == [age + s <= BACKLOG_NS] * 4, (t - t0, age)
    for name in names:
        for srcs in (blocks, samples):
            stats = srcs.sources[name].stats
            assert stats.rejections == {"older than the backlog window": 1}, name
            assert stats.events_out == 15
    for a, b in zip(kf_b, kf_s):
        assert a.stats.summary() == b.stats.summary()
        xa, pa = a.filter.state
        xb, pb = b.filter.state
        assert xa.tobytes() == xb.tobytes() and pa.tobytes() == pb.tobytes()
