"""The end-to-end bar of the live inputs, measured on a whole recording.

Three ``trackflow simulate`` processes (NatNet 4.1, DTrack ``ts2``, VRPN) replay the same
recording (default TUM-VI room1, 138 s, 120 Hz) at once over 127.0.0.1 with 5 ms latency,
2 ms uniform jitter, 1 % loss, a clock offset and 20 ppm drift; this process receives all
three. Per protocol it reports the poses sent, received and counted as lost, whether every
received position equals the sent one within float32 rounding, and the error of the mapped
exposure time against the sender's truth (after the first second, while the clock mapping
converges, and over the whole run).

Usage: ``python bench/trackers_e2e.py [--json] [--seconds S] [--jitter-ms J]``.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from trackflow.dataflow import parse_input
from trackflow.io import read_stream
from trackflow.trackers.inputs import make_input

ROOT = Path(__file__).resolve().parents[1]
F32 = 2.0**-24


def match(got, truth):
    """Pair every received sample with the sent one it carries: walking both in order, the
    next sent sample whose position equals the received one within float32 rounding.
    Returns ``(indices, all matched, time error [us])``; unmatched samples get index -1."""
    tp = truth.position
    idx = np.full(len(got), -1)
    j = 0
    for i, s in enumerate(got):
        k = j
        while k < len(tp) and not np.all(np.abs(s.position - tp[k]) <= F32 * np.abs(tp[k]) + 1e-15):
            k += 1
        if k < len(tp):
            idx[i], j = k, k + 1
    ok = idx >= 0
    t = np.array([s.t_ns for s in got])
    return idx[ok], bool(ok.all()), (t[ok] - truth.t_ns[idx[ok]]) * 1e-3


def _port(kind) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _plot(series: dict, path: Path, jitter_ms: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for proto, (t, err, delay) in series.items():
        axes[0].plot(t, delay, ".", ms=1, label=f"{proto}: host arrival - true exposure")
        axes[1].plot(t, err, ".", ms=1, label=f"{proto}: mapped exposure - true exposure")
    axes[0].set_ylabel("ms")
    axes[0].set_title(
        f"5 ms latency + U(0, {jitter_ms:g} ms) jitter, 1 % loss, clock offset, 20 ppm"
    )
    axes[1].set_ylabel("us")
    axes[1].set_ylim(-300, 300)
    axes[1].axhspan(-200, 200, color="0.9", zorder=0)
    axes[1].set_xlabel("time [s]")
    for a in axes:
        a.legend(loc="upper right", markerscale=8, fontsize=8)
        a.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--seconds", type=float, default=None, help="default: whole recording")
    ap.add_argument("--jitter-ms", type=float, default=2.0)
    ap.add_argument("--recording", type=Path, default=None)
    ap.add_argument("--plot", type=Path, default=None, help="write a PNG of the time errors")
    args = ap.parse_args(argv)
    rec = args.recording
    if rec is None:
        for base in (ROOT.parent / "shared" / "data", Path("/work/shared/data")):
            rec = base / "tumvi" / "dataset-room1_512_16.txt"
            if rec.exists():
                break
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    out = {}
    series = {}
    with tempfile.TemporaryDirectory() as tmp:
        inputs, procs = {}, {}
        for proto in ("natnet", "dtrack", "vrpn"):
            port = _port(socket.SOCK_STREAM if proto == "vrpn" else socket.SOCK_DGRAM)
            spec = {
                "natnet": {"natnet": {"command_port": port, "body": "rig"}},
                "dtrack": {"dtrack": {"port": port, "body": 1}},
                "vrpn": {"vrpn": {"device": f"Tracker0@127.0.0.1:{port}", "latency_ms": 5.0}},
            }[proto]
            inp = make_input(proto, parse_input(spec), np.eye(6) * 1e-6)
            got = []
            inp.start(lambda i, d, a, got=got: got.extend(s for _, s in i.handle(d, a)))
            inp.ready.wait(10)
            inputs[proto] = (inp, got)
            cmd = [
                sys.executable, "-m", "trackflow.cli.main", "simulate", proto, str(rec),
                "--port", str(port), "--latency-ms", "5", "--clock-offset-s", "-3600.5",
                "--drift-ppm", "20", "--jitter-ms", str(args.jitter_ms), "--loss", "0.01",
                "--body", "rig", "--wait", "60", "--truth", f"{tmp}/{proto}.tfrec",
            ]  # fmt: skip
            if args.seconds:
                cmd += ["--duration", str(args.seconds)]
            procs[proto] = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, text=True)
        reports = {p: json.loads(pr.communicate(timeout=3600)[0]) for p, pr in procs.items()}
        time.sleep(0.5)
        for proto, (inp, got) in inputs.items():
            inp.stop()
            truth, _ = read_stream(f"{tmp}/{proto}.tfrec")
            st = inp.status
            idx, exact, err_us = match(got, truth)
            arrival = np.array([s.arrival_ns for s in got])[: len(idx)]
            t_rel = (truth.t_ns[idx] - truth.t_ns[0]) * 1e-9
            settled = err_us[t_rel > 1.0]
            series[proto] = (t_rel, err_us, (arrival - truth.t_ns[idx]) * 1e-6)
            out[proto] = {
                "sent": reports[proto]["sent"],
                "lost_injected": reports[proto]["lost"],
                "received": len(got),
                "rejections": st.rejections,
                "dropouts_counted": st.dropouts,
                "positions_exact_f32": exact,
                "time_error_us_after_1s": {
                    "p50": float(np.percentile(np.abs(settled), 50)),
                    "p99": float(np.percentile(np.abs(settled), 99)),
                    "max": float(np.abs(settled).max()),
                    "within_200us": float(np.mean(np.abs(settled) < 200)),
                },
                "time_error_us_all_max": float(np.abs(err_us).max()),
                "clock_drift_ppm": st.clock.drift * 1e6 if st.clock else None,
            }
    if args.plot is not None:
        _plot(series, args.plot, args.jitter_ms)
    if args.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(k, json.dumps(v))
    return 0


if __name__ == "__main__":
    sys.exit(main())
