"""Clock offset between two streams: synthetic truth with different rates, gaps and drift."""

from __future__ import annotations

import numpy as np
import pytest
from _synth import two_trackers

from trackflow.calibration import estimate_clock_offset


@pytest.mark.parametrize("offset", [-0.31, 0.0, 0.25])
def test_offset_found_within_a_tenth_of_the_slower_period(offset):
    a, b = two_trackers(1, duration=25.0, offset=offset, gap=(10.0, 11.0))
    r = estimate_clock_offset(a, b)
    assert abs(r.offset_s - offset) < 0.1 / 30.0
    assert abs(r.offset_s - offset) < 5 * r.sigma_s + 1e-4
    assert abs(r.coarse_offset_s - offset) < 1 / 30.0
    assert r.signal == "angular" and r.peak_correlation > 0.8


def test_offset_standard_error_is_consistent():
    z = []
    for seed in range(8):
        a, b = two_trackers(seed + 40, duration=20.0, offset=0.1)
        r = estimate_clock_offset(a, b)
        z.append((r.offset_s - 0.1) / r.sigma_s)
    # chi-square with 8 dof: 99.9 % quantile 26.1; a standard error 3x too small would give ~72
    assert np.sum(np.square(z)) < 26.1


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
