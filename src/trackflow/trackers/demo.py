"""The live demo (``make demo-live``): simulated NatNet and DTrack trackers replaying real
recordings, ``trackflow run`` on ``examples/live_demo.yaml``, the answers compared with the
truth, and the recorded run replayed bit for bit.

Every part is a separate process talking over 127.0.0.1, exactly as with real hardware: two
``trackflow simulate`` senders (with latency, clock offsets and jitter) and one
``trackflow run``. The truth is what the senders exposed (``--truth``); the answer
``T_head_tool`` at time ``t`` is compared with ``T_room_head(t)^-1 T_room_tool(t)``
interpolated from the two truths.

Usage: ``python -m trackflow.trackers.demo [--seconds S] [--data DIR] [--out DIR]``.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import numpy as np

from ..errors import ServiceError
from ..io import PoseStream, read_stream
from ..math import Pose, quat_angle, quat_slerp
from ..yamlfile import dump_yaml, read_yaml

__all__ = ["run_live_demo"]

HEAD = "ar_table/table_01.txt"
TOOL = "euroc/V1_01_easy_groundtruth_200hz.txt"


def _free_port(kind=socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cmd(*args) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "trackflow.cli.main", *map(str, args)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ},
    )


def _done(p: subprocess.Popen, what: str, timeout: float) -> str:
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        p.kill()
        raise ServiceError(f"{what} did not finish in {timeout:.0f} s") from None
    if p.returncode != 0:
        raise ServiceError(f"{what} failed: {err.strip()[-500:]}")
    return out


def _at(stream: PoseStream, t_ns: np.ndarray) -> Pose:
    """Truth interpolated at ``t_ns`` (linear position, slerp orientation)."""
    t = stream.t_ns
    i = np.clip(np.searchsorted(t, t_ns) - 1, 0, len(t) - 2)
    s = ((t_ns - t[i]) / (t[i + 1] - t[i]).astype(float))[:, None]
    p = stream.position[i] * (1 - s) + stream.position[i + 1] * s
    q = quat_slerp(stream.quaternion[i], stream.quaternion[i + 1], s[:, 0])
    return Pose(p, q, normalize=True)


def run_live_demo(data: Path, seconds: float, out: Path, setup_file: Path) -> dict:
    """Run the demo; returns the figures (module docstring)."""
    out.mkdir(parents=True, exist_ok=True)
    doc = read_yaml(setup_file)
    nn, dt = _free_port(), _free_port()
    doc["sensors"][0]["input"]["natnet"]["command_port"] = nn
    doc["sensors"][1]["input"]["dtrack"]["port"] = dt
    setup = out / "live_demo.yaml"
    setup.write_text(dump_yaml(doc))
    rec = out / "live.tfrec"
    run = _cmd("run", setup, "--duration", seconds + 8, "--record", rec, "--json")
    first: list[str] = []
    reader = threading.Thread(target=lambda: first.append(run.stderr.readline()), daemon=True)
    reader.start()
    reader.join(120)
    if not first or not first[0].startswith("listening"):
        run.kill()
        raise ServiceError(f"trackflow run did not start: {first}")
    drain = threading.Thread(target=run.stderr.read, daemon=True)  # status lines
    drain.start()
    senders = [
        _cmd("simulate", "natnet", data / HEAD, "--port", nn, "--body", "head",
             "--latency-ms", 4, "--clock-offset-s", 1234.5, "--jitter-ms", 1,
             "--duration", seconds, "--wait", 60, "--truth", out / "head_truth.tfrec"),
        _cmd("simulate", "dtrack", data / TOOL, "--port", dt, "--latency-ms", 6,
             "--clock-offset-s", -86000.25, "--jitter-ms", 1, "--duration", seconds,
             "--wait", 60, "--truth", out / "tool_truth.tfrec"),
    ]  # fmt: skip
    sent = [json.loads(_done(s, "trackflow simulate", seconds + 120)) for s in senders]
    res = json.loads(run.communicate(timeout=seconds + 120)[0])
    replay = json.loads(_done(_cmd("run", setup, "--replay", rec, "--json"), "replay", 600))
    answers, _ = read_stream(rec)
    head, _ = read_stream(out / "head_truth.tfrec")
    tool, _ = read_stream(out / "tool_truth.tfrec")
    t = answers.t_ns
    inside = (t >= max(head.t_ns[0], tool.t_ns[0])) & (t <= min(head.t_ns[-1], tool.t_ns[-1]))
    truth = _at(head, t[inside]).inverse() @ _at(tool, t[inside])
    est = answers.poses[inside]
    dp_mm = np.linalg.norm(est.position - truth.position, axis=-1) * 1e3
    dq_deg = np.degrees(quat_angle(est.quaternion, truth.quaternion))
    period = int(round(1e9 / doc["queries"][0]["rate_hz"]))
    expected = int((t[-1] - t[0]) // period) + 1
    return {
        "seconds": seconds,
        "sent": {"head": sent[0]["sent"], "tool": sent[1]["sent"]},
        "received": {k: v["measurements"] for k, v in res["sensors"].items()},
        "rejections": {k: v["rejections"] for k, v in res["sensors"].items()},
        "clock_offset_ms": {k: v["clock_offset_ms"] for k, v in res["sensors"].items()},
        "answers": res["answers"],
        "answers_lost": expected - len(answers),
        "replay_identical": replay["identical"],
        "error_vs_truth": {
            "position_mm_rms": float(np.sqrt(np.mean(dp_mm**2))),
            "position_mm_p95": float(np.percentile(dp_mm, 95)),
            "rotation_deg_rms": float(np.sqrt(np.mean(dq_deg**2))),
        },
        "record": str(rec),
    }


def _data_dir(root: Path) -> Path:
    """``$TRACKFLOW_DATA``, else ``../shared/data`` next to the repository, else the
    workplace's ``/work/shared/data`` (as the tests look for it)."""
    env = os.environ.get("TRACKFLOW_DATA")
    if env:
        return Path(env)
    for candidate in (root.parent / "shared" / "data", Path("/work/shared/data")):
        if (candidate / HEAD).exists():
            return candidate
    return root.parent / "shared" / "data"


def main(argv=None) -> int:
    root = Path(__file__).resolve().parents[3]
    ap = argparse.ArgumentParser(description="trackflow's live demo (docs/trackers.md)")
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--data", type=Path, default=_data_dir(root))
    ap.add_argument("--setup", type=Path, default=root / "examples" / "live_demo.yaml")
    ap.add_argument("--out", type=Path, default=None, help="keep the files here")
    args = ap.parse_args(argv)
    if not (args.data / HEAD).exists():
        print(f"demo-live: the recordings are missing under {args.data}", file=sys.stderr)
        return 1
    with tempfile.TemporaryDirectory() as tmp:
        result = run_live_demo(args.data, args.seconds, args.out or Path(tmp), args.setup)
    print(json.dumps(result, indent=2))
    ok = result["replay_identical"] and result["answers_lost"] == 0
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
