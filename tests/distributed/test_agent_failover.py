"""Failover across agents (real processes): the agent of the preferred sensor freezes
(SIGSTOP, so Zenoh still sees it alive); the application agent's query moves to the other
agent's path once the preferred sensor's newest state is older than the stale time, drops
the backlog the frozen agent flushes when it continues (counted), and returns to the
preferred path after the hold time."""

from __future__ import annotations

import signal
import time

import pytest

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (pip install .[distributed])")

from _agents import AgentProcess, endpoint, free_port, observer, status, wait_for
from test_agents_processes import PERIOD_NS, _files, _query

from trackflow.dataflow._planner import DEFAULT_STALE_NS
from trackflow.distributed.wire import decode

pytestmark = pytest.mark.slow

FROZEN_S = 2.0


def test_a_frozen_agent_is_replaced_by_a_live_path_and_comes_back(tmp_path):
    realm = f"f{free_port()}"
    ports = {n: free_port() for n in "abcd"}  # d: the files' late joiner, not started here
    others = {"a": [], "b": ["a"], "c": ["a", "b"], "d": ["a"]}

    def zenoh_of(n):
        return {
            "listen": {"endpoints": [endpoint(ports[n])]},
            "connect": {"endpoints": [endpoint(ports[o]) for o in others[n]]},
        }

    start_ns = (time.time_ns() // PERIOD_NS) * PERIOD_NS
    files = _files(tmp_path, realm, zenoh_of, start_ns)
    procs = {n: AgentProcess(files[n], "--duration", "90", log_dir=tmp_path) for n in "abc"}
    session = None
    try:
        for p in procs.values():
            p.wait_ready()
        session = observer([endpoint(ports[n]) for n in "abc"])
        answers = []  # (exposure, path) of every answer: each says which path gave it

        def on_answer(sample) -> None:
            m = decode(sample.payload.to_bytes())
            answers.append((m.exposure_ns, m.path))

        sub = session.declare_subscriber(f"trackflow/{realm}/result/c/q", on_answer)

        def on(path: int, min_published: int = 0):
            q = _query(status(session, realm, "c"), "q")
            ok = q.get("state") == "running" and q.get("path") == path
            return q if ok and q.get("published", 0) >= min_published else None

        q = wait_for(lambda: on(0, 20), 60)
        assert q["paths"] and "s1" in q["paths"][0] and q["switch_count"] == 0, q
        wait_for(lambda: len(answers) >= 10, 30)  # the test's subscriber gets answers too
        frozen_at = time.time_ns()
        procs["a"].proc.send_signal(signal.SIGSTOP)
        try:
            q = wait_for(lambda: on(1), 30)
        finally:
            time.sleep(max(FROZEN_S - (time.time_ns() - frozen_at) * 1e-9, 0.0))
            continued_at = time.time_ns()
            procs["a"].proc.send_signal(signal.SIGCONT)
        away = q["switches"][-1]
        assert away["reason"].startswith("sensor s1: no data for"), away
        # no later than the stale time (and a tick) after the last state s1's agent stamped,
        # which was before it was stopped
        assert away["t_ns"] - frozen_at <= DEFAULT_STALE_NS + PERIOD_NS, away
        # the plan is unchanged: Zenoh never saw the agent go (only the data stopped)
        assert "s1" in q["paths"][0]
        q = wait_for(lambda: on(0), 60)
        back = q["switches"][-1]
        assert back["reason"].startswith("path 0 live for"), back
        assert back["t_ns"] >= continued_at + 2 * 10**9  # the hold time after it came back
        # the states it held while stopped came late: dropped and counted, not replayed
        rejected = status(session, realm, "c")["rejections"]
        print(
            f"away {(away['t_ns'] - frozen_at) * 1e-6:.0f} ms after the stop, back "
            f"{(back['t_ns'] - continued_at) * 1e-9:.2f} s after it continued; {rejected}"
        )
        assert rejected.get("older than the backlog window", 0) > 0, rejected
        wait_for(lambda: any(t > back["t_ns"] + PERIOD_NS for t, _ in answers) or None, 10)
        seen = list(answers)
        away_paths = {p for t, p in seen if away["t_ns"] + PERIOD_NS < t < back["t_ns"]}
        after = {p for t, p in seen if t > back["t_ns"] + PERIOD_NS}
        before = {p for t, p in seen if t < frozen_at}
        sub.undeclare()
        assert before == {0} and away_paths == {1} and after == {0}, (before, away_paths, after)
    finally:
        if session is not None:
            session.close()
        for p in procs.values():
            if p.proc.poll() is None:
                p.proc.send_signal(signal.SIGCONT)
            p.stop()
