"""Prediction shrinkage: on the data it is fitted to, never worse than holding or the filter."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.evaluation import (
    KalmanPredictor,
    NoPredictor,
    Predictor,
    ShrunkPredictor,
    Trajectory,
    fit_shrinkage,
    pose_errors,
)
from trackflow.filters import MotionModel
from trackflow.math import quat_exp


def _oscillation(seed=0, n=1500, rate=100.0) -> Trajectory:
    """Hand-like back-and-forth motion at 2.5 Hz: linear extrapolation overshoots at 200 ms."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    p = np.stack([0.05 * np.sin(2 * np.pi * 2.5 * t), 0.02 * np.cos(2 * np.pi * 1.3 * t),
                  0 * t], 1) + rng.normal(scale=2e-4, size=(n, 3))  # fmt: skip
    rv = np.stack([0.6 * np.sin(2 * np.pi * 2.5 * t + 0.3), 0 * t, 0.2 * np.cos(4 * t)], 1)
    q = quat_exp(rv + rng.normal(scale=2e-3, size=(n, 3)))
    return Trajectory.check(t, p, q, gap_s=0.05)


def _filter() -> KalmanPredictor:
    return KalmanPredictor(MotionModel(2, 1, noise=(2e-4, 0, 30.0, 2e-3, 30.0)), 2e-4, 2e-3, None)


def _rms(rec, pred, i, h):
    m = rec.scored(h)
    tp, tq = rec.target(h)
    e_p, e_q = pose_errors(pred.position[i][m], pred.quaternion[i][m], tp[m], tq[m])
    return np.sqrt(np.mean(e_p**2)), np.sqrt(np.mean(e_q**2))


def test_shrinkage_is_never_worse_than_holding_or_the_filter_in_sample():
    rec = _oscillation()
    base = _filter()
    h = np.array([0.02, 0.1, 0.2])
    shr = fit_shrinkage(rec, base, h)
    assert isinstance(shr, ShrunkPredictor) and isinstance(shr, Predictor)
    assert shr.family == base.family
    assert shr.position[-1] < 0.9 and shr.orientation[-1] < 0.95  # long horizons shrink
    assert all(0.0 <= v <= 1.0 for v in shr.position + shr.orientation)
    runs = {"shrunk": shr.predict(rec, h), "filter": base.predict(rec, h),
            "hold": NoPredictor().predict(rec, h)}  # fmt: skip
    for i, hv in enumerate(h):
        rms = {name: _rms(rec, run, i, hv) for name, run in runs.items()}
        for part in (0, 1):
            assert rms["shrunk"][part] <= rms["hold"][part] * (1 + 1e-9)
            assert rms["shrunk"][part] <= rms["filter"][part] * (1 + 1e-9)
    # at 200 ms the constant-velocity filter overshoots: shrinking is strictly better there
    assert _rms(rec, runs["shrunk"], 2, 0.2)[0] < 0.95 * _rms(rec, runs["filter"], 2, 0.2)[0]


def test_factors_interpolate_from_one_at_zero_and_hold_the_last():
    shr = ShrunkPredictor(_filter(), (0.05, 0.1), (0.8, 0.4), (1.0, 0.6))
    lam_p, lam_o = shr.factors([0.0, 0.025, 0.075, 0.3])
    assert np.allclose(lam_p, [1.0, 0.9, 0.6, 0.4]) and np.allclose(lam_o, [1.0, 1.0, 0.8, 0.6])
    d = shr.as_dict()
    assert d["family"] == "derivative" and d["shrinkage"]["horizons_ms"] == [50.0, 100.0]


def test_zero_factors_are_holding_and_one_is_the_filter():
    rec = _oscillation(seed=1, n=300)
    h = np.array([0.05, 0.1])
    base, hold = _filter().predict(rec, h), NoPredictor().predict(rec, h)
    zero = ShrunkPredictor(_filter(), (0.05, 0.1), (0.0, 0.0), (0.0, 0.0)).predict(rec, h)
    one = ShrunkPredictor(_filter(), (0.05, 0.1), (1.0, 1.0), (1.0, 1.0)).predict(rec, h)
    assert np.allclose(zero.position, hold.position)
    assert np.allclose(np.abs(np.sum(zero.quaternion * hold.quaternion, -1)), 1.0)
    assert np.allclose(one.position, base.position, atol=1e-12)
    assert np.allclose(np.abs(np.sum(one.quaternion * base.quaternion, -1)), 1.0)


def test_factors_outside_the_unit_interval_are_rejected():
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        ShrunkPredictor(_filter(), (0.05,), (1.5,), (1.0,))
    with pytest.raises(ValueError, match="one lambda"):
        ShrunkPredictor(_filter(), (0.05, 0.1), (1.0,), (1.0,))
