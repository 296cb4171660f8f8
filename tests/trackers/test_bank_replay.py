"""The filter bank and the dispatch in the receiving thread change no answer: a live run
recorded with the code before them replays bit for bit, and a live run of two bodies per
NatNet packet (one batched filter update per packet) replays bit for bit through the
sequential dataflow of the replay."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from trackflow.dataflow import Component, load_setup
from trackflow.math import numba_available, use_backend
from trackflow.trackers.runtime import replay, run_live

from ._lines import read_lines, stop_when_stale, wait_line
from .test_live_e2e import _finish, _free_port, _trackflow

BEFORE = Path(__file__).resolve().parent / "data" / "before_bank"


def test_a_run_recorded_before_the_bank_replays_bit_for_bit():
    if not numba_available():
        pytest.skip("recorded with the compiled backend (the NumPy one agrees to rounding)")
    with use_backend("numba"):  # as it was recorded, whatever backend the suite runs
        out = replay(load_setup(BEFORE / "setup.yaml"), BEFORE / "run.tfrec")
    assert out.mismatch is None and out.identical
    assert len(out.answers) == len(out.recorded) == 99


@pytest.mark.slow
def test_a_live_run_of_two_bodies_per_packet_replays_bit_for_bit(shared_data, tmp_path):
    room1 = shared_data / "tumvi" / "dataset-room1_512_16.txt"
    if not room1.exists():
        pytest.skip(f"{room1} not present")
    port = _free_port()
    setup = tmp_path / "live.yaml"
    setup.write_text((BEFORE / "setup.yaml").read_text().replace("47811", str(port)))
    rec = tmp_path / "out.tfrec"
    run = _trackflow("run", setup, "--record", rec, "--json")
    try:
        lines = read_lines(run.stderr)
        wait_line(lines, "listening", 180)  # it compiles (or loads) its filters, then listens
        sim = _trackflow(
            "simulate", "natnet", room1, "--port", port, "--body", "rig", "--bodies", 2,
            "--duration", 2, "--jitter-ms", 1, "--wait", 20,
        )  # fmt: skip
        sent = json.loads(_finish(sim, 90))["sent"]
        # both stale: every frame sent has been received (no run length to guess)
        out = json.loads(stop_when_stale(run, lines, 2))
        assert run.returncode == 0
    finally:
        if run.poll() is None:
            run.kill()
            run.communicate()
    for sensor in ("head", "hand"):
        assert out["sensors"][sensor]["measurements"] > 0.9 * sent, out
    assert out["answers"] > 100, out
    rep = json.loads(_finish(_trackflow("run", setup, "--replay", rec, "--json"), 90))
    assert rep == {"answers": out["answers"], "recorded": out["answers"], "identical": True}


class _Failing(Component):
    """A push consumer that fails on its third event."""

    push_in = 1

    def push(self, m, port=0):
        self.stats.events_in += 1
        if self.stats.events_in == 3:
            raise RuntimeError("consumer failed")


@pytest.mark.slow
def test_an_error_while_a_receiving_thread_dispatches_stops_the_run(shared_data, tmp_path):
    """The receiving thread dispatches its packet itself; an error there ends the run and
    is raised by run_live (not lost with the thread)."""
    room1 = shared_data / "tumvi" / "dataset-room1_512_16.txt"
    if not room1.exists():
        pytest.skip(f"{room1} not present")
    port = _free_port()
    path = tmp_path / "live.yaml"
    path.write_text((BEFORE / "setup.yaml").read_text().replace("47811", str(port)))
    failing = _Failing("failing")

    def attach(net, plan, inputs):
        net.components["head"].consumers.append((failing, 0))

    sim = _trackflow(
        "simulate", "natnet", room1, "--port", port, "--body", "rig", "--bodies", 2,
        "--duration", 3, "--wait", 30,
    )  # fmt: skip
    try:
        t0 = time.monotonic()
        with pytest.raises(RuntimeError, match="consumer failed"):
            run_live(load_setup(path), duration_s=30, on_network=attach)
        assert time.monotonic() - t0 < 25  # stopped at the error, not at the deadline
    finally:
        sim.kill()
        sim.communicate(timeout=10)
    assert failing.stats.events_in == 3
