"""One sign convention for the three estimators: ``offset = host - remote``, so that
``host = remote + offset``, whichever way the offset is measured."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.timesync import ClockMapper, RoundTripOffset, correlation_offset

#: the remote clock reads host time minus this [ns]: host = remote + OFFSET_NS
OFFSET_NS = 250_000_000


def _remote(host_ns):
    return np.asarray(host_ns) - OFFSET_NS


@pytest.mark.parametrize("sign", [1, -1])
def test_the_three_estimators_agree_on_the_sign(sign):
    off = sign * OFFSET_NS
    rng = np.random.default_rng(11)

    rt = RoundTripOffset()
    for k in range(10):  # a request at host t0, read on the remote clock 100 us later
        t0 = 10**9 + k * 10**7
        rt.add_round_trip(t0, t0 + 100_000 - off, t0 + 200_000)
    assert abs(rt.offset_ns - off) <= 3 * rt.sigma_ns + 1
    assert rt.to_host(5 * 10**9 - off) == 5 * 10**9

    env = ClockMapper()
    x = np.arange(500, dtype=np.int64) * 10_000_000 + 10**9  # remote stamps
    for xi in x:  # sent at remote xi = host xi + off, received 20..100 us later
        env.add(int(xi), int(xi) + off + int(rng.uniform(20_000, 100_000)))
    e = env.estimate
    assert abs(e.offset_ns - off - 20_000) < 5_000  # plus the minimum delay
    assert abs(env.to_host(int(x[-1])) - (int(x[-1]) + off)) < 25_000

    f = lambda t: np.sin(3.1 * t) + 0.5 * np.sin(7.3 * t + 1.0)  # noqa: E731
    th = np.arange(0.0, 10.0, 0.01)
    tr = np.arange(-2.0, 12.0, 0.01)  # remote stamps tau: host time tau + off
    r = correlation_offset(th, f(th), tr, f(tr + off * 1e-9), max_offset_s=0.5)
    assert abs(r.offset_s - off * 1e-9) < max(4 * r.sigma_s, 1e-4)
