"""The official VRPN client against ``trackflow run --vrpn-port``.

Builds VRPN's own ``vrpn_print_devices`` and a small full-precision report printer
(``bench/vrpn_client/dump_reports.cpp``, trackflow's code) from the public VRPN sources,
which stay outside this repository (``--vrpn-src``: a checkout of github.com/vrpn/vrpn).
Then the live demo's two simulated trackers (NatNet and DTrack replaying real recordings)
feed ``trackflow run examples/live_demo.yaml --vrpn-port P --record``, and both VRPN clients
read ``Tracker0`` for ``--seconds``. Reported: the reports each client received, VRPN's
warnings and errors in their output (a server that does not answer VRPN's ping makes every
client warn "No response from server" each second), and whether every report of the
full-precision client equals the recorded answer of the same time (header time to the
microsecond; position and quaternion as float64, exactly).

Usage: ``python bench/vrpn_official.py --vrpn-src PATH [--seconds 30] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import re
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from trackflow.io import read_stream

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
#: what VRPN prints for its warnings and errors (vrpn_TextPrinter)
WARNING = re.compile(r"VRPN (Warning|Error)|No response from server")


def build(src: Path, out: Path) -> tuple[Path, Path]:
    """``vrpn_print_devices`` and ``dump_reports`` built from the VRPN sources ``src`` in
    ``out`` (configured once; ``make`` does nothing when up to date)."""
    out.mkdir(parents=True, exist_ok=True)
    if not (out / "CMakeCache.txt").exists():
        subprocess.run(
            ["cmake", str(src), "-DCMAKE_BUILD_TYPE=Release", "-DVRPN_BUILD_CLIENTS=ON",
             "-DVRPN_BUILD_SERVERS=OFF", "-DVRPN_BUILD_PYTHON=OFF", "-DVRPN_BUILD_JAVA=OFF",
             "-DVRPN_USE_HID=OFF", "-DVRPN_BUILD_SERVER_LIBRARY=OFF"],
            cwd=out, check=True, stdout=subprocess.DEVNULL,
        )  # fmt: skip
    jobs = str(os.cpu_count() or 1)
    subprocess.run(["make", "-j", jobs, "vrpn_print_devices"], cwd=out, check=True,
                   stdout=subprocess.DEVNULL)  # fmt: skip
    dump = out / "dump_reports"
    cpp = ROOT / "bench" / "vrpn_client" / "dump_reports.cpp"
    subprocess.run(
        ["g++", "-O2", f"-I{src}", f"-I{out}", str(cpp), str(out / "libvrpn.a"),
         str(out / "quat" / "libquat.a"), "-lm", "-lpthread", "-o", str(dump)],
        check=True,
    )  # fmt: skip
    return out / "client_src" / "vrpn_print_devices", dump


def _port(kind=socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _trackflow(*args, **kw) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "trackflow.cli.main", *map(str, args)]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def _listening(run: subprocess.Popen, timeout_s: float) -> list[str]:
    """Wait until ``trackflow run`` says it listens; its stderr lines so far."""
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in run.stderr], daemon=True).start()
    seen, deadline = [], time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=0.5)
        except queue.Empty:
            continue
        seen.append(line)
        if line.startswith("listening:"):
            return seen
    raise RuntimeError(f"trackflow run did not listen within {timeout_s} s: {seen}")


def compare(dump_out: str, answers) -> dict:
    """Every full-precision report against the recorded answer of its header time."""
    rows = np.array([[float(v) for v in ln.split()] for ln in dump_out.splitlines() if ln])
    by_us = {int(t) // 1000: k for k, t in enumerate(answers.t_ns.tolist())}
    matched, equal, dp, dq = 0, 0, 0.0, 0.0
    for r in rows:
        k = by_us.get(int(r[0]) * 1_000_000 + int(r[1]))
        if k is None:
            continue
        matched += 1
        ep = float(np.abs(r[3:6] - answers.position[k]).max())
        eq = float(np.abs(r[6:10] - answers.quaternion[k]).max())
        equal += ep == 0.0 and eq == 0.0
        dp, dq = max(dp, ep), max(dq, eq)
    return {"reports": len(rows), "matched_to_answers": matched, "equal": equal,
            "max_position_diff_m": dp, "max_quaternion_diff": dq}  # fmt: skip


def measure(print_devices: Path, dump: Path, seconds: float, folder: Path) -> dict:
    nn, dt, vr = _port(), _port(), _port(socket.SOCK_STREAM)
    text = (ROOT / "examples" / "live_demo.yaml").read_text()
    setup = folder / "live.yaml"
    setup.write_text(text.replace("command_port: 41510", f"command_port: {nn}")
                     .replace("port: 45000", f"port: {dt}"))  # fmt: skip
    total = seconds + 15
    procs = [
        _trackflow("simulate", "natnet", DATA / "ar_table" / "table_01.txt", "--port", nn,
                   "--body", "head", "--duration", total + 10),
        _trackflow("simulate", "dtrack", DATA / "euroc" / "V1_01_easy_groundtruth_200hz.txt",
                   "--port", dt, "--duration", total + 10),
    ]  # fmt: skip
    record = folder / "answers.tfrec"
    run = _trackflow("run", setup, "--duration", total, "--vrpn-port", vr, "--record", record)
    procs.append(run)
    try:
        _listening(run, 60)
        device = f"Tracker0@127.0.0.1:{vr}"
        pd = subprocess.Popen([str(print_devices), device], stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True)  # fmt: skip
        dr = subprocess.run([str(dump), device, str(seconds)], capture_output=True, text=True,
                            timeout=seconds + 60)  # fmt: skip
        pd.send_signal(signal.SIGINT)  # its ^C handler exits cleanly (flushing its output)
        pd_out = pd.communicate(timeout=30)[0]
        summary = run.communicate(timeout=total + 60)[0]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.communicate()
    answers, _ = read_stream(record)
    pd_lines = pd_out.splitlines()
    out = {
        "seconds": seconds,
        "vrpn_print_devices": {
            "reports": sum(ln.startswith("Tracker Tracker0") for ln in pd_lines),
            "warnings": sum(bool(WARNING.search(ln)) for ln in pd_lines),
            "warning_lines": sorted({ln for ln in pd_lines if WARNING.search(ln)})[:5],
        },
        "dump_reports": {
            **compare(dr.stdout, answers),
            "warnings": sum(bool(WARNING.search(ln)) for ln in dr.stderr.splitlines()),
        },
        "answers_recorded": len(answers.t_ns),
        "run_summary_tail": summary.strip().splitlines()[-3:],
    }
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vrpn-src", type=Path, default=os.environ.get("VRPN_SRC"),
                    help="a checkout of github.com/vrpn/vrpn (or $VRPN_SRC)")  # fmt: skip
    ap.add_argument("--build-dir", type=Path,
                    default=Path.home() / ".cache" / "trackflow" / "vrpn-build")  # fmt: skip
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if args.vrpn_src is None or not (args.vrpn_src / "vrpn_Connection.C").exists():
        print("skipped: needs --vrpn-src (or $VRPN_SRC), a checkout of the public VRPN sources",
              file=sys.stderr)  # fmt: skip
        return 0
    if not DATA.exists():
        print(f"needs the recordings in {DATA}", file=sys.stderr)
        return 2
    print_devices, dump = build(args.vrpn_src, args.build_dir)
    with tempfile.TemporaryDirectory() as tmp:
        out = measure(print_devices, dump, args.seconds, Path(tmp))
    if args.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(f"{k}: {v}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
