"""Every decoder fed random bytes, truncations and bit flips: a frame or a PacketError,
never another exception (and never a hang: inputs are bounded)."""

from __future__ import annotations

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from trackflow.trackers import PacketError
from trackflow.trackers.dtrack import decode_dtrack
from trackflow.trackers.natnet import (
    SUPPORTED_VERSIONS,
    decode_frame,
    decode_message,
    decode_model_definitions,
    decode_server_info,
)
from trackflow.trackers.vrpn import StreamDecoder

from .test_dtrack import GOLDEN as DTRACK_GOLDEN
from .test_natnet import golden as natnet_golden
from .test_vrpn import _golden_stream

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _natnet(data: bytes, v) -> None:
    try:
        msg, payload = decode_message(data)
    except PacketError:
        return
    for fn in (
        lambda: decode_frame(payload, v),
        lambda: decode_model_definitions(payload, v),
        lambda: decode_server_info(payload),
    ):
        try:
            fn()
        except PacketError:
            pass


def _dtrack(data: bytes) -> None:
    try:
        decode_dtrack(data)
    except PacketError:
        pass


def _vrpn(data: bytes, split: int) -> None:
    d = StreamDecoder()
    try:
        d.feed(data[:split])
        d.feed(data[split:])
    except PacketError:
        pass


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
    _vrpn(b"vrpn: ver. 07.35  0\0\0\0\0\0" + data, split)
    _vrpn(data, split)


@FUZZ
@given(st.data())
def test_vrpn_truncations_and_flips(data):
    raw = _golden_stream()
    cut = data.draw(st.integers(0, len(raw)))
    _vrpn(raw[:cut], cut // 2)
    flips = data.draw(st.lists(st.integers(0, 8 * len(raw) - 1), min_size=1, max_size=8))
    _vrpn(_flip(raw, flips), data.draw(st.integers(0, len(raw))))
