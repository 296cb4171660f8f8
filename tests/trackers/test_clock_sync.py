"""NatNet round-trip clock synchronisation: the echo messages' golden bytes, the transit delay
the clock mapping removes with round trips, and the input's handling of echo answers."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.dataflow import parse_input
from trackflow.timesync import ClockMapper
from trackflow.trackers import PacketError, natnet
from trackflow.trackers.inputs import make_input

FREQ = 10_000_000


def test_echo_messages_golden_bytes():
    token, ticks = 0x0102030405060708, 0x1112131415161718
    req = natnet.encode_echo_request(token)
    assert req == b"\x0c\x00\x08\x00" + bytes([8, 7, 6, 5, 4, 3, 2, 1])
    resp = natnet.encode_echo_response(token, ticks)
    assert resp == (
        b"\x0d\x00\x10\x00" + bytes([8, 7, 6, 5, 4, 3, 2, 1])
        + bytes([0x18, 0x17, 0x16, 0x15, 0x14, 0x13, 0x12, 0x11])
    )  # fmt: skip
    msg, payload = natnet.decode_message(resp)
    assert msg == natnet.ECHORESPONSE
    assert natnet.decode_echo_response(payload) == (token, ticks)
    with pytest.raises(PacketError) as e:
        natnet.decode_echo_response(payload[:15])
    assert e.value.reason == "truncated"


def _one_way(rng, n, offset, transit):
    """(tracker stamp, host receive time) of ``n`` packets 4 ms apart [ns]: the host clock
    is the tracker's plus ``offset``; each packet takes ``transit`` plus an exponential
    delay of mean 200 us."""
    x = 1_000_000_000_000 + np.arange(n) * 4_000_000
    h = x + offset + transit + rng.exponential(200_000, n).astype(np.int64)
    return x, h


def test_round_trips_remove_the_minimum_transit_delay():
    rng = np.random.default_rng(5)
    offset, transit = 3_600_500_000_000, 300_000  # host = tracker + 1 h; 300 us each way
    x, h = _one_way(rng, 3000, offset, transit)
    one_way, synced = ClockMapper(), ClockMapper()
    for k, (xi, hi) in enumerate(zip(x, h)):
        one_way.add(int(xi), int(hi))
        synced.add(int(xi), int(hi))
        if k % 25 == 0:  # a round trip: 300 us + up to 100 us each way
            send = int(hi) + 1_000_000
            answered = send - offset + transit + int(rng.uniform(0, 100_000))
            synced.add_round_trip(send, answered, answered + offset + transit
                                  + int(rng.uniform(0, 100_000)))  # fmt: skip
    truth = int(x[-1]) + offset
    err_one_way = one_way.to_host(int(x[-1])) - truth
    err_synced = synced.to_host(int(x[-1])) - truth
    # one way: the mapping is late by the minimum delay (300 us + the smallest jitter)
    assert 290_000 < err_one_way < 320_000
    # with round trips: within the asymmetry of the shortest one (here < 100 us / 2)
    assert abs(err_synced) < 60_000, err_synced
    e = synced.estimate
    assert 250_000 < e.transit_ns < 320_000 and 300_000 <= e.transit_sigma_ns < 400_000
    assert e.offset_ns == one_way.estimate.offset_ns  # the envelope itself is unchanged


def test_bad_round_trips_are_counted_and_a_reset_forgets_them():
    c = ClockMapper(max_rtt_s=0.01)
    c.add(1_000, 2_000)
    assert not c.add_round_trip(5_000, 3_000, 4_000)  # received before it was sent
    assert not c.add_round_trip(0, 3_000, 20_000_000)  # 20 ms > 10 ms
    assert c.rejected_round_trips == 2 and c.estimate.transit_ns == 0.0
    assert c.add_round_trip(1_500, 1_000, 1_700)
    assert c.estimate.transit_ns == 1_000 - (1_600 - 1_000) - 0  # line at x minus midpoint
    c.reset()
    assert not c.round_trips and c.estimate is None


def test_natnet_input_uses_echo_answers():
    inp = make_input("s", parse_input({"natnet": {"body": 3}}), np.eye(6) * 1e-6)
    resp = natnet.encode_echo_response(5_000_000, 42)
    assert inp.handle(resp, 5_100_000) == []
    assert inp.status.rejections == {"no handshake yet": 1}
    info = natnet.ServerInfo(clock_frequency=FREQ)
    inp.handle(natnet.encode_server_info(info), 0)
    ticks = 7 * FREQ  # the server answered at tracker time 7 s
    inp.handle(natnet.encode_echo_response(100_000_000_000, ticks), 100_000_200_000)
    ((x, rtt, mid),) = inp.clock.round_trips
    assert x == 7_000_000_000 and rtt == 200_000 and mid == 100_000_100_000 - 7_000_000_000
    inp.handle(natnet.encode_echo_response(100_000_300_000, ticks), 100_000_000_000)
    assert inp.status.rejections["bad round trip"] == 1
    assert inp.echo and inp._echo_due(1.0, 0.0)
    inp.handle(natnet.encode_message(natnet.UNRECOGNIZED), 0)
    assert not inp.echo and not inp._echo_due(10.0, 0.0)  # an old server is not asked again
