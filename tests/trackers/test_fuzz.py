"""Every decoder fed random bytes, truncations and bit flips: a decoded message whose
numbers are all finite, or a :class:`PacketError` with one of the decoders' named reasons,
never another exception; and never a hang: each example runs under a watchdog that fails it
after 10 s of CPU-independent waiting (a bound on a hang, not a speed assertion: a decode
takes microseconds)."""

from __future__ import annotations

import math
import signal
from contextlib import contextmanager

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from trackflow.trackers import PacketError
from trackflow.trackers.dtrack import DTrackFrame, decode_dtrack
from trackflow.trackers.natnet import (
    SUPPORTED_VERSIONS,
    ModelDefinitions,
    NatNetFrame,
    ServerInfo,
    decode_frame,
    decode_message,
    decode_model_definitions,
    decode_server_info,
)
from trackflow.trackers.vrpn import PoseReport, StreamDecoder

from .test_dtrack import GOLDEN as DTRACK_GOLDEN
from .test_natnet import golden as natnet_golden
from .test_vrpn import COOKIE as VRPN_COOKIE
from .test_vrpn import _golden_stream

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])

#: every reason the decoders give (grep 'PacketError("' in dtrack.py, natnet.py, vrpn.py,
#: _packet.py): a rejection always names one of them
REASONS = {
    "bad count", "bad field", "bad length", "bad line", "bad rotation", "bad size",
    "bad stamp", "bad stamps", "bad string", "empty", "not ASCII", "not tracked",
    "oversized", "truncated", "unknown sender", "wrong version",
}  # fmt: skip


@contextmanager
def _watchdog(seconds: int = 10):
    """Fail (not hang) if the block has not returned after ``seconds``."""

    def expired(signum, frame):
        raise TimeoutError(f"a decoder ran for more than {seconds} s: a hang")

    old = signal.signal(signal.SIGALRM, expired)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def _finite(*values) -> bool:
    """Every number in ``values`` (nested tuples and lists) is finite."""
    out = True
    for v in values:
        if isinstance(v, (tuple, list)):
            out = out and _finite(*v)
        elif isinstance(v, float):
            out = out and math.isfinite(v)
    return out


def _outcome(fn, kinds):
    """``fn()``'s result, which must be one of ``kinds``; or None for a PacketError with a
    named reason."""
    try:
        with _watchdog():
            got = fn()
    except PacketError as exc:
        assert exc.reason in REASONS, exc.reason
        return None
    assert isinstance(got, kinds), type(got)
    return got


def _natnet(data: bytes, v) -> None:
    try:
        msg, payload = decode_message(data)
    except PacketError as exc:
        assert exc.reason in REASONS, exc.reason
        return
    f = _outcome(lambda: decode_frame(payload, v), NatNetFrame)
    if f is not None:
        for rb in f.rigid_bodies:  # decoded numbers are the wire's: finite or refused later
            assert len(rb.position) == 3 and len(rb.quaternion) == 4
    _outcome(lambda: decode_model_definitions(payload, v), ModelDefinitions)
    _outcome(lambda: decode_server_info(payload), ServerInfo)


def _dtrack(data: bytes) -> None:
    f = _outcome(lambda: decode_dtrack(data), DTrackFrame)
    if f is not None:
        for b in f.bodies:
            assert _finite(b.position_mm, b.rotation), b


def _vrpn(data: bytes, split: int) -> None:
    d = StreamDecoder()

    def both():
        return d.feed(data[:split]) + d.feed(data[split:])

    reports = _outcome(both, list)
    for r in reports or ():
        assert isinstance(r, PoseReport) and 0 <= r.usec < 1_000_000


def _flip(data: bytes, positions: list[int]) -> bytes:
    b = bytearray(data)
    for p in positions:
        b[(p // 8) % len(b)] ^= 1 << (p % 8)
    return bytes(b)


@FUZZ
@given(st.binary(max_size=2048), st.sampled_from(SUPPORTED_VERSIONS))
def test_natnet_random_bytes(data, v):
    _natnet(data, v)


@FUZZ
@given(st.sampled_from(SUPPORTED_VERSIONS), st.data())
def test_natnet_truncations_and_flips(v, data):
    raw = natnet_golden(v)
    cut = data.draw(st.integers(0, len(raw)))
    _natnet(raw[:cut], v)
    flips = data.draw(st.lists(st.integers(0, 8 * len(raw) - 1), min_size=1, max_size=8))
    _natnet(_flip(raw, flips), v)


@FUZZ
@given(st.binary(max_size=2048))
def test_dtrack_random_bytes(data):
    _dtrack(data)


@FUZZ
@given(st.text(alphabet="0123456789 .-[]\r\nfrts26dcov3i", max_size=400))
def test_dtrack_random_text(text):
    _dtrack(text.encode())


@FUZZ
@given(st.data())
def test_dtrack_truncations_and_flips(data):
    cut = data.draw(st.integers(0, len(DTRACK_GOLDEN)))
    _dtrack(DTRACK_GOLDEN[:cut])
    flips = data.draw(st.lists(st.integers(0, 8 * len(DTRACK_GOLDEN) - 1), min_size=1, max_size=8))
    _dtrack(_flip(DTRACK_GOLDEN, flips))


@FUZZ
@given(st.binary(max_size=2048), st.integers(0, 2048))
def test_vrpn_random_bytes(data, split):
    _vrpn(VRPN_COOKIE + data, split)
    _vrpn(data, split)


@FUZZ
@given(st.data())
def test_vrpn_truncations_and_flips(data):
    raw = _golden_stream()
    cut = data.draw(st.integers(0, len(raw)))
    _vrpn(raw[:cut], cut // 2)
    flips = data.draw(st.lists(st.integers(0, 8 * len(raw) - 1), min_size=1, max_size=8))
    _vrpn(_flip(raw, flips), data.draw(st.integers(0, len(raw))))


def test_the_watchdog_fails_a_hang():
    with pytest.raises(TimeoutError, match="a hang"):
        with _watchdog(1):
            signal.pause()  # waits for a signal: the alarm
