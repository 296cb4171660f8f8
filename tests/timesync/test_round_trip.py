"""Round-trip clock offsets (Cristian's method): the fastest round trip, its uniform error."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.timesync import RoundTripOffset, round_trip_offset


def test_offset_from_the_fastest_round_trip(rng):
    true_offset = 250_000_000
    c = RoundTripOffset(window=16)
    for _ in range(16):
        t0 = int(rng.integers(0, 10**12))
        up, down = rng.integers(20_000, 2_000_000, size=2)
        remote = t0 + up + true_offset
        c.add_round_trip(t0, remote, t0 + up + down)
    # the estimate (host - remote) is within half the best round trip of the truth
    rtt = c.sigma_s * 2 * np.sqrt(3) * 1e9
    assert c.sigma_ns == pytest.approx(c.sigma_s * 1e9)
    assert abs(c.offset_ns + true_offset) <= rtt / 2 + 1
    assert c.to_host(10**9 + true_offset) == 10**9 + (c.offset_ns + true_offset)
    assert c.to_remote(c.to_host(123_456_789)) == 123_456_789
    with pytest.raises(ValueError, match="ends before"):
        c.add_round_trip(10, 0, 5)
    with pytest.raises(ValueError, match="no clock round trip"):
        RoundTripOffset().offset_ns


def test_sigma_matches_uniform_errors_monte_carlo(rng):
    # the remote reading falls uniformly inside the round trip: error sd = rtt / sqrt(12)
    rtt = 1_000_000
    errors = []
    for _ in range(4000):
        c = RoundTripOffset(window=1)
        t0 = 0
        c.add_round_trip(t0, int(rng.uniform(0, rtt)), t0 + rtt)
        errors.append(-c.offset_ns * 1e-9)
    assert np.std(errors) == pytest.approx(c.sigma_s, rel=0.05)


def test_one_round_trip_against_its_monte_carlo_scatter(rng):
    """The remote reading falls anywhere inside the round trip: the reported sigma is the
    scatter of the estimate about the truth over seeded draws of the two one-way delays."""
    offset, rtt = -7_000_000, 400_000  # host = remote - 7 ms
    errs, sigmas = [], []
    for _ in range(4000):
        send = int(rng.integers(0, 10**12))
        up = int(rng.uniform(0, rtt))
        o, s = round_trip_offset(send, send + up - offset, send + rtt)
        errs.append(o - offset)
        sigmas.append(s)
    assert np.mean(errs) == pytest.approx(0.0, abs=0.1 * sigmas[0])
    assert np.std(errs) == pytest.approx(sigmas[0], rel=0.05)
    with pytest.raises(ValueError, match="ends before"):
        round_trip_offset(10, 0, 5)
