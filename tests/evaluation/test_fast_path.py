"""The means-only fast path of run_filter computes the same filter as the covariance path."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow import UncertainPose
from trackflow.filters import MotionModel, run_filter
from trackflow.math import quat_angle, quat_exp, quat_multiply


def _recording(rng, n=500):
    t = np.cumsum(rng.uniform(0.007, 0.011, n))
    t[250:] += 0.2  # a dropout
    p = np.stack([np.sin(2 * t), np.cos(1.5 * t), 0.2 * t], axis=1) + rng.normal(0, 1e-3, (n, 3))
    q = quat_exp(np.stack([np.sin(t), 0.5 * t, 0.3 * np.cos(2 * t)], axis=1))
    q = quat_multiply(q, quat_exp(rng.normal(0, 2e-3, (n, 3))))
    p[100] += 0.3  # a spike the gate rejects
    p[400:412] += 0.5  # a jump that makes the filter reset
    cov = np.broadcast_to(np.diag([1e-6] * 3 + [4e-6] * 3), (n, 6, 6)).copy()
    pos = p.copy()
    pos[50] = np.nan  # a dropout row (skipped, counted)
    return t, UncertainPose._trusted(pos, q, cov)


@pytest.mark.parametrize(
    "model",
    [
        MotionModel(2, 1, noise=(1e-3, 0, 30, 1e-3, 30)),
        MotionModel(3, -1, noise=(0, 0, 0, 300)),
        MotionModel(-1, 2, noise=(1e-3, 0, 30), kind="thesis"),
        MotionModel(0, 0, noise=(0.1, 0.1)),
    ],
)
@pytest.mark.parametrize("max_gap", [None, 0.05])
def test_means_only_matches_the_covariance_path(rng, model, max_gap):
    t, poses = _recording(rng)
    h = (0.0, 0.05, 0.1)
    full = run_filter(t, poses, model, h, max_gap=max_gap)
    fast = run_filter(t, poses, model, h, max_gap=max_gap, covariance=False)
    assert np.array_equal(full.status, fast.status)
    assert full.stats == fast.stats
    assert full.stats["rejected_gate"] > 0 or model.n_dp < 0  # the position spike is gated
    assert np.allclose(full.nis, fast.nis, rtol=1e-9, equal_nan=True)
    for a, b in [(full.filtered, fast.filtered)] + [(full.predictions[v], fast.predictions[v])
                                                    for v in h]:  # fmt: skip
        assert np.allclose(a.position, b.position, rtol=0, atol=1e-10)
        assert quat_angle(a.quaternion, b.quaternion).max() < 1e-9


def test_max_gap_restarts_the_filter(rng):
    t, poses = _recording(rng)
    res = run_filter(t, poses, MotionModel(), (0.05,), max_gap=0.05, covariance=False)
    assert res.status[250] == 4 and res.status[0] == 4  # initialised after the dropout
    assert np.sum(res.status == 4) == 2
    with pytest.raises(ValueError, match="max_gap"):
        run_filter(t, poses, MotionModel(), max_gap=-1.0)
