"""A StatusGroup counts what a packet does to every body once; every reader of the members'
statuses sees what counting each body on its own gives: random sequences of group and
per-body operations, reads in between, a small flush threshold, and a reader thread."""

from __future__ import annotations

import threading

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackflow.trackers.status import SensorStatus, StatusGroup

from .test_natnet_pass import status_of

N = 3
op = st.one_of(
    st.tuples(st.just("packet")),
    st.tuples(st.just("next_frame"), st.integers(-2, 12)),
    st.tuples(st.just("measured"), st.integers(0, 10**6), st.integers(0, 10**6)),
    st.tuples(st.just("own_measured"), st.integers(0, N - 1), st.integers(0, 10**6)),
    st.tuples(st.just("own_frame"), st.integers(0, N - 1), st.integers(-2, 12)),
    st.tuples(st.just("set_frame"), st.integers(0, N - 1), st.integers(-2, 12)),
    st.tuples(st.just("reject"), st.integers(0, N - 1)),
    st.tuples(st.just("read"), st.integers(0, N - 1)),
)


def _pair():
    group = StatusGroup()
    grouped = [SensorStatus(f"s{k}", "natnet") for k in range(N)]
    for s in grouped:
        group.add(s)
    return group, grouped, [SensorStatus(f"s{k}", "natnet") for k in range(N)]


def _apply(o, group, grouped, alone):
    kind = o[0]
    if kind == "packet":
        group.packet()
        for s in alone:
            s.packets += 1
    elif kind == "next_frame":
        n = o[1]
        want = all(s.last_frame == n - 1 for s in alone)
        assert group.next_frame(n) == want
        if want:
            for s in alone:
                s.last_frame = n
    elif kind == "measured":
        group.measured(o[1], o[2])
        for s in alone:
            s.measured(o[1], o[2])
    elif kind == "own_measured":
        grouped[o[1]].measured(o[2], 7)
        alone[o[1]].measured(o[2], 7)
    elif kind == "own_frame":
        assert grouped[o[1]].frame(o[2]) == alone[o[1]].frame(o[2])
    elif kind == "set_frame":
        grouped[o[1]].last_frame = alone[o[1]].last_frame = o[2]
    elif kind == "reject":
        grouped[o[1]].reject("not tracked")
        alone[o[1]].reject("not tracked")
    else:
        assert status_of(grouped[o[1]]) == status_of(alone[o[1]])


@settings(max_examples=150, deadline=None)
@given(st.lists(op, max_size=60), st.sampled_from([1, 3, 256]))
def test_group_reads_as_each_body_counted_alone(ops, flush_at):
    group, grouped, alone = _pair()
    group.FLUSH_AT = flush_at
    for o in ops:
        _apply(o, group, grouped, alone)
    for a, b in zip(grouped, alone):
        assert status_of(a) == status_of(b)


def test_a_status_joins_one_group_only():
    group, grouped, _ = _pair()
    with pytest.raises(ValueError, match="already in a group"):
        StatusGroup().add(grouped[0])
    assert group.members == grouped


def test_readers_in_another_thread_see_consistent_figures():
    """The receiving thread counts while another thread reads (as the status line does):
    the final figures are those of bodies counted alone, and no read fails."""
    group, grouped, alone = _pair()
    stop = threading.Event()
    errors = []

    def read():
        try:
            while not stop.is_set():
                for s in grouped:
                    s.summary(10**6)
        except Exception as exc:  # any failure of a reader is the finding
            errors.append(exc)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        for i in range(3000):
            _apply(("packet",), group, grouped, alone)
            _apply(("next_frame", i), group, grouped, alone)
            if i % 97 == 0:
                _apply(("own_frame", i % N, i), group, grouped, alone)
            _apply(("measured", 1000 + i, i), group, grouped, alone)
    finally:
        stop.set()
        reader.join(5.0)
    assert not reader.is_alive() and errors == []
    for a, b in zip(grouped, alone):
        assert status_of(a) == status_of(b)
