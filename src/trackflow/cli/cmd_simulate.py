"""``trackflow simulate {natnet,dtrack,vrpn} RECORDING``: a simulated tracker on loopback."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..errors import InputError

_DEFAULT_PORT = {"natnet": 1510, "dtrack": 5000, "vrpn": 3883}


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "simulate",
        help="replay a recording as a live DTrack, NatNet or VRPN tracker",
        description="Replay a recording (any format trackflow reads) as packets of a real "
        "tracker protocol on 127.0.0.1, with a chosen latency, clock offset, loss and jitter: "
        "test a pipeline without the hardware. NatNet serves the handshake on --port (the "
        "command port); DTrack sends to --port; VRPN listens on --port.",
    )
    p.add_argument("protocol", choices=("natnet", "dtrack", "vrpn"))
    p.add_argument("recording", type=Path)
    p.add_argument("--port", type=int, default=None, help="port (protocol default)")
    p.add_argument("--host", default="127.0.0.1", help="interface / destination host")
    p.add_argument("--latency-ms", type=float, default=5.0, help="exposure to send [ms]")
    p.add_argument("--clock-offset-s", type=float, default=0.0, help="tracker clock - host [s]")
    p.add_argument("--drift-ppm", type=float, default=0.0, help="tracker clock drift [ppm]")
    p.add_argument("--loss", type=float, default=0.0, help="fraction of frames never sent")
    p.add_argument("--jitter-ms", type=float, default=0.0, help="uniform network delay [ms]")
    p.add_argument("--speed", type=float, default=1.0, help="replay speed factor")
    p.add_argument("--start", type=float, default=0.0, help="start this far in [s]")
    p.add_argument("--duration", type=float, default=None, help="replay this much [s]")
    p.add_argument("--natnet-version", default="4.1", help="NatNet version (2.0 .. 4.1)")
    p.add_argument("--body", default="body", help="NatNet rigid body name")
    p.add_argument("--body-id", type=int, default=1, help="NatNet/DTrack body id")
    p.add_argument("--bodies", type=int, default=1, help="bodies (0.1 m apart along x)")
    p.add_argument("--multicast", default=None, help="NatNet: stream to this group")
    p.add_argument("--data-port", type=int, default=1511, help="NatNet multicast data port")
    p.add_argument("--device", default="Tracker0", help="VRPN device name")
    p.add_argument("--command-port", type=int, default=None, help="DTrack TCP command port")
    p.add_argument("--wait", type=float, default=10.0, help="wait this long for a client [s]")
    p.add_argument("--seed", type=int, default=0, help="seed of loss and jitter")
    p.add_argument(
        "--outage",
        action="append",
        default=[],
        metavar="A:B",
        help="send no frames from A to B s after the first (repeatable)",
    )
    p.add_argument(
        "--freeze",
        action="append",
        default=[],
        metavar="A:B",
        help="hold the frames from A to B s, then send them at once (repeatable)",
    )
    p.add_argument(
        "--plays",
        type=int,
        default=1,
        help="play the recording this many times, every second one backwards (continuous "
        "motion for long runs)",
    )
    p.add_argument("--noise-mm", type=float, default=0.0, help="position noise sigma [mm]")
    p.add_argument("--noise-deg", type=float, default=0.0, help="orientation noise sigma [deg]")
    p.add_argument(
        "--change",
        action="append",
        default=[],
        metavar="T:KEY=V,...",
        help="from T s on, set latency_ms, noise_mm and/or noise_deg "
        "(e.g. 10:latency_ms=30,noise_mm=2; repeatable)",
    )
    p.add_argument("--truth", type=Path, default=None, help="write exposure times + poses")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    try:
        major, minor = (int(x) for x in args.natnet_version.split("."))
    except ValueError as exc:
        raise InputError(f"--natnet-version must be like 4.1, got {args.natnet_version!r}") from exc
    from ..trackers.simulate import SimConfig, simulate

    outages = tuple(_window("--outage", w) for w in args.outage)
    freezes = tuple(_window("--freeze", w) for w in args.freeze)
    changes = tuple(_change(c) for c in args.change)
    cfg = SimConfig(
        args.protocol,
        host=args.host,
        port=_DEFAULT_PORT[args.protocol] if args.port is None else args.port,
        latency_ms=args.latency_ms,
        clock_offset_s=args.clock_offset_s,
        drift_ppm=args.drift_ppm,
        loss=args.loss,
        jitter_ms=args.jitter_ms,
        speed=args.speed,
        duration_s=args.duration,
        start_s=args.start,
        seed=args.seed,
        version=(major, minor),
        body_id=args.body_id,
        body_name=args.body,
        bodies=args.bodies,
        device=args.device,
        command_port=args.command_port,
        multicast_group=args.multicast,
        data_port=args.data_port,
        outages=outages,
        freezes=freezes,
        noise_mm=args.noise_mm,
        noise_deg=args.noise_deg,
        changes=changes,
        plays=args.plays,
    )
    out = simulate(args.recording, cfg, truth_path=args.truth, wait_for_client_s=args.wait)
    print(json.dumps(out))
    return 0


def _change(text: str) -> tuple[float, dict]:
    """``T:latency_ms=30,noise_mm=2`` as ``(T, {"latency_ms": 30.0, "noise_mm": 2.0})``."""
    try:
        at, _, rest = text.partition(":")
        change = {}
        for item in rest.split(","):
            key, _, value = item.partition("=")
            change[key.strip()] = float(value)
        return float(at), change
    except ValueError:
        raise InputError(
            f"--change must be T:KEY=VALUE,... (keys latency_ms, noise_mm, noise_deg), got {text!r}"
        ) from None


def _window(option: str, text: str) -> tuple[float, float]:
    """``A:B`` [s] as a pair of floats (a typed error naming the option otherwise)."""
    try:
        a, b = (float(x) for x in text.split(":"))
    except ValueError:
        raise InputError(f"{option} must be START:END in seconds, got {text!r}") from None
    if not 0 <= a < b:
        raise InputError(f"{option} {text}: need 0 <= START < END")
    return a, b
