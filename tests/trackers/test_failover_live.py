"""Failover in a live run (real processes and sockets): two simulated trackers of one body,
NatNet (preferred) and DTrack, replay one real recording; the NatNet one has an outage
(``trackflow simulate --outage``). ``trackflow run`` moves the query to the DTrack path once
NatNet has sent nothing for its ``stale_ms``, answers honestly from it (NEES against the
truth the sender wrote), returns after the hold time, records every switch, and its replay
makes the same switches."""

from __future__ import annotations

import json

import numpy as np
import pytest

from trackflow.io import read_stream
from trackflow.trackers.runtime import input_paths
from trackflow.trackers.switch_log import read_switch_log, switch_log_path

from ._lines import read_lines, stop_when_stale, wait_line
from .test_live_e2e import _finish, _free_port, _trackflow

pytestmark = pytest.mark.slow

STALE_MS, HOLD_MS, RATE_HZ, FRAME_HZ = 100, 500, 100, 120
# the fallback's own liveness is not what is measured here: a longer stale time keeps a
# DTrack sender starved for 100 ms by a loaded machine from forcing an early return
STALE_FALLBACK_MS = 400
OUTAGE = (1.5, 2.5)  # s after the NatNet tracker's first frame
SETUP = """frames: [W, B]
sensors:
  - {{name: natnet, source: W, target: B, rate_hz: 120, latency_ms: 5, sigma_pos_mm: 0.5,
     sigma_ori_deg: 0.2, motion: {{n_dp: 1, n_do: 1, noise: [0.0, 3.0, 0.0, 10.0]}},
     input: {{natnet: {{command_port: {nn}, body: rig}}, stale_ms: {stale}}}}}
  - {{name: dtrack, source: W, target: B, rate_hz: 120, latency_ms: 20, sigma_pos_mm: 0.5,
     sigma_ori_deg: 0.2, motion: {{n_dp: 1, n_do: 1, noise: [0.0, 3.0, 0.0, 10.0]}},
     input: {{dtrack: {{port: {dt}, body: 1}}, stale_ms: {stale_fallback}}}}}
queries:
  - {{name: q, source: W, target: B, mode: push, rate_hz: {rate}, failover: {{hold_ms: {hold}}}}}
"""


