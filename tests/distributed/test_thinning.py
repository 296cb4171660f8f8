"""The thinning rule (trackflow.distributed.thinning): which state is sent for which tick."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackflow.distributed.thinning import (
    MAX_STREAMS_PER_EDGE,
    Grid,
    Thinner,
    ThinStreams,
    demand_key,
    next_tick,
    parse_demand,
    prev_tick,
)

MS = 1_000_000
GRACE = MS


def run(grids, events, end_ns, start_ns=0, step_ns=250_000):
    """Feed ``(h_ns, name)`` states to a thinner while a clock advances in ``step_ns`` steps
    (the timer calls ``due``); returns the messages sent ``(tick, name | None)``."""
    th = Thinner({g: 1 for g in grids}, start_ns)
    out = []
    events = sorted(events, key=lambda e: e[0])
    i = 0
    for now in range(start_ns, end_ns + 1, step_ns):
        while i < len(events) and events[i][0] <= now:
            out += th.offer(*events[i])
            i += 1
        out += th.due(now, GRACE)
    return th, out


def newest_before(events, tick):
    before = [name for h, name in sorted(events, key=lambda e: e[0]) if h <= tick]
    return before[-1] if before else None


def test_ticks_of_grids():
    g = [Grid(10, 3)]
    assert next_tick(3, g) == 3 and next_tick(4, g) == 13 and next_tick(-7, g) == -7
    assert prev_tick(3, g) == -7 and prev_tick(4, g) == 3 and prev_tick(14, g) == 13
    u = [Grid(10, 0), Grid(15, 0)]
    assert [next_tick(h, u) for h in (1, 11, 16, 21)] == [10, 15, 20, 30]


def test_one_state_per_tick_the_newest_before_it():
    """240 Hz states, a 60 Hz grid: each tick gets the newest state sent at or before it."""
    p = 16_666_667
    events = [(round(k * 1e9 / 240) + 100_000, k) for k in range(240)]
    th, out = run([Grid(p, 0)], events, 1_000 * MS)
    states = [(t, n) for t, n in out if n is not None]
    assert len(states) == 59  # ticks 1..59 (tick 0 precedes the first state)
    for tick, name in states:
        assert tick % p == 0 and name == newest_before(events, tick)
    assert th.late == 0 and th.heartbeats == 0  # none before the first state (tick 0)


def test_burst_sends_only_the_last_state_of_the_burst():
    events = [(5 * MS + k, f"b{k}") for k in range(50)] + [(12 * MS, "after")]
    _, out = run([Grid(10 * MS, 0)], events, 30 * MS)
    assert (10 * MS, "b49") in out and (20 * MS, "after") in out
    assert not any(n and n.startswith("b") and n != "b49" for _, n in out)


def test_gap_sends_heartbeats_then_resumes():
    events = [(1 * MS, "a"), (57 * MS, "b")]
    _, out = run([Grid(10 * MS, 0)], events, 70 * MS)
    assert out[0] == (10 * MS, "a")  # no heartbeat before the first state
    assert [t for t, n in out if n is None] == [20 * MS, 30 * MS, 40 * MS, 50 * MS]
    assert (60 * MS, "b") in out


def test_next_state_completes_the_tick_before_the_timer():
    """A state after the tick tells the thinner the previous one was the newest: it leaves
    then, before the grace period is over, completing every tick before the new state."""
    th = Thinner({Grid(10 * MS, 0): 1}, 0)
    assert th.offer(8 * MS, "x") == []  # tick 0 had nothing, but no state came before
    assert th.offer(10 * MS + 1, "y") == [(10 * MS, "x")]
    assert th.offer(45 * MS, "z") == [(40 * MS, "y")]  # also answers the ticks 20, 30 and 40
    assert th.due(50 * MS + GRACE - 1, GRACE) == []
    assert th.due(50 * MS + GRACE, GRACE) == [(50 * MS, "z")]


def test_out_of_order_send_stamps_and_late_states():
    th = Thinner({Grid(10 * MS, 0): 1}, 0)
    th.offer(12 * MS, "a")
    assert th.offer(9 * MS, "b") == []  # an earlier stamp after a later one: newest still
    assert th.due(21 * MS, GRACE) == [(20 * MS, "b")]
    # a state made before the completed tick but offered after it: sent at once, counted
    assert th.offer(19 * MS, "late") == [(20 * MS, "late")]
    assert th.late == 1


def test_consumer_faster_than_sensor_sends_every_state_once():
    """A 100 Hz grid on a 30 Hz sensor: no thinning, each state once, heartbeats between."""
    events = [(k * 33_333_333 + 2 * MS, k) for k in range(30)]
    th, out = run([Grid(10 * MS, 0)], events, 1_000 * MS)
    assert sorted(n for _, n in out if n is not None) == list(range(30))
    assert th.sent == 30 and th.heartbeats == 100 - 30 - 1  # ticks 10 .. 990 ms


def test_union_of_two_grids_serves_both_and_never_more_than_every_state():
    events = [(round(k * 1e9 / 240) + 50_000, k) for k in range(480)]
    grids = [Grid(33_333_333, 0), Grid(16_666_667, 5 * MS)]
    _, out = run(grids, events, 2_000 * MS)
    sent = {t: n for t, n in out if n is not None}
    for g in grids:  # every tick of each grid has its newest state in the stream
        for k in range(1, int(1.9e9 // g.period_ns)):
            tick = g.phase_ns + k * g.period_ns
            # the message completing the first union tick at or after this one
            t_done = min(t for t, _ in out if t >= tick)
            got = [n for t, n in out if t <= t_done and n is not None]
            assert got[-1] == newest_before(events, tick)
    assert len(sent) <= len(events)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.integers(0, 200 * MS), min_size=1, max_size=60),
    st.sampled_from([3 * MS, 10 * MS, 16_666_667, 33_333_333]),
    st.integers(0, 10 * MS),
)
def test_every_tick_gets_the_newest_state_before_it(stamps, period, phase):
    """Random send stamps: for every tick, the last state sent up to the message that
    completes the tick is the newest state made at or before it; each state at most once."""
    phase %= period
    events = [(h, i) for i, h in enumerate(sorted(stamps))]
    th, out = run([Grid(period, phase)], events, 250 * MS, step_ns=MS)
    names = [n for _, n in out if n is not None]
    assert len(names) == len(set(names)) and th.late == 0
    ticks = [t for t, _ in out]
    assert ticks == sorted(ticks)
    for tick in range(phase, 200 * MS, period):
        done = [k for k, (t, _) in enumerate(out) if t >= tick]
        if not done:
            continue
        want = newest_before(events, tick)
        if want is None:
            continue  # before the first state nothing is sent (no heartbeats either)
        got = [n for _, n in out[: done[0] + 1] if n is not None]
        assert got and got[-1] == want


def test_demand_keys_round_trip_and_garbage_is_rejected():
    key = demand_key("r", "e1", "app", Grid(16_666_667, 1234))
    assert parse_demand(key, "r") == ("e1", "app", Grid(16_666_667, 1234))
    bad = {
        "trackflow/r/demand/e1/app/16666667": "malformed demand",
        "trackflow/r/demand/e1/app/x/0": "malformed demand",
        "trackflow/r/demand/e1/app/-5/0": "malformed demand",
        "trackflow/q/demand/e1/app/16666667/0": "malformed demand",
        "trackflow/r/demand/e1/app/10/0": "demand period out of range",
        "trackflow/r/demand/e1/app/99999999999/0": "demand period out of range",
        "trackflow/r/demand/e1/app/16666667/16666667": "demand phase out of range",
    }
    for k, reason in bad.items():
        with pytest.raises(ValueError, match=reason):
            parse_demand(k, "r")


def test_thin_needs_a_deadline_and_is_off_by_default(tmp_path):
    from trackflow.dataflow import parse_setup
    from trackflow.distributed import AgentConfig, load_agent

    setup = parse_setup({})
    assert AgentConfig("a", setup).thin is False
    with pytest.raises(ValueError, match="thin: true needs reorder_ms > 0"):
        AgentConfig("a", setup, thin=True)
    with pytest.raises(ValueError, match="thin must be true or false"):
        AgentConfig("a", setup, thin="yes", reorder_ms=10)
    path = tmp_path / "a.yaml"
    path.write_text("agent: {name: a, thin: true, reorder_ms: 20, thin_grace_ms: 2}\n")
    cfg = load_agent(path)
    assert cfg.thin is True and cfg.thin_grace_ms == 2.0


class _Pub:
    def __init__(self, key):
        self.key, self.sent, self.closed = key, [], False

    def put(self, payload, attachment):
        self.sent.append((int.from_bytes(attachment, "little", signed=True), payload))

    def undeclare(self):
        self.closed = True


def test_stream_table_serves_each_consumer_its_union_and_ends_with_the_last_token():
    opened = []

    def open_publisher(key):
        opened.append(_Pub(key))
        return opened[-1]

    table = ThinStreams("r", open_publisher, lambda edge: 0)
    g30, g60 = Grid(33_333_333, 0), Grid(16_666_667, 0)
    keys = {
        "a30": demand_key("r", "s1", "a", g30),
        "a60": demand_key("r", "s1", "a", g60),
        "b30": demand_key("r", "s1", "b", g30),
    }
    for k in keys.values():
        assert table.declare(k, *parse_demand(k, "r"), now_ns=0) == ""
    assert [p.key for p in opened] == ["trackflow/r/thin/s1/a", "trackflow/r/thin/s1/b"]
    for k in range(1, 241):  # one second of a 240 Hz sensor
        h = round(k * 1e9 / 240)
        table.offer("s1", h, f"x{k}".encode(), now_ns=h)
    a, b = opened
    ticks_a = {t for t, p in a.sent}
    assert {k * g30.period_ns for k in range(1, 30)} <= ticks_a  # both of a's grids
    assert {k * g60.period_ns for k in range(1, 59)} <= ticks_a
    assert len([p for _, p in b.sent if p]) <= 31  # b only asked for 30 Hz
    assert len([p for _, p in a.sent if p]) <= 240
    assert table.status()["s1"]["a"]["grids"] == [[16_666_667, 0], [33_333_333, 0]]
    table.withdraw(keys["a60"])
    assert not a.closed and table.status()["s1"]["a"]["grids"] == [[33_333_333, 0]]
    table.withdraw(keys["a30"])
    assert a.closed and "a" not in table.status()["s1"]
    table.withdraw(keys["b30"])
    assert b.closed and table.status() == {}


def test_stream_table_limits_consumers_per_sensor():
    table = ThinStreams("r", _Pub, lambda edge: 0)
    g = Grid(10_000_000, 0)
    for i in range(MAX_STREAMS_PER_EDGE):
        k = demand_key("r", "s1", f"c{i}", g)
        assert table.declare(k, "s1", f"c{i}", g, 0) == ""
    k = demand_key("r", "s1", "one_more", g)
    assert table.declare(k, "s1", "one_more", g, 0) == "too many thinned streams"


def test_stream_table_holds_ticks_back_for_a_late_player():
    """A recording's player 5 ms late at a tick: the clock passing tick + grace does not
    complete the tick before the player has played what arrives by it; the state it then
    plays (made before the tick) is the tick's answer, not a late one."""
    progress = {"s1": None}
    table = ThinStreams("r", _Pub, lambda edge: GRACE, progress.get)
    g = Grid(10 * MS, 0)
    k = demand_key("r", "s1", "a", g)
    table.declare(k, "s1", "a", g, now_ns=0)
    (pub,) = [st.publisher for st in table.streams["s1"].values()]
    table.offer("s1", 4 * MS, b"x4", now_ns=4 * MS)  # on time
    progress["s1"] = 8 * MS - 1  # the sample arriving at 8 ms is not played yet
    table.flush(15 * MS)  # the clock is 5 ms past the tick at 10 ms
    assert pub.sent == []
    assert table.next_due == 16 * MS  # held: looked at again in 1 ms
    table.offer("s1", 8 * MS, b"x8", now_ns=15 * MS)  # played 7 ms late
    progress["s1"] = 12 * MS - 1
    table.flush(16 * MS)
    assert pub.sent == [(10 * MS, b"x8")]
    assert table.status()["s1"]["a"]["late"] == 0
    progress["s1"] = None  # the clock alone again (a live sensor): a heartbeat at 20 ms
    table.flush(21 * MS)
    assert pub.sent == [(10 * MS, b"x8"), (20 * MS, b"")]


def test_a_stream_opened_while_the_player_is_late_sends_nothing_late():
    """A demand that comes while the player is 200 ms behind: the states it still plays
    answer the ticks they were made before, none is late."""
    progress = {"s1": 100 * MS - 1}
    table = ThinStreams("r", _Pub, lambda edge: GRACE, progress.get)
    g = Grid(10 * MS, 0)
    table.declare(demand_key("r", "s1", "a", g), "s1", "a", g, now_ns=300 * MS)
    (pub,) = [st.publisher for st in table.streams["s1"].values()]
    made = range(100 * MS, 300 * MS, 4 * MS)
    for h in made:  # the player catches up
        table.offer("s1", h, str(h).encode(), now_ns=300 * MS)
        progress["s1"] = h + 4 * MS - 1
    assert table.status()["s1"]["a"]["late"] == 0
    assert [t for t, _ in pub.sent] == [k * 10 * MS for k in range(10, 30)]
    for t, p in pub.sent:  # the newest state at or before each tick
        assert int(p) == max(h for h in made if h <= t)
