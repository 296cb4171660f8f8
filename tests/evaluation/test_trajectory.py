"""The PoseTool's boundary value (``Trajectory``) and its predictor contract (``Predictor``)."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.evaluation import (
    KalmanPredictor,
    LinearPredictor,
    NoPredictor,
    PartwisePredictor,
    Predictor,
    Trajectory,
    TwistARPredictor,
    default_gap,
    default_predictor,
    interpolate_poses,
    predict_kalman,
    predict_linear,
    scored_mask,
)
from trackflow.filters.twist_ar import TwistARModel
from trackflow.io import PoseStream
from trackflow.math import quat_exp


def _recording(n=300, rate=100.0, gap_at=150):
    t = np.arange(n) / rate
    t[gap_at:] += 0.5  # one dropout
    p = np.stack([np.sin(t), np.cos(0.7 * t), 0.1 * t], axis=1)
    q = quat_exp(np.stack([0.3 * np.sin(t), 0.2 * t, 0.1 * np.cos(t)], axis=1))
    return t, p, q


def test_check_validates_once_and_defaults_the_gap():
    t, p, q = _recording()
    rec = Trajectory.check(t.tolist(), p, q)
    assert rec.t.dtype == float and rec.t.flags.c_contiguous
    assert rec.gap_s == default_gap(t) and rec.n_gaps == 1
    assert Trajectory.check(t, p, q, gap_s=np.inf).max_gap is None
    sub = rec.select(rec.t < 1.0)
    assert len(sub) == 100 and sub.gap_s == rec.gap_s  # a subset keeps the recording's gaps


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda t, p, q: (t[:3], p[:3], q[:3]), "at least 4 samples"),
        (lambda t, p, q: (t, p[:, :2], q), "positions"),
        (lambda t, p, q: (t, np.where(np.arange(len(t))[:, None] == 5, np.nan, p), q), "finite"),
        (lambda t, p, q: (np.r_[t[:10], t[9], t[11:]], p, q), "sample 10"),
    ],
)
def test_bad_recordings_are_named(change, message):
    with pytest.raises(ValueError, match=message):
        Trajectory.check(*change(*_recording()))
    with pytest.raises(ValueError, match="gap_s"):
        Trajectory.check(*_recording(), gap_s=0.0)


def test_masks_and_targets_are_the_functions_computed_once():
    t, p, q = _recording()
    rec = Trajectory.check(t, p, q)
    m = rec.scored(0.05)
    assert np.array_equal(m, scored_mask(t, 0.05, rec.gap_s)) and rec.scored(0.05) is m
    tp, tq = rec.target(0.05)
    ep, eq = interpolate_poses(t, p, q, t + 0.05)
    assert np.array_equal(tp, ep) and np.array_equal(tq, eq) and rec.target(0.05)[0] is tp


def test_from_stream_counts_time_from_the_first_sample():
    t, p, q = _recording()
    stream = PoseStream("a", "b", (1_000_000_000 + t * 1e9).round().astype(np.int64), p, q)
    rec = Trajectory.from_stream(stream)
    np.testing.assert_allclose(rec.t, t, atol=1e-9)


def test_every_predictor_meets_the_protocol_with_the_documented_shapes():
    t, p, q = _recording()
    rec = Trajectory.check(t, p, q)
    kalman = default_predictor(t, p, q)
    learned = TwistARPredictor(TwistARModel.fit(t, p, q, 3), 1e-4, 1e-4)
    cases = [kalman, learned, PartwisePredictor(kalman, learned), LinearPredictor(), NoPredictor()]
    for pred in cases:
        assert isinstance(pred, Predictor)
        assert pred.as_dict()["family"] == pred.family
        out = predict_kalman(rec, pred, (0.02, 0.05))
        assert out.position.shape == (2, len(t), 3) and out.quaternion.shape == (2, len(t), 4)
    lp, lq = predict_linear(t, p, q, 0.05)
    out = LinearPredictor().predict(rec, np.array([0.05]))
    assert np.array_equal(out.position[0], lp) and np.array_equal(out.quaternion[0], lq)
    assert np.array_equal(NoPredictor().predict(rec, np.array([0.05])).position[0], p)
    assert isinstance(kalman, KalmanPredictor) and not isinstance(kalman.model, Predictor)
