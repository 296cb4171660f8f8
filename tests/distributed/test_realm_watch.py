"""A realm watcher (:class:`trackflow.distributed.realm_watch.RealmWatch`) with real agent
processes: a re-plan reaches it as the agent's ``event/<agent>`` message, not only by its
status poll, and a malformed event message is a counted rejection."""

from __future__ import annotations

import pytest

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (pip install .[distributed])")

from _agents import AgentProcess, free_port, observer, sensor_and_app, wait_for

from trackflow.distributed.realm_watch import RealmWatch

pytestmark = pytest.mark.slow


def _replans(watch: RealmWatch, why: str) -> list[dict]:
    return [e for e in watch.snapshot()["events"] if "re-planned" in e["text"] and why in e["text"]]


def test_a_replan_reaches_the_watch_as_it_happens(tmp_path):
    realm = f"watch{free_port()}"
    sensor, app, endpoints = sensor_and_app(tmp_path, realm, duration_s=60)
    agents = [AgentProcess(f, "--duration", "90", log_dir=tmp_path) for f in (sensor, app)]
    session = None
    try:
        for a in agents:
            a.wait_ready()
        session = observer(endpoints)
        # the watch's own thread polls once, at the start; the test polls until the query
        # runs, then no more: what comes later came as a message
        watch = RealmWatch(session, realm, period_s=3600.0).start()

        def running() -> bool:
            watch.poll()
            q = watch.snapshot()["agents"].get("host_c", {}).get("queries", {}).get("q", {})
            return q.get("state") == "running"

        try:
            wait_for(running, 60)
            agents[0].kill9()
            got = wait_for(lambda: _replans(watch, "of agent host_s left"), 60)
            assert len(got) == 1, got  # taken once
            assert got[0]["text"].startswith("host_c: query q re-planned"), got
            # a message that is not an event is counted, and nothing else happens
            session.put(f"trackflow/{realm}/event/host_x", b"\xffnot json")
            wait_for(lambda: watch.rejections.counts.get("event: malformed") == 1, 30)
            assert len(_replans(watch, "of agent host_s left")) == 1
        finally:
            watch.close()
    finally:
        if session is not None:
            session.close()
        for a in agents:
            a.stop()
