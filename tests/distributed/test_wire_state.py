"""Wire encoding of filter states (version 2): golden bytes, round trips, fuzzing and counted
rejections."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackflow.distributed.wire import (
    Rejections,
    WireError,
    decode,
    decode_state,
    encode,
    encode_state,
)
from trackflow.filters import FilterSnapshot, MotionModel
from trackflow.math import Pose, UncertainPose, quat_exp

# Written out field by field from the layout in docs/wire.md (not produced by the encoder):
# a pose-only model (n_dp = n_do = 0): x = (t, q), 7 values; P is 6 x 6.
HEAD = (
    "5446"  # magic "TF"
    "02"  # version 2: filter state
    "01"  # flags: segment start
    "0700000000000000"  # seq 7
    "00ca9a3b00000000"  # state stamp 1_000_000_000 ns
    "206ba23b00000000"  # host 1_000_500_000 ns
    "c0878b3b00000000"  # origin 999_000_000 ns
    "00"  # n_dp 0
    "00"  # n_do 0
    "00"  # formulation error_state
    "00"  # reserved
    "0700"  # nx 7
    "0600"  # nc 6
    "00000000"  # reserved
)
X = (
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
GOLDEN = bytes.fromhex(HEAD + X + "".join(UPPER))
P6 = np.diag([1e-6] * 3 + [1e-4] * 3)
SNAP = FilterSnapshot(1.0, np.array([1.0, -2.0, 0.5, 0, 0, 0, 1]), P6, True)
STAMPS = dict(seq=7, stamp_ns=1_000_000_000, host_ns=1_000_500_000, origin_ns=999_000_000)


def test_golden_bytes():
    assert len(GOLDEN) == 48 + 7 * 8 + 21 * 8 == 272
    assert encode_state(SNAP, **STAMPS, n_dp=0, n_do=0) == GOLDEN
    s = decode_state(GOLDEN)
    assert (s.seq, s.stamp_ns, s.host_ns, s.origin_ns) == (7, 10**9, 1_000_500_000, 999_000_000)
    assert (s.n_dp, s.n_do, s.formulation, s.segment_start) == (0, 0, "error_state", True)
    assert np.array_equal(s.x, SNAP.x) and np.array_equal(s.p, P6)
    snap = s.snapshot(offset_ns=-250_000_000)  # the sender's clock is 250 ms ahead
    assert snap.t == pytest.approx(0.75) and snap.segment_start


def _model_state(n_dp, n_do, additive, rng):
    """A random state (unit quaternion at its place) and a random positive definite P."""
    m = MotionModel(n_dp, n_do)
    nx = m.state_size
    nc = nx if additive else m.error_size
    x = rng.normal(size=nx)
    if n_do >= 0:
        qo = 3 * (n_dp + 1)
        x[qo : qo + 4] = quat_exp(rng.normal(size=3))
    L = rng.normal(size=(nc, nc)) * 1e-2
    return x, L @ L.T + 1e-9 * np.eye(nc)


@settings(max_examples=100, deadline=None)
@given(
    n_dp=st.integers(-1, 3),
    n_do=st.integers(-1, 3),
    additive=st.booleans(),
    seed=st.integers(0, 2**32 - 1),
    seq=st.integers(0, 2**64 - 1),
    stamps=st.tuples(*[st.integers(-(2**63), 2**63 - 1)] * 3),
    segment=st.booleans(),
)
def test_round_trip_is_bit_exact(n_dp, n_do, additive, seed, seq, stamps, segment):
    if n_dp < 0 and n_do < 0:
        return
    x, p = _model_state(n_dp, n_do, additive, np.random.default_rng(seed))
    form = "additive" if additive else "error_state"
    b = encode_state(
        FilterSnapshot(0.0, x, p, segment),
        seq=seq,
        stamp_ns=stamps[0],
        host_ns=stamps[1],
        origin_ns=stamps[2],
        n_dp=n_dp,
        n_do=n_do,
        formulation=form,
    )
    s = decode_state(b)
    assert (s.seq, s.stamp_ns, s.host_ns, s.origin_ns) == (seq, *stamps)
    assert (s.n_dp, s.n_do, s.formulation, s.segment_start) == (n_dp, n_do, form, segment)
    assert np.array_equal(s.x, x)
    iu = np.triu_indices(len(p))
    assert np.array_equal(s.p[iu], p[iu]) and np.array_equal(s.p, s.p.T)


@settings(max_examples=500, deadline=None)
@given(st.binary(max_size=900))
def test_random_bytes_never_crash(data):
    try:
        decode_state(data)
    except WireError as exc:
        assert exc.reason


@settings(max_examples=300, deadline=None)
@given(st.integers(0, len(GOLDEN) - 1), st.integers(0, 255))
def test_any_flipped_byte_decodes_or_is_a_counted_rejection(where, value):
    b = bytearray(GOLDEN)
    b[where] = value
    try:
        s = decode_state(bytes(b))
    except WireError as exc:
        assert exc.reason
    else:  # what decodes is a usable state: finite, unit quaternion, P positive definite
        assert np.all(np.isfinite(s.x)) and abs(np.linalg.norm(s.x[3:7]) - 1) < 1e-6
        assert np.all(np.linalg.eigvalsh(s.p) > 0)


def _rejection(data) -> str:
    with pytest.raises(WireError) as info:
        decode_state(data)
    return info.value.reason


def test_rejection_reasons_are_counted():
    def at(offset, fmt, value):
        return GOLDEN[:offset] + struct.pack(fmt, value) + GOLDEN[offset + struct.calcsize(fmt) :]

    pose = encode(UncertainPose(Pose.identity(), P6), seq=1, exposure_ns=0, host_ns=0)
    bad = {
        "unknown version": at(2, "<B", 7),
        "wrong kind": pose,  # a pose message where a state is expected
        "bad magic": b"XX" + GOLDEN[2:],
        "truncated": GOLDEN[:40],
        "unknown flags": at(3, "<B", 0x81),
        "unknown motion model": at(36, "<b", 9),
        "state size": at(40, "<H", 8),
        "wrong length": GOLDEN + b"\x00" * 8,
        "non-finite": at(48, "<d", np.inf),
        "non-unit quaternion": at(48 + 6 * 8, "<d", 2.0),
        "invalid covariance": at(48 + 7 * 8, "<d", -1e-6),
    }
    r = Rejections()
    for reason, data in bad.items():
        got = _rejection(data)
        assert got == reason, (reason, got)
        r.add(got)
    assert r.total == len(bad)
    # and the other way round: a pose decoder refuses a state as the other kind
    with pytest.raises(WireError, match="wrong kind"):
        decode(GOLDEN)
