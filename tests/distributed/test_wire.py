"""Wire encoding: golden bytes, round trips, fuzzing and counted rejections."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackflow.distributed.wire import Rejections, WireError, decode, encode
from trackflow.math import Pose, UncertainPose

COV = np.diag([1e-6] * 3 + [1e-4] * 3)
POSE = UncertainPose(Pose([1.0, -2.0, 0.5], [0, 0, 0, 1]), COV)

# Written out field by field from the layout in docs/wire.md (not produced by the encoder).
HEAD = (
    "5446"  # magic "TF"
    "01"  # version 1
    "{flags}"
    "0700000000000000"  # seq 7
    "00ca9a3b00000000"  # exposure 1_000_000_000 ns
    "206ba23b00000000"  # host 1_000_500_000 ns
    "c0878b3b00000000"  # origin 999_000_000 ns
    "000000000000f03f"
    "00000000000000c0"
    "000000000000e03f"  # position 1, -2, 0.5
    "0000000000000000"
    "0000000000000000"
    "0000000000000000"
    "000000000000f03f"  # q identity
)
E6 = "8dedb5a0f7c6b03e"  # 1e-6
E4 = "2d431cebe2361a3f"  # 1e-4
Z = "0000000000000000"
UPPER = [E6, Z, Z, Z, Z, Z, E6, Z, Z, Z, Z, E6, Z, Z, Z, E4, Z, Z, E4, Z, E4]
GOLDEN_COV = bytes.fromhex(HEAD.format(flags="01") + "".join(UPPER))
GOLDEN_NOCOV = bytes.fromhex(HEAD.format(flags="00"))
STAMPS = dict(seq=7, exposure_ns=1_000_000_000, host_ns=1_000_500_000, origin_ns=999_000_000)


def test_golden_bytes():
    assert len(GOLDEN_COV) == 260 and len(GOLDEN_NOCOV) == 92
    assert encode(POSE, **STAMPS) == GOLDEN_COV
    assert encode(POSE, **STAMPS, covariance=False) == GOLDEN_NOCOV
    s = decode(GOLDEN_COV)
    assert (s.seq, s.exposure_ns, s.host_ns, s.origin_ns) == (7, 10**9, 1_000_500_000, 999_000_000)
    assert np.array_equal(s.pose.position, [1.0, -2.0, 0.5])
    assert np.array_equal(s.pose.covariance, COV)
    assert np.array_equal(decode(GOLDEN_NOCOV).pose.covariance, np.zeros((6, 6)))


def test_golden_bytes_with_the_answers_path():
    """Flag bit 1: the index of the query's candidate path, uint16, after the covariance."""
    with_cov = bytes.fromhex(HEAD.format(flags="03") + "".join(UPPER) + "0200")
    without = bytes.fromhex(HEAD.format(flags="02") + "0100")
    assert encode(POSE, **STAMPS, path=2) == with_cov and len(with_cov) == 262
    assert encode(POSE, **STAMPS, covariance=False, path=1) == without
    assert decode(with_cov).path == 2 and decode(without).path == 1
    assert np.array_equal(decode(with_cov).pose.covariance, COV)
    assert decode(GOLDEN_COV).path is None  # no flag: no path
    assert _rejection(with_cov[:-1]) == "truncated"
    assert _rejection(GOLDEN_COV[:3] + b"\x03" + GOLDEN_COV[4:]) == "truncated"
    with pytest.raises(ValueError, match="path index"):
        encode(POSE, **STAMPS, path=70_000)


finite = st.floats(-1e6, 1e6, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(
    pos=st.tuples(finite, finite, finite),
    rot=st.tuples(*[st.floats(-3.0, 3.0)] * 3),
    chol=st.lists(st.floats(-1e-2, 1e-2), min_size=36, max_size=36),
    seq=st.integers(0, 2**64 - 1),
    stamps=st.tuples(*[st.integers(-(2**63), 2**63 - 1)] * 3),
)
def test_round_trip_is_bit_exact(pos, rot, chol, seq, stamps):
    from trackflow.math import quat_exp

    q = quat_exp(np.array(rot))
    L = np.array(chol).reshape(6, 6)
    C = L @ L.T
    pose = UncertainPose(Pose(pos, q), C)
    b = encode(pose, seq=seq, exposure_ns=stamps[0], host_ns=stamps[1], origin_ns=stamps[2])
    s = decode(b)
    assert (s.seq, s.exposure_ns, s.host_ns, s.origin_ns) == (seq, *stamps)
    assert np.array_equal(s.pose.position, pose.position)
    # the bits travel exactly; the receiving Pose renormalises to the last bit
    assert np.allclose(s.pose.quaternion, pose.quaternion, rtol=0, atol=4e-16)
    iu = np.triu_indices(6)
    assert np.array_equal(s.pose.covariance[iu], pose.covariance[iu])
    assert np.array_equal(s.pose.covariance, s.pose.covariance.T)


@settings(max_examples=500, deadline=None)
@given(st.binary(max_size=300))
def test_random_bytes_never_crash(data):
    try:
        decode(data)
    except WireError as exc:
        assert exc.reason


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 259), st.integers(0, 255))
def test_any_flipped_byte_decodes_or_is_a_counted_rejection(where, value):
    b = bytearray(GOLDEN_COV)
    b[where] = value
    try:
        s = decode(bytes(b))
    except WireError as exc:
        assert exc.reason
    else:
        assert s.pose.covariance.shape == (6, 6)


def _rejection(data) -> str:
    with pytest.raises(WireError) as info:
        decode(data)
    return info.value.reason


def test_rejection_reasons_are_counted():
    r = Rejections()
    bad = {
        "unknown version": GOLDEN_COV[:2] + b"\x04" + GOLDEN_COV[3:],
        "wrong kind": GOLDEN_COV[:2] + b"\x02" + GOLDEN_COV[3:],  # a filter state
        "bad magic": b"XX" + GOLDEN_COV[2:],
        "truncated": GOLDEN_COV[:100],
        "wrong length": GOLDEN_COV + b"\x00",
        "unknown flags": GOLDEN_COV[:3] + b"\x05" + GOLDEN_COV[4:],
        "non-finite": GOLDEN_COV[:36] + struct.pack("<d", np.nan) + GOLDEN_COV[44:],
        "non-unit quaternion": GOLDEN_COV[:84] + struct.pack("<d", 2.0) + GOLDEN_COV[92:],
        "invalid covariance": GOLDEN_COV[:92] + struct.pack("<d", -1.0) + GOLDEN_COV[100:],
    }
    for reason, data in bad.items():
        got = _rejection(data)
        assert got == reason
        r.add(got)
    r.add(_rejection(GOLDEN_COV[:2] + b"\x09" + GOLDEN_COV[3:]))
    assert r.counts["unknown version"] == 2 and r.total == len(bad) + 1
