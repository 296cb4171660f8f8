"""Clock checks of other agents (``Discovery.check_clocks``): only the agents this agent
receives sensors from, and less often while an offset holds still (a realm of N agents made
N x (N - 1) checks every 2 s)."""

from __future__ import annotations

import threading

import pytest

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (pip install .[distributed])")

from trackflow.distributed.discovery import (
    CLOCK_PERIOD_MAX_S,
    CLOCK_PERIOD_S,
    Discovery,
    RemoteAgent,
)
from trackflow.distributed.wire import Rejections


class _Reply:
    def __init__(self, remote_ns: int):
        self.ok = self
        self.payload = self
        self._b = int(remote_ns).to_bytes(8, "little", signed=True)

    def to_bytes(self) -> bytes:
        return self._b


class _Clocks:
    """A stand-in Zenoh session answering ``clock/<agent>`` with that agent's clock: this
    host's minus its offset; counts the questions."""

    def __init__(self, host, offsets_ns: dict[str, int]):
        self.host, self.offsets_ns = host, offsets_ns
        self.asked: list[str] = []

    def get(self, key: str, timeout: float):
        agent = key.rsplit("/", 1)[-1]
        self.asked.append(agent)
        self.host[0] += 20_000  # 20 us each way
        reply = _Reply(self.host[0] - self.offsets_ns[agent])
        self.host[0] += 20_000
        return [reply]


def _discovery(needed):
    host = [10**15]
    d = Discovery("me", "r", threading.RLock(), Rejections(), lambda *a: None, lambda: None,
                  lambda: set(needed))  # fmt: skip
    d.now_ns = lambda: host[0]
    d.session = _Clocks(host, {"a": 5_000_000, "b": -3_000_000})
    for name in ("a", "b"):
        d.remotes[name] = RemoteAgent(name)
        d.live[f"s_{name}"] = name
    return d


def test_only_the_clocks_of_agents_followed_are_checked():
    needed = {"a"}
    d = _discovery(needed)
    assert d.check_clocks(0.0) == 1 and d.session.asked == ["a"]
    assert d.remotes["a"].clock.offset_ns == pytest.approx(5_000_000, abs=1)
    needed.add("b")  # a plan now receives b's sensor
    d.check_clocks(0.0)
    assert d.session.asked == ["a", "b"]


def test_a_still_offset_is_checked_less_often_and_a_moved_one_at_once_again():
    d = _discovery({"a"})
    a = d.remotes["a"]
    t, periods = 0.0, []
    for _ in range(6):  # every round of the clock thread for 40 s
        while d.check_clocks(t) == 0:
            t += CLOCK_PERIOD_S
        periods.append(a.clock_period_s)
        t += CLOCK_PERIOD_S
    # the first check has nothing to compare with; then 4, 8, 8 ... s
    assert periods == [CLOCK_PERIOD_S, 4.0, CLOCK_PERIOD_MAX_S, 8.0, 8.0, 8.0]
    d.session.offsets_ns["a"] += 2_000_000  # the remote's clock was set 2 ms back
    d.session.host[0] += 10**10  # (later: its better round trips are still in the window)
    for _ in range(40):  # until the estimate follows (the window's best round trip ages out)
        while d.check_clocks(t) == 0:
            t += CLOCK_PERIOD_S
        t += CLOCK_PERIOD_S
        if a.clock_period_s == CLOCK_PERIOD_S:
            break
    assert a.clock_period_s == CLOCK_PERIOD_S
    assert d.clocks()["a"]["period_s"] == CLOCK_PERIOD_S
