"""Cross-correlation clock offset: seeded synthetic truth, its standard error against seeded
Monte Carlo scatter, gaps and the errors it reports."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from trackflow.timesync import correlation_offset

OFFSET = 0.1234  # host - remote [s]


def _signal(rng):
    f, ph, amp = rng.uniform(0.2, 3.0, 8), rng.uniform(0, 2 * np.pi, 8), rng.uniform(0.5, 1, 8)
    return lambda t: (amp * np.sin(2 * np.pi * f * np.asarray(t)[..., None] + ph)).sum(-1)


def _recordings(rng, noise=0.3, offset=OFFSET):
    """Host recording at 100 Hz; remote at 73 Hz on a clock ``offset`` behind, with another
    gain and bias: a remote stamp ``tau`` is host time ``tau + offset``."""
    f = _signal(rng)
    th = np.arange(0.0, 20.0, 0.01) + rng.uniform(0, 0.01)
    tr = np.arange(-3.0, 17.0, 1 / 73)
    sh = f(th) + rng.normal(0, noise, th.shape)
    sr = 2.0 * f(tr + offset) + 1.0 + rng.normal(0, noise, tr.shape)
    return th, sh, tr, sr


@pytest.mark.parametrize("offset", [-0.31, 0.0, OFFSET])
def test_offset_is_recovered(offset):
    th, sh, tr, sr = _recordings(np.random.default_rng(3), offset=offset)
    r = correlation_offset(th, sh, tr, sr, max_offset_s=0.5)
    assert abs(r.offset_s - offset) < 4 * r.sigma_s
    assert 0 < r.sigma_s < 2e-3
    assert abs(r.coarse_offset_s - offset) < 0.01  # the parabola, within a step
    assert r.peak > 0.8 and r.lags_s.shape == r.correlation.shape


def test_standard_error_matches_monte_carlo_scatter():
    runs = 150
    err, sig = [], []
    for seed in range(runs):
        th, sh, tr, sr = _recordings(np.random.default_rng(seed + 100))
        r = correlation_offset(th, sh, tr, sr, max_offset_s=0.5)
        err.append(r.offset_s - OFFSET)
        sig.append(r.sigma_s)
    err, sig = np.array(err), np.array(sig)
    z2 = np.mean((err / sig) ** 2)
    lo, hi = stats.chi2.ppf([0.005, 0.995], runs) / runs
    assert lo <= z2 <= hi, (z2, lo, hi)
    assert abs(err.mean()) < 3 * err.std() / np.sqrt(runs)  # no bias


def test_gaps_are_left_out_and_refine_false_gives_the_peak():
    th, sh, tr, sr = _recordings(np.random.default_rng(9), noise=0.05)
    sh[(th > 5) & (th < 7)] = np.nan  # a gap in each recording
    sr[(tr > 10) & (tr < 10.5)] = np.nan
    r = correlation_offset(th, sh, tr, sr, max_offset_s=0.5)
    assert abs(r.offset_s - OFFSET) < 4 * r.sigma_s
    c = correlation_offset(th, sh, tr, sr, max_offset_s=0.5, refine=False)
    assert c.offset_s == c.coarse_offset_s == r.coarse_offset_s
    assert c.sigma_s == pytest.approx(0.5 / 73 / np.sqrt(12))


def test_errors_say_what_is_wrong():
    th, sh, tr, sr = _recordings(np.random.default_rng(1), offset=0.4)
    with pytest.raises(ValueError, match="edge of the search range|do not correlate"):
        correlation_offset(th, sh, tr, sr, max_offset_s=0.2)
    noise = np.random.default_rng(2).normal(size=tr.shape)
    with pytest.raises(ValueError, match="do not correlate"):
        correlation_offset(th, sh, tr, noise, max_offset_s=0.5, min_peak=0.5)
    with pytest.raises(ValueError, match="overlap too little"):
        correlation_offset(th, sh, tr + 100.0, sr, max_offset_s=0.5)
