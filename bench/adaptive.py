"""Failover of a live run, measured with real processes and sockets (issue 28's figures).

Two simulated trackers of one body replay TUM-VI room1 (``trackflow simulate``): NatNet, the
preferred path, and DTrack, the fallback (declared 15 ms slower). ``trackflow run`` answers
a 100 Hz push query with ``stale_ms: 100`` on both inputs and ``failover: {hold_ms: 500}``.
The NatNet tracker fails once both stream, three ways:

* ``outage``: it sends nothing for 1 s (``simulate --outage 6:7``), then goes on;
* ``kill``: its process is killed (SIGKILL) 1.5 s after DTrack streams and a new one started
  1 s later (the run's NatNet input connects to it again);
* ``freeze``: its process is stopped (SIGSTOP) 1.5 s after DTrack streams, for 1 s, then
  continued (SIGCONT): it sends the held frames at once, then goes on.

Per mode, from the run's recordings: ``failover_gap_ms`` (from the exposure of the last NatNet
frame before the failure to the switch to DTrack: how long the answers were not backed by
fresh data),
``switch_back_s`` (from the first fresh NatNet arrival after it, one at most ``stale_ms``
after its exposure, to the switch back) and the answers'
position NEES on the fallback against the DTrack sender's truth. Printed as a table, or one
JSON object with ``--json``: ``{"failover_gap_ms": {"outage", "kill", "freeze"},
"post_switch_nees": mean over the modes' fallback answers, "post_switch_nees_p99",
"switch_back_s": worst mode, "modes": {...}}``.

Measured attributes (``attributes``): two NatNet trackers of the body, declared wrong. ``a``
is declared 5 ms late at 60 Hz with 0.5 mm / 0.2 deg of noise and truly sends at the
recording's 120 Hz, 40 ms late, with 2 mm / 0.5 deg of added noise; ``b`` is declared 30 ms
late and truly 5 ms, with 1 mm / 0.3 deg added. After 12 s of a live run, the run's summary
gives each sensor's measured figures; ``attribute_error`` is the largest relative error over
both sensors of each figure against the truth (rate: frames the sender sent per second;
latency: the median of arrival minus the sender's true exposure time, from the run's
recordings; noise: the added sigma, the recording's own floor of about 0.09 mm / 0.045 deg
not counted).
``rescored`` says whether the query moved from ``a`` (preferred as declared) to ``b`` (truly
better under eq. 2.5) and when.

Online relative delay (``online_offset``): the real Quest 2 / UR5e recordings (robot tool
30 Hz against the headset 72 Hz, runs ``calib`` and ``traj1``; the OptiTrack / headset
example) played through a network on the wall clock, as a live run dispatches
(:func:`trackflow.calibration.replay_online_offset`, the first 32 s; the example's 14 s),
against the offline ``calibrate clock-offset`` of the whole recordings: per run ``online_ms``,
``sigma_ms``, ``offline_ms`` and ``diff_ms``; and against the offline fit with clock drift at
the middle of the window the online estimate used (``offline_drift_ppm`` with its
``offline_drift_sigma_ppm``, ``offline_at_window_ms``, ``diff_at_window_ms``): the two
trackers' clocks drift apart, so a 30 s window's offset is not the whole recording's mean.

Usage: ``python bench/adaptive.py [--json]`` (needs ``../shared/data/tumvi`` and
``../shared/data/quest_ur5e``).
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from _failover_modes import print_table, run_modes, summary
from trackflow.io import read_stream
from trackflow.trackers.runtime import input_paths
from trackflow.trackers.switch_log import read_switch_log, switch_log_path

ROOT = Path(__file__).resolve().parents[1]
ROOM1 = ROOT.parent / "shared" / "data" / "tumvi" / "dataset-room1_512_16.txt"
STALE_MS, HOLD_MS, RATE_HZ = 100, 500, 100
FAIL_AT_S, FAIL_FOR_S, START_S, DURATION_S = 1.5, 1.0, 5.0, 12.0
OUTAGE_AT_S = 6.0  # s into the NatNet replay (it streams from the run's start, DTrack later)
MOTION = "{n_dp: 1, n_do: 1, noise: [0.0, 3.0, 0.0, 10.0]}"


def _setup(sensors: list[tuple[str, float, float, str]]) -> str:
    """A setup of one body ``W -> B`` measured by ``(name, declared rate [Hz], declared
    latency [ms], input)`` sensors (0.5 mm / 0.2 deg declared), with the 100 Hz push query
    ``q`` (``failover: {hold_ms}``)."""
    lines = ["frames: [W, B]", "sensors:"]
    for name, rate, latency, inp in sensors:
        lines += [
            f"  - {{name: {name}, source: W, target: B, rate_hz: {rate}, latency_ms: {latency},",
            f"     sigma_pos_mm: 0.5, sigma_ori_deg: 0.2, motion: {MOTION},",
            f"     input: {{{inp}, stale_ms: {STALE_MS}}}}}",
        ]
    lines += [
        "queries:",
        f"  - {{name: q, source: W, target: B, mode: push, rate_hz: {RATE_HZ},",
        f"     failover: {{hold_ms: {HOLD_MS}}}}}",
    ]
    return "\n".join(lines) + "\n"


SETUP = _setup([("natnet", 120, 5, "natnet: {command_port: NN, body: rig}"),
                ("dtrack", 120, 20, "dtrack: {port: DT, body: 1}")])  # fmt: skip


def _port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _trackflow(*args) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    return subprocess.Popen(
        [sys.executable, "-m", "trackflow.cli.main", *map(str, args)],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip


def _lines(stream) -> queue.Queue:
    out: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [out.put(x) for x in stream], daemon=True).start()
    return out


def _wait(lines: queue.Queue, accept, timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        try:
            if accept(lines.get(timeout=max(end - time.monotonic(), 0.01))):
                return
        except queue.Empty:
            break
    raise TimeoutError(f"no status line as expected within {timeout_s} s")


def _dtrack_streams(line: str) -> bool:
    """Whether a status line (one segment per sensor, `` | `` between) says DTrack streams."""
    for seg in line.strip().split(" | "):
        if seg.startswith("dtrack (dtrack): "):
            rate = float(seg.split()[2])
            return rate > 0 and not seg.endswith("STALE")
    return False


def _natnet(room1: Path, nn: int, mode: str, start_s: float, duration_s: float):
    args = ["simulate", "natnet", room1, "--port", nn, "--wait", 200, "--body", "rig"]
    if mode == "outage":
        args += ["--outage", f"{OUTAGE_AT_S}:{OUTAGE_AT_S + FAIL_FOR_S}"]
    return _trackflow(*args, "--start", start_s, "--duration", duration_s)


def _fail(mode, natnet, room1: Path, nn: int, streaming_since: float) -> subprocess.Popen:
    """Fail the streaming NatNet sender as ``mode`` says; the sender that goes on. A killed
    one is restarted where its replay would be by then (``streaming_since``: monotonic time
    it began), as a tracker that comes back sees the body where it is."""
    if mode == "outage":
        return natnet  # it withholds its frames itself
    time.sleep(FAIL_AT_S)
    if mode == "kill":
        natnet.kill()
        natnet.communicate()
        time.sleep(FAIL_FOR_S)
        resumed = time.monotonic() - streaming_since
        return _natnet(room1, nn, "kill", START_S + resumed, DURATION_S - resumed)
    natnet.send_signal(signal.SIGSTOP)
    time.sleep(FAIL_FOR_S)
    natnet.send_signal(signal.SIGCONT)
    return natnet


def measure(mode: str, room1: Path, folder: Path) -> dict:
    """One run of ``mode``: the failover figures from its recordings."""
    nn, dt = _port(), _port()
    setup = folder / "live.yaml"
    setup.write_text(SETUP.replace("NN", str(nn)).replace("DT", str(dt)))
    rec, truth_path = folder / "out.tfrec", folder / "truth.tfrec"
    # the NatNet sender first: the run connects to it as it opens its inputs, and it streams
    # from then on; the DTrack sender once the run listens
    natnet = _natnet(room1, nn, mode, START_S, DURATION_S)
    run = _trackflow("run", setup, "--record", rec, "--json")
    senders = [natnet]
    try:
        lines = _lines(run.stderr)
        _wait(lines, lambda x: x.startswith("listening"), 180)
        streaming_since = time.monotonic()  # NatNet streams once the run has connected
        senders.append(_trackflow("simulate", "dtrack", room1, "--port", dt, "--body-id", 1,
                                  "--start", START_S, "--duration", DURATION_S,
                                  "--truth", truth_path))  # fmt: skip
        # both stream (a DTrack status line with a rate, not stale) before NatNet fails
        _wait(lines, _dtrack_streams, 60)
        senders.append(_fail(mode, natnet, room1, nn, streaming_since))
        for p in senders[1:]:
            p.communicate(timeout=120)
        _wait(lines, lambda x: x.count("STALE") == 2, 60)
        run.send_signal(signal.SIGTERM)
        summary = json.loads(run.communicate(timeout=60)[0])
    finally:
        for p in (run, *senders):
            if p.poll() is None:
                p.kill()
                p.communicate()
    events = read_switch_log(switch_log_path(rec)).get("q", [])
    exposures, _ = read_stream(input_paths(rec, "natnet")[0], format="native")
    arrivals, _ = read_stream(input_paths(rec, "natnet")[1], format="native")
    k = int(np.argmax(np.diff(arrivals.t_ns)))
    went = int(arrivals.t_ns[k])
    newest = int(exposures.t_ns[k])  # the exposure of NatNet's last frame before the gap
    # recovered: the first frame after the gap that is fresh (a continued process first
    # sends the frames it held, each as old as the freeze: old data, not a live tracker)
    age = arrivals.t_ns[k + 1 :] - exposures.t_ns[k + 1 :]
    came = int(arrivals.t_ns[k + 1 + int(np.argmax(age <= STALE_MS * 1_000_000))])
    away = next((e for e in events if e.to_path == 1 and e.t_ns > went), None)
    # the return because NatNet is back (not because DTrack ended meanwhile)
    back = next((e for e in events if e.to_path == 0 and e.t_ns > came), None)
    if away is None or back is None:
        raise RuntimeError(f"{mode}: no move away and back around the failure "
                           f"({went}..{came}): {[e.as_dict() for e in events]}")  # fmt: skip
    if not back.reason.startswith("path 0 live"):
        raise RuntimeError(f"{mode}: no return to NatNet before DTrack ended: {events}")
    answers, _ = read_stream(rec, format="native")
    truth, _ = read_stream(truth_path)
    on = (answers.t_ns >= away.t_ns) & (answers.t_ns < back.t_ns)
    on &= (answers.t_ns > truth.t_ns[0]) & (answers.t_ns < truth.t_ns[-1])
    t = answers.t_ns[on]
    ref = np.stack([np.interp(t, truth.t_ns, truth.position[:, i]) for i in range(3)], axis=1)
    err = answers.position[on] - ref
    cov = answers.covariance[on][:, :3, :3]
    nees = np.einsum("ni,ni->n", err, np.linalg.solve(cov, err[..., None])[..., 0])
    return {
        "failover_gap_ms": (away.t_ns - newest) * 1e-6,
        "switch_back_s": (back.t_ns - came) * 1e-9,
        "nees": nees.tolist(),
        "switches": [e.as_dict() for e in events],
        "natnet_gap": [went, came],
        "reason": away.reason,
        "answers_by_path": summary["queries"]["q"]["answers_by_path"],
        "natnet": {k: summary["sensors"]["natnet"][k] for k in ("measurements", "rejections")},
    }


ATTR_SETUP = _setup([("a", 60, 5, "natnet: {command_port: NA, body: rig}"),
                     ("b", 120, 30, "natnet: {command_port: NB, body: rig}")])  # fmt: skip
#: the senders' truth: latency [ms], added noise [mm, deg]
ATTR_TRUTH = {"a": (40.0, 2.0, 0.5), "b": (5.0, 1.0, 0.3)}
ATTR_SECONDS = 12.0


def measure_attributes(room1: Path, folder: Path) -> dict:
    """The live run of two wrongly declared NatNet trackers (module docstring)."""
    ports = {"a": _port(), "b": _port()}
    setup = folder / "attr.yaml"
    setup.write_text(ATTR_SETUP.replace("NA", str(ports["a"])).replace("NB", str(ports["b"])))
    rec = folder / "attr.tfrec"
    senders = {}
    for name, (lat, mm, deg) in ATTR_TRUTH.items():
        senders[name] = _trackflow(
            "simulate", "natnet", room1, "--port", ports[name], "--wait", 200, "--body", "rig",
            "--start", START_S, "--duration", ATTR_SECONDS, "--latency-ms", lat,
            "--noise-mm", mm, "--noise-deg", deg, "--seed", len(senders) + 1,
            "--truth", folder / f"truth_{name}.tfrec",
        )  # fmt: skip
    run = _trackflow("run", setup, "--record", rec, "--json")
    try:
        lines = _lines(run.stderr)
        reports = {k: json.loads(p.communicate(timeout=240)[0]) for k, p in senders.items()}
        _wait(lines, lambda x: x.count("STALE") == 2, 60)
        run.send_signal(signal.SIGTERM)
        summary = json.loads(run.communicate(timeout=60)[0])
    finally:
        for p in (run, *senders.values()):
            if p.poll() is None:
                p.kill()
                p.communicate()
    errors: dict[str, float] = {}
    sensors = {}
    first = None  # the first frame either tracker exposed
    for name, (_, mm, deg) in ATTR_TRUTH.items():
        got = summary["attributes"][name]["measured"]
        truth, _ = read_stream(folder / f"truth_{name}.tfrec")
        first = int(truth.t_ns[0]) if first is None else min(first, int(truth.t_ns[0]))
        exposures, _ = read_stream(input_paths(rec, name)[0], format="native")
        arrivals, _ = read_stream(input_paths(rec, name)[1], format="native")
        tail = exposures.t_ns >= exposures.t_ns[-1] - 4_000_000_000  # the ring's span, about
        near = np.clip(np.searchsorted(truth.t_ns, exposures.t_ns[tail]), 1, len(truth) - 1)
        left = truth.t_ns[near - 1]
        near -= np.abs(exposures.t_ns[tail] - left) < np.abs(
            exposures.t_ns[tail] - truth.t_ns[near]
        )
        true = {
            "rate_hz": reports[name]["sent"] / ((truth.t_ns[-1] - truth.t_ns[0]) * 1e-9),
            "latency_ms": float(np.median(arrivals.t_ns[tail] - truth.t_ns[near])) * 1e-6,
            "noise_mm": mm,
            "noise_deg": deg,
        }
        sensors[name] = {"measured": got, "true": true,
                         "declared": summary["attributes"][name]["declared"]}  # fmt: skip
        for key, value in true.items():
            err = abs(got[key] - value) / value
            errors[key] = max(errors.get(key, 0.0), err)
    events = summary["queries"]["q"]["switches"]
    moved = [e for e in events if "measured better" in e["reason"]]
    return {
        "attribute_error": {k: round(v, 4) for k, v in errors.items()},
        "rescored": {
            "moved": bool(moved) and moved[0]["to"] == 1,
            "reason": moved[0]["reason"] if moved else None,
            "after_s": round((moved[0]["t_ns"] - first) * 1e-9, 2) if moved else None,
            "answers_by_path": summary["queries"]["q"]["answers_by_path"],
        },
        "sensors": sensors,
    }


QUEST = ROOT.parent / "shared" / "data" / "quest_ur5e"


PLAY_S, WINDOW_S = 32.0, 30.0  # played, and the last part the online estimate uses [s]


def measure_online_offsets() -> dict:
    """The running estimate of each real two-tracker recording against the offline one."""
    from trackflow.calibration import estimate_clock_offset, replay_online_offset

    runs = {
        "calib": (QUEST / "quest2" / "robot_tcp_calib.tum.txt", QUEST / "quest2" / "calib.txt"),
        "traj1": (QUEST / "quest2" / "robot_tcp_traj1.tum.txt", QUEST / "quest2" / "traj1.txt"),
        "optitrack": (QUEST / "optitrack_unity_example" / "opti.csv",
                      QUEST / "optitrack_unity_example" / "unity.csv"),
    }  # fmt: skip
    out = {}
    for name, (ref_path, headset_path) in runs.items():
        ref, _ = read_stream(ref_path)
        headset, _ = read_stream(headset_path, clean=True)
        offline = estimate_clock_offset(headset, ref)
        got = replay_online_offset(headset, ref, play_s=PLAY_S, realtime=True)
        # the two clocks drift apart (10 ppm on traj1): the offline fit with its drift,
        # evaluated in the middle of the window the online estimate saw, is its like
        drifting = estimate_clock_offset(headset, ref, drift=True)
        start = max(headset.t_ns[0], ref.t_ns[0])
        end = min(start + int(PLAY_S * 1e9), headset.t_ns[-1], ref.t_ns[-1])
        mid = max(start, end - int(WINDOW_S * 1e9)) / 2 + end / 2
        at_window = drifting.offset_s + drifting.drift * (mid - drifting.reference_time_ns) * 1e-9
        out[name] = {
            "online_ms": got.get("offset_ms"),
            "sigma_ms": got.get("sigma_ms"),
            "offline_ms": round(offline.offset_s * 1e3, 3),
            "diff_ms": None
            if "why" in got
            else round(got["offset_ms"] - offline.offset_s * 1e3, 3),
            "offline_drift_ppm": round(drifting.drift * 1e6, 2),
            "offline_drift_sigma_ppm": round(drifting.drift_sigma * 1e6, 2),
            "offline_at_window_ms": round(at_window * 1e3, 3),
            "diff_at_window_ms": None
            if "why" in got
            else round(got["offset_ms"] - at_window * 1e3, 3),
        }
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if not ROOM1.exists():
        print(f"needs {ROOM1}", file=sys.stderr)
        return 2
    modes = run_modes(lambda mode, folder: measure(mode, ROOM1, folder))
    with tempfile.TemporaryDirectory() as d:
        print("attributes ...", file=sys.stderr, flush=True)
        attributes = measure_attributes(ROOM1, Path(d))
    print("online offsets (32 s of each recording on the wall clock) ...", file=sys.stderr)
    online = measure_online_offsets()
    out = {
        **summary(modes, STALE_MS + 2 * 1000 / 120),
        "attribute_error": attributes["attribute_error"],
        "rescored": attributes["rescored"],
        "attributes": attributes["sensors"],
        "online_offset": online,
    }
    if args.json:
        print(json.dumps(out))
    else:
        print_table(out)
        print(f"measured attributes, largest relative error: {out['attribute_error']}")
        print(f"re-scored with the measured figures: {out['rescored']}")
        print(f"online relative delay vs offline: {out['online_offset']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
