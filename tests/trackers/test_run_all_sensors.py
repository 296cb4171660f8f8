"""``trackflow run`` opens and records every sensor of the setup and serves every query, not
only those on the main query's path (real processes: a NatNet sender of three bodies)."""

from __future__ import annotations

import json

import pytest

from trackflow.io import read_stream
from trackflow.trackers.runtime import input_paths, query_record_path

from ._lines import read_lines, stop_when_stale, wait_line
from .test_live_e2e import _finish, _free_port, _trackflow

SETUP = """frames: [W, A, B, C]
sensors:
  - {name: a, source: W, target: A, rate_hz: 120,
     input: {natnet: {command_port: PORT, body: rig}}}
  - {name: b, source: W, target: B, rate_hz: 120,
     input: {natnet: {command_port: PORT, body: rig_2}}}
  - {name: c, source: W, target: C, rate_hz: 120,
     input: {natnet: {command_port: PORT, body: rig_3}}}
queries:
  - {name: a_in_w, source: W, target: A, mode: push, rate_hz: 50}
  - {name: c_in_b, source: B, target: C, mode: pull}
  - {name: b_in_w, source: W, target: B, mode: push, rate_hz: 25}
"""


@pytest.mark.slow
def test_three_bodies_one_path_all_recorded(shared_data, tmp_path):
    room1 = shared_data / "tumvi" / "dataset-room1_512_16.txt"
    if not room1.exists():
        pytest.skip(f"{room1} not present")
    port = _free_port()
    setup = tmp_path / "three.yaml"
    setup.write_text(SETUP.replace("PORT", str(port)))
    rec = tmp_path / "out.tfrec"
    run = _trackflow("run", setup, "--record", rec, "--json")
    try:
        lines = read_lines(run.stderr)
        wait_line(lines, "listening", 180)
        sim = _trackflow(
            "simulate", "natnet", room1, "--port", port, "--body", "rig", "--bodies", 3,
            "--duration", 1.5, "--wait", 30,
        )  # fmt: skip
        sent = json.loads(_finish(sim, 90))["sent"]
        out = stop_when_stale(run, lines, 3)  # everything received
    finally:
        if run.poll() is None:
            run.kill()
            run.communicate()
    assert run.returncode == 0
    out = json.loads(out)
    assert sorted(out["sensors"]) == ["a", "b", "c"]
    for sensor in ("a", "b", "c"):  # every sensor opened, every frame of it recorded
        st = out["sensors"][sensor]
        n = st["measurements"]
        assert n == sent, (sensor, st)
        assert n == st["accepted"] + sum(st["dropped"].values()), st  # each one accounted
        for path in input_paths(rec, sensor):
            stream, _ = read_stream(path)
            assert len(stream) == st["accepted"], (path, len(stream), st)
    queries = out["queries"]
    assert queries["c_in_b"] == {"mode": "pull", "served": True}
    for name in ("a_in_w", "b_in_w"):
        assert queries[name]["served"] and queries[name]["answers"] > 0, queries
    answers, _ = read_stream(rec)  # the main query's answers (the first push query)
    assert len(answers) == queries["a_in_w"]["answers"] == out["answers"]
    other, _ = read_stream(query_record_path(rec, "b_in_w"))
    assert len(other) == queries["b_in_w"]["answers"]
