"""Clock offset between two streams: synthetic truth with different rates, gaps and drift."""

from __future__ import annotations

import numpy as np
import pytest
from _synth import two_trackers
from scipy import stats

from trackflow.calibration import estimate_clock_offset
from trackflow.calibration._sampling import body_rate_jacobians, body_rates, make_trajectory
from trackflow.math import quat_exp, quat_multiply


@pytest.mark.parametrize("offset", [-0.31, 0.0, 0.25])
def test_offset_found_within_a_tenth_of_the_slower_period(offset):
    a, b = two_trackers(1, duration=25.0, offset=offset, gap=(10.0, 11.0))
    r = estimate_clock_offset(a, b)
    assert abs(r.offset_s - offset) < 0.1 / 30.0
    assert abs(r.offset_s - offset) < 5 * r.sigma_s + 1e-4
    assert abs(r.coarse_offset_s - offset) < 1 / 30.0
    assert r.signal == "angular" and r.peak_correlation > 0.8


@pytest.mark.slow
def test_offset_standard_error_is_consistent():
    """The rates are differences over +-0.2 s, so neighbouring residuals share samples (and
    their autocorrelation has a negative lobe): the sample-noise sandwich must neither ignore
    that (overconfident) nor over-count it (the residual autocorrelation time gave 0.28)."""
    runs = 20
    z = []
    for seed in range(runs):
        a, b = two_trackers(seed + 40, duration=20.0, offset=0.1)
        r = estimate_clock_offset(a, b)
        z.append((r.offset_s - 0.1) / r.sigma_s)
    lo, hi = stats.chi2.ppf([0.025, 0.975], runs) / runs
    assert lo <= np.mean(np.square(z)) <= hi, (np.mean(np.square(z)), lo, hi)


def test_body_rate_jacobians_match_finite_differences():
    t = np.arange(0.0, 2.0, 1 / 72)
    q = quat_exp(np.stack([0.3 * np.sin(2 * t), 0.2 * np.cos(3 * t), 0.1 * t], axis=1))
    p = np.zeros((len(t), 3))
    tq = np.array([0.5, 0.77, 1.2])
    J, index = body_rate_jacobians(make_trajectory(t, p, q), tq, 0.2)
    h = 1e-6
    for n in np.unique(index):
        for c in range(3):
            d = np.zeros(3)
            d[c] = h
            w = []
            for sgn in (1, -1):
                qq = q.copy()
                qq[n] = quat_multiply(q[n], quat_exp(sgn * d))
                w.append(body_rates(make_trajectory(t, p, qq), tq, 0.2)[0])
            fd = (w[0] - w[1]) / (2 * h)
            an = np.einsum("kq,kqi->ki", (index == n).astype(float), J[:, :, :, c])
            # first order in the rotation between two samples (under 0.5 deg here)
            np.testing.assert_allclose(an, fd, atol=0.02 * np.abs(fd).max() + 1e-9)


def test_drift_is_estimated():
    a, b = two_trackers(2, duration=40.0, offset=0.2)
    # b's clock runs 200 ppm fast relative to a: stamps stretched about their middle
    t = b.t_ns.astype(np.int64)
    mid = t[len(t) // 2]
    stretched = b.with_(t_ns=mid + np.round((t - mid) * (1 + 2e-4)).astype(np.int64))
    r = estimate_clock_offset(a, stretched, drift=True)
    assert r.drift is not None and r.drift_sigma is not None
    assert abs(r.drift - (-2e-4)) < max(4 * r.drift_sigma, 3e-5)
    assert abs(r.offset_s - 0.2) < 0.1 / 30.0


def test_offset_beyond_the_search_range_is_a_clear_error():
    a, b = two_trackers(3, duration=20.0, offset=0.9)
    with pytest.raises(ValueError, match="max_offset_s|correlate"):
        estimate_clock_offset(a, b, max_offset_s=0.5)


def test_single_axis_rotation_falls_back_to_speed_magnitudes():
    a, b = two_trackers(5, duration=20.0, axes=(0, 0, 1))
    r = estimate_clock_offset(a, b)
    assert abs(r.offset_s - 0.25) < 0.1 / 30.0
    assert abs(r.offset_s - 0.25) < 4 * r.sigma_s


def test_no_rotation_uses_linear_speed():
    a, b = two_trackers(5, duration=20.0, rot_amp=0.0)
    r = estimate_clock_offset(a, b)
    assert r.signal == "linear"
    assert abs(r.offset_s - 0.25) < 0.1 / 30.0
