"""Clock mapping: the lower envelope recovers offset and drift under delay spikes."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.math import numba_available
from trackflow.timesync import ClockMapper, lower_envelope


def test_lower_envelope_is_below_every_point_and_touches_the_hull():
    rng = np.random.default_rng(0)
    x = np.sort(rng.uniform(0, 10, 200))
    y = 3.0 + 0.5 * x + rng.exponential(0.2, 200)
    a, b = lower_envelope(list(x), list(y))
    line = a + b * (x - x.mean())
    assert (y - line >= -1e-9).all()
    assert np.sort(y - line)[:2] == pytest.approx([0, 0], abs=1e-9)  # an edge of the hull
    assert b == pytest.approx(0.5, abs=0.02)
    assert lower_envelope([1.0], [2.0]) == (2.0, 0.0)


def _stream(rng, n, offset_ns, drift, rate_hz=120.0, spikes=0.05):
    """Tracker stamps every 1/rate; arrival = stamp (tracker) mapped to host + delay."""
    x = (np.arange(n) * 1e9 / rate_hz).astype(np.int64) + 5_000_000_000
    delay = rng.uniform(0, 2e6, n)  # 2 ms uniform jitter
    spike = rng.random(n) < spikes
    delay[spike] += rng.uniform(5e6, 50e6, spike.sum())  # delay spikes
    host = x + offset_ns + drift * (x - x[0]) + 30_000 + delay  # 30 us minimum transit
    return x, np.round(host).astype(np.int64)


@pytest.mark.parametrize("drift", [0.0, 20e-6, -50e-6])
def test_mapper_recovers_offset_and_drift(drift):
    rng = np.random.default_rng(1)
    offset = -123_456_789_000
    x, h = _stream(rng, 120 * 60, offset, drift)
    m = ClockMapper()
    errs = []
    for xi, hi in zip(x, h):
        m.add(int(xi), int(hi))
        true_host = xi + offset + drift * (xi - x[0])
        errs.append(m.to_host(int(xi)) - true_host)
    errs = np.array(errs) * 1e-3  # us
    # once the drift is estimated (15 s) the mapping sits on the minimum transit (30 us):
    # never more than 10 us below it or 45 us above it, although the delays spread over
    # 2 ms and 5 % of them spike by up to 50 ms; before, within 200 us
    late = errs[120 * 15 :] - 30
    assert -10 < late.min() and late.max() < 45, (late.min(), late.max())
    assert np.abs(errs[120:]).max() < 200
    e = m.estimate
    assert e.drift == pytest.approx(drift, abs=2e-6)
    assert 0 < e.sigma_ns < 2e6


def test_mapper_lowers_at_once_and_clips_drift():
    m = ClockMapper(max_drift=1e-4)
    m.add(0, 1_000_000)
    assert m.to_host(0) == 1_000_000
    m.add(1_000_000, 1_500_000)  # a faster packet: the line drops immediately
    assert m.to_host(1_000_000) == 1_500_000
    # a clock running 1 % fast is clipped to 100 ppm
    for k in range(2, 400):
        m.add(k * 10_000_000, int(k * 10_000_000 * 1.01))
    assert abs(m.estimate.drift) <= 1e-4 + 1e-12
    with pytest.raises(ValueError):
        ClockMapper(window_s=0.1, bin_s=0.2)
    with pytest.raises(ValueError, match="no samples"):
        ClockMapper().to_host(0)


def test_a_stall_of_every_packet_does_not_move_the_mapping():
    """Every packet of 5 s arrives 2 s late (a stalled sender): the mapping keeps the line
    of the window instead of following the late packets (at most the height of one bin's
    minimum off while the first fast packets come back), and is back on it right after."""
    rng = np.random.default_rng(4)
    x, h = _stream(rng, 120 * 40, 10**12, 0.0, spikes=0.0)
    stall = (x - x[0] > 25e9) & (x - x[0] < 30e9)
    h[stall] += 2_000_000_000
    m = ClockMapper()
    errs = []
    for xi, hi in zip(x, h):
        m.add(int(xi), int(hi))
        errs.append(m.to_host(int(xi)) - (xi + 10**12))
    errs = np.array(errs) * 1e-3
    assert np.abs(errs[120 * 15 :]).max() < 500, np.abs(errs[120 * 15 :]).max()
    after = errs[120 * 32 :] - 30  # minimum transit 30 us
    assert np.abs(after).max() < 40, np.abs(after).max()


def test_a_step_of_the_tracker_clock_restarts_the_fit():
    """The tracker's clock jumps back by 5 s (a restart): once three samples agree, the fit
    starts again from the new stamps instead of calling every packet 5 s late; a jump forward
    likewise."""
    rng = np.random.default_rng(6)
    x, h = _stream(rng, 120 * 60, 10**12, 0.0, spikes=0.0)
    step = x - x[0] > 20e9
    x = x.copy()
    x[step] -= 5_000_000_000  # the same host arrivals, stamps 5 s lower
    m = ClockMapper()
    errs = []
    for xi, hi, st in zip(x, h, step):
        m.add(int(xi), int(hi))
        errs.append(m.to_host(int(xi)) - (xi + 10**12 + (5_000_000_000 if st else 0)))
    errs = np.array(errs) * 1e-3
    assert m.steps == 1
    after = errs[step][120:] - 30  # a second after the step
    assert np.abs(after).max() < 200, np.abs(after).max()
    # forward by 7 s: the first two samples are refused, the third confirms the step
    fwd = [(int(x[-1]) + 7_000_000_000 + k * 8_333_333, int(h[-1]) + 8_000_000 + k * 8_333_333)
           for k in range(3)]  # fmt: skip
    assert [m.add(*p) for p in fwd] == [False, False, True]
    assert m.steps == 2 and m.suspects == 2 + 2  # two held at the step back too
    assert m.to_host(fwd[0][0]) == fwd[0][1]
    m.reset()
    with pytest.raises(ValueError, match="no samples"):
        m.to_host(0)


def test_scatter_matches_monte_carlo_error():
    """Exponential delays over a 30 us minimum: the mapping's error about the minimum transit
    is the smallest delay's excess, whose spread the reported scatter (the gap to the
    second smallest bin minimum) matches in RMS over seeded runs."""
    err, scatter = [], []
    for seed in range(150):
        rng = np.random.default_rng(seed)
        x = np.arange(600, dtype=np.int64) * 10_000_000 + 10**9
        offset = -5_000_000_000  # host - remote
        h = x + offset + 30_000 + np.round(rng.exponential(300_000, x.shape)).astype(np.int64)
        m = ClockMapper()
        for xi, hi in zip(x, h):
            m.add(int(xi), int(hi))
        err.append(m.to_host(int(x[-1])) - (x[-1] + offset + 30_000))
        scatter.append(m.estimate.offset_sigma_ns)
    err, scatter = np.array(err, float), np.array(scatter)
    assert (err >= 0).all()  # the envelope never undercuts the fastest packet
    ratio = np.sqrt(np.mean(scatter**2) / np.mean(err**2))
    assert 0.75 < ratio < 1.35, ratio


@pytest.mark.skipif(not numba_available(), reason="numba not installed")
def test_compiled_envelope_fit_equals_the_reference():
    from trackflow.math import frozen, kernels_for, use_backend
    from trackflow.timesync import _kernels

    rng = np.random.default_rng(8)
    tx = np.cumsum(rng.integers(50_000_000, 150_000_000, 200)).astype(np.int64)
    y = 1e6 + 20e-6 * tx + rng.exponential(3e5, 200)
    args = (frozen(tx, np.int64), frozen(y), 10**10, 5e-4, 3 * 10**9, 1e5)
    ref = _kernels.envelope_fit(*args)
    with use_backend("numba"):
        fast = kernels_for(_kernels).envelope_fit(*args)
    np.testing.assert_allclose(fast, ref, rtol=1e-12)
    assert ref[3] > 0  # the scatter: the gap to the second lowest bin


@pytest.mark.parametrize("shift_ns", [5_000_000, 40_000_000, 7_000_000_000, -5_000_000_000])
def test_a_lone_corrupted_stamp_never_moves_the_mapping(shift_ns):
    """One stamp in a stream off by ``shift_ns`` (a flipped digit, a bogus value; more than
    ``jump_s`` plus the 2 ms delay jitter) every half second: each is a counted suspect,
    kept out of the fit (and refused when it is a step: more than 50 ms off), and the
    others are mapped exactly as the stream without those packets is."""
    rng = np.random.default_rng(11)
    x, h = _stream(rng, 120 * 30, 10**12, 10e-6, spikes=0.0)
    clean, dirty = ClockMapper(), ClockMapper()
    worst, taken = 0, []
    for k, (xi, hi) in enumerate(zip(x.tolist(), h.tolist())):
        if k % 60 == 59:
            taken.append(dirty.add(xi + shift_ns, hi))
            continue
        clean.add(xi, hi)
        assert dirty.add(xi, hi)
        worst = max(worst, abs(dirty.to_host(xi) - clean.to_host(xi)))
    step = abs(shift_ns) > 50_000_000
    assert taken == [not step] * (120 * 30 // 60)
    assert dirty.suspects == len(taken) and dirty.steps == 0
    assert worst == 0


def test_the_first_packets_may_be_slow():
    """The first two packets of a stream came 30 ms late (a sender starting up): the later,
    faster ones are no jump but the fit's floor, and none is held back."""
    rng = np.random.default_rng(12)
    x, h = _stream(rng, 120 * 5, 10**12, 0.0, spikes=0.0)
    h = h.copy()
    h[:2] += 30_000_000
    m = ClockMapper()
    assert all(m.add(int(a), int(b)) for a, b in zip(x, h)) and m.suspects == 0
    assert abs(m.to_host(int(x[-1])) - (int(x[-1]) + 10**12)) < 2_100_000


def test_a_corrupted_round_trip_never_shifts_the_mapping():
    """Round trips with a true 40 us transit take it out of the mapping; one whose remote
    stamp was corrupted (by 1.5 ms, or 10 s) is refused and counted, and the mapping stays."""
    rng = np.random.default_rng(13)
    x, h = _stream(rng, 120 * 5, 10**12, 0.0, spikes=0.0)
    m = ClockMapper()
    for k, (a, b) in enumerate(zip(x.tolist(), h.tolist())):
        m.add(a, b)
        if k % 12 == 0:  # a round trip of 80 us, 40 us each way
            send = b + 1_000_000
            assert m.add_round_trip(send, send + 40_000 - 10**12, send + 80_000)
    good = m.to_host(int(x[-1]))
    assert abs(good - (int(x[-1]) + 10**12)) < 20_000  # the 30 us transit taken out
    send = int(h[-1]) + 2_000_000
    for bad in (1_500_000, 10_000_000_000):
        assert not m.add_round_trip(send, send + 40_000 - 10**12 + bad, send + 60_000)
    assert m.rejected_round_trips == 2 and m.to_host(int(x[-1])) == good