def test_an_outage_of_the_preferred_tracker_fails_over_and_back(room1, tmp_path):
    nn, dt = _free_port(), _free_port()
    setup = tmp_path / "live.yaml"
    setup.write_text(
        SETUP.format(
            nn=nn,
            dt=dt,
            stale=STALE_MS,
            hold=HOLD_MS,
            rate=RATE_HZ,
            stale_fallback=STALE_FALLBACK_MS,
        )
    )
    rec = tmp_path / "out.tfrec"
    run = _trackflow("run", setup, "--record", rec, "--json")
    try:
        lines = read_lines(run.stderr)
        wait_line(lines, "listening", 180)
        common = ("--wait", 20, "--start", 5)
        # each sender starts when its process is up (NatNet once the run has asked for its
        # description): on a loaded machine seconds apart. DTrack's 8 s cover NatNet's
        # outage (1.5-2.5 s into its 4 s) unless NatNet starts 1.5 s before it or 5.5 s after
        outage = ("--outage", f"{OUTAGE[0]}:{OUTAGE[1]}")
        s1 = _trackflow("simulate", "natnet", room1, "--port", nn, "--body", "rig", *outage,
                        "--duration", 4, *common)  # fmt: skip
        s2 = _trackflow("simulate", "dtrack", room1, "--port", dt, "--duration", 8, *common,
                        "--truth", tmp_path / "truth.tfrec")  # fmt: skip
        sent = [json.loads(_finish(s, 90)) for s in (s1, s2)]
        out = json.loads(stop_when_stale(run, lines, 2))
    finally:
        if run.poll() is None:
            run.kill()
            run.communicate()
    assert run.returncode == 0
    assert sent[0]["withheld"] > 0.9 * (OUTAGE[1] - OUTAGE[0]) * FRAME_HZ, sent[0]
    query = out["queries"]["q"]
    events = query["switches"]
    recorded = [e.as_dict() for e in read_switch_log(switch_log_path(rec))["q"]]
    assert events == recorded and events, events

    # the outage as the run saw it: the longest gap between NatNet arrivals
    nn_exp, nn_arr = _recorded(rec, "natnet")
    gaps = np.diff(nn_arr)
    k = int(np.argmax(gaps))
    went, came = int(nn_arr[k]), int(nn_arr[k + 1])
    newest = int(nn_exp[: k + 1].max())  # the newest NatNet exposure before it
    assert came - went > 0.8e9
    tick, frame = 10**9 // RATE_HZ, 10**9 // FRAME_HZ
    # the rule, judged from what the run received (a loaded machine may starve the DTrack
    # sender too: then the switch waits for it, and that is right): the answers move to
    # DTrack at the first answer after NatNet's newest exposure is STALE_MS old at which
    # DTrack is live, and back at the first answer after NatNet has been live for the hold,
    # unless DTrack went down before
    dtrack_live = _live(*_recorded(rec, "dtrack"), STALE_FALLBACK_MS * 10**6)
    natnet_live = _live(nn_exp, nn_arr, STALE_MS * 10**6)
    earlier = [e for e in events if e["t_ns"] <= went]
    if not earlier or earlier[-1]["to"] == 0:
        due = _first(dtrack_live, newest + STALE_MS * 10**6, came)
        away = next(e for e in events if e["to"] == 1 and e["t_ns"] > went)
        assert away["reason"].startswith("sensor natnet: no data for"), away
        gap_ms = (away["t_ns"] - newest) * 1e-6
        print(f"failover gap {gap_ms:.1f} ms (DTrack live from {(due - newest) * 1e-6:.1f} ms)")
        assert STALE_MS < gap_ms and due <= away["t_ns"] <= due + tick + 2 * frame, events
    else:  # already on DTrack: NatNet's sender stalled just before (a loaded machine)
        away = earlier[-1]
        assert away["reason"].startswith("sensor natnet: no data for"), events
        assert not natnet_live(away["t_ns"]), events
    back = next(e for e in events if e["to"] == 0 and e["t_ns"] > came)
    if back["reason"].startswith("path 0 live for"):  # back once NatNet was live for the hold
        due = _first_held(natnet_live, came, back["t_ns"] + 1, HOLD_MS * 10**6)
        assert due <= back["t_ns"] <= due + tick + 2 * frame, (due, events)
    else:  # DTrack went down first: it had sent nothing for its stale time
        assert back["reason"].startswith("sensor dtrack: no data for"), events
        assert not dtrack_live(back["t_ns"]) and natnet_live(back["t_ns"]), events

    # the fallback's answers are honest: position NEES against the DTrack sender's truth
    answers, _ = read_stream(rec, format="native")
    truth, _ = read_stream(tmp_path / "truth.tfrec")
    on = (answers.t_ns >= away["t_ns"]) & (answers.t_ns < back["t_ns"])
    on &= (answers.t_ns > truth.t_ns[0]) & (answers.t_ns < truth.t_ns[-1])
    # how many ticks a loaded machine answers in the window is its load, not the failover:
    # the window must hold answers enough for the NEES to mean something (a second's worth
    # at 100 Hz is 100; the outage is one second)
    assert on.sum() >= 30, (on.sum(), (back["t_ns"] - away["t_ns"]) / tick, "DTrack's truth [s]",
                            (truth.t_ns[[0, -1]] - away["t_ns"]) * 1e-9)  # fmt: skip
    t = answers.t_ns[on]
    ref = np.stack([np.interp(t, truth.t_ns, truth.position[:, i]) for i in range(3)], axis=1)
    err = answers.position[on] - ref
    nees = np.einsum(
        "ni,ni->n", err, np.linalg.solve(answers.covariance[on][:, :3, :3], err[..., None])[..., 0]
    )
    print(f"NEES after the switch: mean {nees.mean():.2f}, p99 {np.percentile(nees, 99):.2f}")
    assert np.mean(nees < 11.34) > 0.95, np.percentile(nees, [50, 90, 99])  # chi2(3) 99 %
    assert query["answers_by_path"][1] >= on.sum()

    replay = _trackflow("run", setup, "--replay", rec, "--json")
    rep_out, rep_err = replay.communicate(timeout=90)
    assert json.loads(rep_out)["identical"] is True, rep_out + rep_err[-2000:]


def _recorded(rec, sensor: str) -> tuple[np.ndarray, np.ndarray]:
    """A sensor's recorded exposure and arrival times [ns, host clock], in arrival order."""
    exposures, _ = read_stream(input_paths(rec, sensor)[0], format="native")
    arrivals, _ = read_stream(input_paths(rec, sensor)[1], format="native")
    return exposures.t_ns, arrivals.t_ns


def _live(exposures: np.ndarray, arrivals: np.ndarray, stale_ns: int):
    """Whether the sensor is live at a time [ns]: the newest exposure it had delivered by
    then is at most ``stale_ns`` old."""
    newest = np.maximum.accumulate(exposures)

    def live(t_ns: int) -> bool:
        i = int(np.searchsorted(arrivals, t_ns, side="right")) - 1
        return i >= 0 and t_ns - int(newest[i]) <= stale_ns

    return live


def _first_held(live, start_ns: int, end_ns: int, hold_ns: int, step_ns: int = 1_000_000):
    """The first time from ``start_ns`` (1 ms steps) at which ``live`` has held for
    ``hold_ns`` without a break."""
    since = None
    for t in range(start_ns, end_ns, step_ns):
        if not live(t):
            since = None
            continue
        since = t if since is None else since
        if t - since >= hold_ns:
            return t
    raise AssertionError("NatNet was never live for the hold time before the return")


def _first(live, start_ns: int, end_ns: int, step_ns: int = 1_000_000) -> int:
    """The first time from ``start_ns`` (1 ms steps) at which ``live`` holds."""
    for t in range(start_ns, end_ns, step_ns):
        if live(t):
            return t
    raise AssertionError("DTrack was never live while NatNet was away")
