"""PoseStream: validation, indexing, concatenation, conversions."""

from __future__ import annotations

import numpy as np
import pytest
from _io_helpers import random_stream

from trackflow import Pose, UncertainPose
from trackflow.io import FLAG_COVARIANCE, FLAG_ORIENTATION, FLAG_POSITION, PoseStream


def test_defaults_and_readonly(rng):
    s = random_stream(rng, 5)
    assert len(s) == 5
    assert s.covariance is None
    assert np.all(s.confidence == 1.0)
    assert np.all(s.flags == (FLAG_POSITION | FLAG_ORIENTATION))
    with pytest.raises(ValueError):
        s.position[0, 0] = 1.0  # read-only arrays
    c = random_stream(rng, 5, covariance=True)
    assert np.all(c.flags & FLAG_COVARIANCE)


def test_times(rng):
    s = random_stream(rng, 4)
    assert s.times_s[0] == pytest.approx(s.t_ns[0] * 1e-9)
    assert s.elapsed_s[0] == 0.0
    assert s.elapsed_s[-1] == pytest.approx((s.t_ns[-1] - s.t_ns[0]) / 1e9, abs=1e-15)
    assert s.duration_s == pytest.approx(s.elapsed_s[-1])
    f = PoseStream.from_seconds("a", "b", [0.5, 1.25], np.zeros((2, 3)), [[0, 0, 0, 1]] * 2)
    assert f.t_ns.tolist() == [500_000_000, 1_250_000_000]


@pytest.mark.parametrize(
    "change, message",
    [
        ({"t_ns": np.array([0.0, 1.0])}, "integer nanoseconds"),
        ({"t_ns": np.array([5, 5])}, "strictly increasing"),
        ({"position": [[0, 0, np.nan], [0, 0, 0]]}, "NaN"),
        ({"quaternion": [[0, 0, 0, 2.0], [0, 0, 0, 1]]}, "unit length"),
        ({"covariance": np.full((2, 6, 6), 1.0) - 2 * np.eye(6)}, "semi-definite"),
        ({"confidence": [0.5, 1.5]}, "confidence"),
        ({"source": ""}, "source"),
        ({"position": np.zeros((3, 3))}, "shape"),
    ],
)
def test_invalid_fields_raise(change, message):
    fields = dict(
        source="a",
        target="b",
        t_ns=np.array([1, 2]),
        position=np.zeros((2, 3)),
        quaternion=[[0, 0, 0, 1.0]] * 2,
    )
    fields.update(change)
    with pytest.raises(ValueError, match=message):
        PoseStream(**fields)


def test_indexing(rng):
    s = random_stream(rng, 10, covariance=True)
    part = s[2:5]
    assert len(part) == 3 and part.t_ns[0] == s.t_ns[2]
    assert np.array_equal(part.covariance, s.covariance[2:5])
    one = s[-1]
    assert len(one) == 1 and one.t_ns[0] == s.t_ns[-1]
    mask = np.zeros(10, dtype=bool)
    mask[[1, 7]] = True
    assert s[mask].t_ns.tolist() == s.t_ns[[1, 7]].tolist()
    assert s[np.array([0, 3])].t_ns.tolist() == s.t_ns[[0, 3]].tolist()
    with pytest.raises(IndexError):
        s[np.array([3, 0])]  # would break time order
    with pytest.raises(IndexError):
        s[::-1]
    sl = s.time_slice(int(s.t_ns[3]), int(s.t_ns[6]))
    assert sl.t_ns.tolist() == s.t_ns[3:6].tolist()


def test_concatenate_and_with(rng):
    s = random_stream(rng, 12, covariance=True)
    joined = PoseStream.concatenate([s[:4], s[4:9], s[9:]])
    assert joined == s
    with pytest.raises(ValueError, match="strictly increas"):
        PoseStream.concatenate([s[4:], s[:4]])
    with pytest.raises(ValueError, match="T_a_body"):
        PoseStream.concatenate([s, s.with_(source="a")])
    no_cov = s.with_(covariance=None)
    assert no_cov.covariance is None
    assert not np.any(no_cov.flags & FLAG_COVARIANCE)
    with pytest.raises(ValueError, match="covariance"):
        PoseStream.concatenate([s[:3], no_cov[3:]])
    moved = s.with_(position=s.position + 1.0)
    assert np.allclose(moved.position - s.position, 1.0)
    assert moved != s and s == s.with_()
    with pytest.raises(ValueError, match="unknown"):
        s.with_(colour="red")


def test_pose_views(rng):
    s = random_stream(rng, 6, covariance=True)
    assert isinstance(s.poses, Pose) and s.poses.shape == (6,)
    up = s.uncertain_poses
    assert isinstance(up, UncertainPose)
    assert np.array_equal(up.covariance, s.covariance)
    # composing with the inverse gives identity poses: the views are real Pose batches
    ident = s.poses @ s.poses.inverse()
    assert np.allclose(ident.position, 0.0, atol=1e-9)
    with pytest.raises(ValueError, match="no covariance"):
        s.with_(covariance=None).uncertain_poses
    back = PoseStream.from_poses("world", "body", s.t_ns, up)
    assert np.array_equal(back.covariance, s.covariance)
