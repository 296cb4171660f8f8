"""Wire encoding of state batches (version 3): golden bytes, round trips, fuzzing and counted
rejections; and the agent-side batch that gathers one dispatch round's states."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from test_wire_state import GOLDEN as STATE  # a version-2 state, written out from docs/wire.md

from trackflow.dataflow import Scheduler, WallTime
from trackflow.distributed.replica import StateBatch
from trackflow.distributed.wire import (
    MAX_BATCH,
    WireError,
    decode_batch,
    decode_state,
    encode_batch,
)
from trackflow.errors import InputError

# Written out field by field from the layout in docs/wire.md: two states, of "s1" and "art"
GOLDEN = (
    bytes.fromhex(
        "5446"  # magic "TF"
        "03"  # version 3: state batch
        "00"  # flags
        "0200"  # count 2
        "0000"  # reserved
        "02" + b"s1".hex() + "1001"  # name length 2, "s1", state length 272
    )
    + STATE
    + bytes.fromhex("03" + b"art".hex() + "1001")
    + STATE
)


def test_golden_bytes():
    assert len(STATE) == 272
    assert encode_batch([("s1", STATE), ("art", STATE)]) == GOLDEN
    entries = decode_batch(GOLDEN)
    assert [e for e, _ in entries] == ["s1", "art"]
    assert all(s == STATE for _, s in entries)
    assert decode_state(entries[1][1]).seq == 7


@given(st.lists(st.tuples(st.from_regex(r"[A-Za-z0-9_-]{1,255}", fullmatch=True),
                          st.binary(max_size=2000)), min_size=1, max_size=40))  # fmt: skip
def test_round_trip_is_exact(entries):
    assert decode_batch(encode_batch(entries)) == entries


def test_the_encoder_refuses_what_cannot_be_sent():
    with pytest.raises(InputError, match="1 to 1024 states, not 0"):
        encode_batch([])
    with pytest.raises(InputError, match="1 to 1024 states"):
        encode_batch([("s", STATE)] * (MAX_BATCH + 1))
    for name in ("", "a/b", "x" * 256, "ü"):
        with pytest.raises((InputError, UnicodeEncodeError)):
            encode_batch([(name, STATE)])


@given(st.binary(max_size=1200))
def test_random_bytes_never_crash(data):
    try:
        decode_batch(data)
    except WireError as exc:
        assert exc.reason


@given(st.integers(0, len(GOLDEN) - 1), st.integers(0, 255))
def test_any_flipped_byte_decodes_or_is_a_counted_rejection(where, value):
    buf = bytearray(GOLDEN)
    buf[where] = value
    try:
        entries = decode_batch(bytes(buf))
    except WireError as exc:
        assert exc.reason in {"bad magic", "unknown version", "wrong kind", "unknown flags",
                              "empty batch", "bad edge name", "truncated",
                              "wrong length"}  # fmt: skip
        return
    # a byte inside a state or a name that is still a name: the frame holds together
    assert len(entries) == 2 and sum(len(s) for _, s in entries) == 2 * len(STATE)


@pytest.mark.parametrize(
    ("buf", "reason"),
    [
        (GOLDEN[:3], "truncated"),
        (b"XX" + GOLDEN[2:], "bad magic"),
        (GOLDEN[:2] + b"\x02" + GOLDEN[3:], "wrong kind"),
        (GOLDEN[:2] + b"\x09" + GOLDEN[3:], "unknown version"),
        (GOLDEN[:3] + b"\x01" + GOLDEN[4:], "unknown flags"),
        (GOLDEN[:4] + b"\x00\x00" + GOLDEN[6:], "empty batch"),
        (GOLDEN[:4] + b"\x03\x00" + GOLDEN[6:], "truncated"),
        (GOLDEN[:4] + b"\x01\x00" + GOLDEN[6:], "wrong length"),
        (GOLDEN[:8] + b"\x00" + GOLDEN[9:], "bad edge name"),
        (GOLDEN[:9] + b"/" + GOLDEN[10:], "bad edge name"),
        (GOLDEN[:-1], "truncated"),
        (GOLDEN + b"\x00", "wrong length"),
    ],
)
def test_each_broken_frame_names_its_problem(buf, reason):
    with pytest.raises(WireError) as err:
        decode_batch(buf)
    assert err.value.reason == reason


class _Put:
    def __init__(self):
        self.messages: list[bytes] = []

    def put(self, buf: bytes) -> None:
        self.messages.append(buf)


class _Clock:
    now_ns = 0
    dispatch_wall_ns = 0


def test_one_dispatch_round_leaves_as_one_message():
    """The states put during one scheduler round (here: three sensors' samples at one
    time) leave as one batch when the scheduler has dispatched them; the next time's
    states in the next message."""
    out = _Put()
    batch = StateBatch(out)
    sched = Scheduler(_Clock())
    sched.drained.append(batch.flush)
    slots = {e: batch.slot(e) for e in ("a", "b", "c")}
    for t in (10, 20):
        for e, slot in slots.items():
            sched.post(t, lambda _t, s=slot, e=e: s.put(STATE[:-1] + bytes([ord(e)])))
    sched.run()
    assert batch.messages == 2 and len(out.messages) == 2
    for msg in out.messages:
        assert [(e, s[-1]) for e, s in decode_batch(msg)] == [(e, ord(e)) for e in "abc"]


def test_a_backlog_on_the_wall_clock_leaves_one_message_per_time():
    """A wall-clock scheduler behind its events (all released at once, so it never waits
    between them) still sends each time's states when it moves on to the next time, and the
    last time's at the run's end."""
    out = _Put()
    batch = StateBatch(out)
    sched = Scheduler(_Clock(), WallTime())
    sched.drained.append(batch.flush)
    slots = {e: batch.slot(e) for e in ("a", "b", "c")}
    for t in (10, 20, 30):  # (1970: long released)
        for e, slot in slots.items():
            sched.post(t, lambda _t, s=slot, e=e: s.put(STATE[:-1] + bytes([ord(e)])))
    sched.run(until_ns=30)
    assert batch.messages == 3 and len(out.messages) == 3
    for msg in out.messages:
        assert [(e, s[-1]) for e, s in decode_batch(msg)] == [(e, ord(e)) for e in "abc"]


def test_an_arrival_block_sends_what_it_made():
    """States made in a receiving thread's :meth:`Scheduler.arrival` block (a tracker's
    frame dispatched where it arrived) leave at the block's end."""
    out = _Put()
    batch = StateBatch(out)
    sched = Scheduler(_Clock(), WallTime())
    sched.drained.append(batch.flush)
    with sched.arrival(1) as arr:
        arr.deliver(2, lambda lo, hi, _t: [batch.slot(f"s{k}").put(STATE) for k in range(lo, hi)])
        assert out.messages == []  # nothing leaves within the round
    assert [e for e, _ in decode_batch(out.messages[0])] == ["s0", "s1"]


def test_a_full_batch_leaves_at_once():
    out = _Put()
    batch = StateBatch(out)
    slot = batch.slot("s")
    for _ in range(MAX_BATCH + 3):
        slot.put(STATE)
    assert len(out.messages) == 1 and len(decode_batch(out.messages[0])) == MAX_BATCH
    batch.flush()
    assert len(decode_batch(out.messages[1])) == 3
    batch.flush()  # nothing gathered: nothing sent
    assert len(out.messages) == 2 and np.all([m[:3] == b"TF\x03" for m in out.messages])
