"""The measured noise figure and its standard error (dataflow/_attributes.py) against a seeded
Monte Carlo: white noise of a known sigma on a smooth motion, a full ring per run."""

from __future__ import annotations

import numpy as np

from trackflow.dataflow import MeasuredAttributes
from trackflow.dataflow._attributes import WINDOW
from trackflow.math import quat_exp, quat_multiply

SIGMA_M, SIGMA_RAD, RATE_HZ = 1e-3, 2e-3, 120.0


def _ring(rng) -> dict:
    t = np.arange(WINDOW) / RATE_HZ
    truth_p = np.stack([0.5 * np.sin(1.3 * t), 0.3 * np.cos(0.7 * t), 0.1 * t], axis=1)
    truth_q = quat_exp(np.stack([0.8 * np.sin(0.9 * t), 0.2 * t, 0 * t], axis=1))
    pos = truth_p + rng.normal(0, SIGMA_M, truth_p.shape)
    quat = quat_multiply(truth_q, quat_exp(rng.normal(0, SIGMA_RAD, truth_p.shape)))
    m = MeasuredAttributes()
    for k in range(WINDOW):
        t_ns = int(round(t[k] * 1e9))
        m.update(t_ns, t_ns + 5_000_000, np.nan, pos[k], quat[k])
    return m.figures()


def test_the_noise_sigma_and_its_standard_error_match_a_monte_carlo():
    runs = [_ring(np.random.default_rng(seed)) for seed in range(120)]
    for key, truth in (("noise_mm", SIGMA_M * 1e3), ("noise_deg", np.degrees(SIGMA_RAD))):
        est = np.array([r[key] for r in runs])
        err = np.array([r[f"{key}_sigma"] for r in runs])
        assert abs(est.mean() - truth) < 0.03 * truth, (key, est.mean(), truth)  # unbiased
        spread = est.std(ddof=1)
        ratio = err.mean() / spread  # the reported standard error against the actual spread
        print(f"{key}: mean {est.mean():.4g} (truth {truth:.4g}), spread {spread:.3g}, "
              f"reported {err.mean():.3g} (ratio {ratio:.2f})")  # fmt: skip
        assert 0.75 < ratio < 1.33, (key, ratio)
    r = runs[0]
    assert abs(r["rate_hz"] - RATE_HZ) < 1e-6 * RATE_HZ  # the interval rounded to 1 ns
    assert r["dropout"] == 0.0 and abs(r["latency_ms"] - 5.0) < 1e-9
