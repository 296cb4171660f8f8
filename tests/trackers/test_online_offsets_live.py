"""``trackflow run --online-offsets`` with real processes and sockets: a NatNet tracker (it
reports its latency, so its exposure times are mapped exactly) and a VRPN tracker of the
same body, both 5 ms late, the VRPN input told 20 ms (VRPN carries no latency: its one-way
clock mapping subtracts the ``latency_ms`` it is given, so its poses come out 15 ms early).
The running estimate of their relative delay finds the 15 ms, with a sigma, beside the two
senders' own start skew (each replays the recording from when it starts; their truth files
say by how much). With ``online_offsets: {apply: true}`` the run corrects the VRPN tracker's
times by what it finds, and its recording replays to the bit."""

from __future__ import annotations

import json
import re
import signal
import socket

import numpy as np
import pytest

from trackflow.io import read_stream

from ._lines import read_lines, stop_when_stale, wait_line
from .test_live_e2e import _finish, _free_port, _trackflow

pytestmark = pytest.mark.slow

SETUP = """frames: [W, B]
sensors:
  - {{name: natnet, source: W, target: B, rate_hz: 120, latency_ms: 5, sigma_pos_mm: 0.5,
     sigma_ori_deg: 0.2, motion: {{n_dp: 1, n_do: 1, noise: [0.0, 3.0, 0.0, 10.0]}},
     input: {{natnet: {{command_port: {nn}, body: rig}}, stale_ms: 300}}}}
  - {{name: vrpn, source: W, target: B, rate_hz: 120, latency_ms: 20, sigma_pos_mm: 0.5,
     sigma_ori_deg: 0.2, motion: {{n_dp: 1, n_do: 1, noise: [0.0, 3.0, 0.0, 10.0]}},
     input: {{vrpn: {{device: "Tracker0@127.0.0.1:{vp}", latency_ms: 20}}, stale_ms: 300}}}}
queries:
  - {{name: q, source: W, target: B, mode: push, rate_hz: 50}}
{extra}"""


def _run_pair(
    room1, tmp_path, extra: str, *args, seconds: float = 8.0, until=None
) -> tuple[dict, float]:
    """``trackflow run`` of the two trackers (``extra``: more of the setup file, ``args``:
    more options) until both senders have sent ``seconds`` (or, with ``until``, until the
    run prints a line ``until(line)`` takes: then the senders are stopped) and gone stale;
    its summary, and the relative delay its online estimate should find [ms]."""
    nn, vp = _free_port(), _free_port(socket.SOCK_STREAM)
    setup = tmp_path / "live.yaml"
    setup.write_text(SETUP.format(nn=nn, vp=vp, extra=extra))
    run = _trackflow("run", setup, *args, "--json")
    try:
        lines = read_lines(run.stderr)
        wait_line(lines, "listening", 180)
        common = ("--duration", seconds, "--wait", 20, "--start", 20, "--latency-ms", 5)
        senders = [
            _trackflow("simulate", "natnet", room1, "--port", nn, "--body", "rig", *common,
                       "--truth", tmp_path / "natnet.tfrec"),
            _trackflow("simulate", "vrpn", room1, "--port", vp, *common,
                       "--truth", tmp_path / "vrpn.tfrec"),
        ]  # fmt: skip
        if until is not None:
            try:
                wait_line(lines, until, seconds + 60)
            except AssertionError as exc:  # every online-offset line, not only the last five
                seen = getattr(until, "seen", "")
                raise AssertionError(f"{exc}; online offsets: {seen}") from None
            for s in senders:  # stopped, they still write the truth of what they sent
                s.send_signal(signal.SIGTERM)
                s.communicate(timeout=60)
        for s in senders:
            if s.returncode is None:
                _finish(s, 90)
        out = json.loads(stop_when_stale(run, lines, 2))
    finally:
        if run.poll() is None:
            run.kill()
            run.communicate()
    # the host times at which the two senders exposed the same recorded pose
    truth = {k: read_stream(tmp_path / f"{k}.tfrec")[0] for k in ("natnet", "vrpn")}
    row = {tuple(p): t for p, t in zip(truth["natnet"].position.tolist(), truth["natnet"].t_ns)}
    skew = [t - row[tuple(p)] for p, t in zip(truth["vrpn"].position.tolist(),
                                              truth["vrpn"].t_ns) if tuple(p) in row]  # fmt: skip
    skew_ms = float(np.median(skew)) * 1e-6
    # t_natnet = t_vrpn + offset: VRPN's stamps 15 ms early, less the delivery delay its
    # one-way mapping cannot tell from the clock offset (a fraction of a millisecond on
    # loopback, more on a loaded machine)
    expected = 15.0 - skew_ms
    print(f"senders' skew {skew_ms:.2f} ms: expected {expected:.2f} ms")
    return out, expected


def test_the_run_estimates_a_wrongly_declared_latency_while_running(room1, tmp_path):
    # the two senders start streaming when each process is up: on a loaded machine half a
    # second or more apart, hence the wide search
    out, expected = _run_pair(room1, tmp_path, "", "--online-offsets", "--online-max-offset", 4)
    (got,) = out["online_offsets"]
    assert (got["a"], got["b"]) == ("natnet", "vrpn"), got
    print(f"online {got}")
    assert expected - 3.0 < got["offset_ms"] < expected + 3 * got["sigma_ms"] + 0.5, got
    assert 0 < got["sigma_ms"] < 2.0 and got["span_s"] > 6.0, got
    assert got["applied_ms"] == 0.0 and "online_corrections" not in out


def test_the_run_corrects_the_vrpn_times_when_the_setup_opts_in_and_replays_exactly(
    room1, tmp_path
):
    extra = (
        "online_offsets: {apply: true, reference: natnet, every_s: 2, min_span_s: 3,\n"
        "                 max_offset_s: 4}\n"
    )
    record = tmp_path / "out.tfrec"
    # the senders stop once the run has estimated 2 s on the corrected times (when the
    # correction comes depends on the machine's load; 40 s is the most they send)
    after = re.compile(r"over (\d+) s \(after a correction")

    seen: list[str] = []  # the run's online-offset lines (for the message if none comes)

    def two_s_after(line: str) -> bool:
        seen.extend(part.strip() for part in line.split(" | ") if "online offset" in part)
        return any(int(m) >= 2 for m in after.findall(line))

    two_s_after.seen = seen  # type: ignore[attr-defined]

    out, expected = _run_pair(
        room1, tmp_path, extra, "--record", record, seconds=40.0, until=two_s_after
    )
    corrections = out["online_corrections"]
    (got,) = out["online_offsets"]
    print(f"corrections {corrections}; final {got}")
    # the VRPN connection's times moved by the relative delay, once or a few times
    assert corrections and all(c["sensors"] == ["vrpn"] for c in corrections), corrections
    total = corrections[-1]["total_ms"]
    assert expected - 3.0 < total < expected + 3.0, (total, expected)
    assert got["applied_ms"] == total
    # on the corrected times the pair's residual is what is left: near zero
    assert "offset_ms" in got, (got, corrections)
    assert abs(got["offset_ms"]) < 3 * got["sigma_ms"] + 1.0, got
    # the log holds every correction, and the recording replays to the bit (its input
    # recordings hold the corrected times the run delivered)
    log = [json.loads(line) for line in (tmp_path / "out.offsets.jsonl").read_text().splitlines()]
    assert log == corrections
    rep = json.loads(_finish(_trackflow("run", tmp_path / "live.yaml", "--replay", record,
                                        "--json"), 90))  # fmt: skip
    assert rep["identical"] and rep["answers"] == rep["recorded"] > 0, rep
