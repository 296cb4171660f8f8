"""The documented three-agent demo (docs/distributed.md), run as written: `trackflow demo
--realm DIR` writes the agent files and recordings, and the three agents started with the
printed commands answer the application's query over the tracker and camera agents."""

from __future__ import annotations

import json
import time

import pytest

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (pip install .[distributed])")

from _agents import AgentProcess, wait_for

from trackflow.cli.main import main

pytestmark = pytest.mark.slow


def test_the_documented_demo_realm_answers_over_three_agents(tmp_path, capsys):
    realm_dir = tmp_path / "demo_realm"
    assert main(["demo", "--realm", str(realm_dir), "--seconds", "60"]) == 0
    printed = capsys.readouterr().out
    assert f"trackflow agent {realm_dir}/app.yaml --duration 60 --status status.json" in printed
    assert main(["demo", "--realm", str(realm_dir)]) == 1  # never replaced without --force
    start = time.time_ns() + 5_000_000_000
    status_file = tmp_path / "status.json"
    procs = [
        AgentProcess(realm_dir / "tracker.yaml", "--start-ns", str(start), log_dir=tmp_path),
        AgentProcess(realm_dir / "camera.yaml", "--start-ns", str(start), log_dir=tmp_path),
        AgentProcess(
            realm_dir / "app.yaml",
            "--duration",
            "15",
            "--status",
            str(status_file),
            log_dir=tmp_path,
        ),  # fmt: skip
    ]
    try:
        app = procs[2]
        wait_for(lambda: app.proc.poll() is not None, 120)
        assert app.proc.returncode == 0, app.log.read_text()
        q = json.loads(status_file.read_text())["queries"]["sheep"]
        assert q["state"] == "running", q
        assert any("art" in p and "artoolkit" in p for p in q["paths"]), q
        # 10 s of a 60 Hz query after the recordings' start; at least a second's worth
        assert q["published"] >= 60, q
    finally:
        for p in procs:
            p.stop()
