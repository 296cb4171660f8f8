"""LiveSource.deliver: plainly valid samples are taken without copies, anything else goes
through the full checks, and bad samples are counted rejections with a reason."""

from __future__ import annotations

import numpy as np

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
