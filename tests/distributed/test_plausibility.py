"""Plausibility of decoded remote states: future stamps, covariance bounds, sequence jumps."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.distributed.plausibility import (
    FUTURE_NS,
    MAX_VARIANCE,
    SEQUENCE_JUMP,
    Sequences,
    state_problem,
)

NOW = 1_700_000_000_000_000_000
P = np.diag([1e-6] * 3 + [1e-5] * 3)


@pytest.mark.parametrize(
    "dt_ns, sigma_s, cov, why",
    [
        (-10_000_000, 0.0, P, None),  # 10 ms old: the usual
        (FUTURE_NS, 0.0, P, None),  # at the tolerance
        (FUTURE_NS + 1, 0.0, P, "stamp in the future"),
        (FUTURE_NS + 1, 1e-3, P, None),  # an uncertain clock widens it by 5 sigma
        (3_600_000_000_000, 1e-3, P, "stamp in the future"),  # an hour ahead
        (0, 0.0, np.diag([1e300] + [1e-6] * 5), "covariance beyond physical bounds"),
        (0, 0.0, np.diag([MAX_VARIANCE] * 6), None),
    ],
)
def test_state_problems(dt_ns, sigma_s, cov, why):
    assert state_problem(NOW + dt_ns, NOW, sigma_s, cov) == why


def test_sequences_count_gaps_refuse_jumps_and_follow_restarts():
    seq = Sequences()
    assert all(seq.take("art", n) for n in (1, 2, 5))  # 3 and 4 lost
    assert seq.lost == 2
    assert not seq.take("art", 180_876_052)  # a fake number: refused, not 180 M lost
    assert seq.take("art", 6) and seq.lost == 2  # the real stream goes on
    big = 6 + SEQUENCE_JUMP + 1
    assert not seq.take("art", big) and seq.take("art", big + 1)  # a jump, confirmed
    assert seq.lost == 2
    assert seq.take("art", 0) and seq.take("art", 1)  # a restarted sender counts again
    assert seq.take("other", 10**9) and seq.lost == 2  # every edge on its own
