"""``trackflow run SETUP.yaml``: run a setup live on its trackers (or replay a recorded run)."""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from pathlib import Path

from ..scheduler import stop_signals as on_stop_signals


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "run",
        help="run a setup live on its trackers (DTrack, NatNet, VRPN, optical) or replay a run",
        description="Connect to the trackers named in the setup's 'input:' keys (every sensor "
        "of the setup is opened and recorded), serve every query of the setup until Ctrl-C, "
        "SIGTERM or SIGHUP (or --duration) with a status line per sensor, record every input "
        "and the answers (--record: the main query's to the file, other push queries' next to "
        "it), serve the answers over VRPN (--vrpn-port: the main query as sensor 0, the other "
        "push queries as 1, 2, ...); or replay a recorded run offline and check that it gives "
        "the same answers bit for bit.",
    )
    p.add_argument("setup", type=Path, help="YAML setup file")
    p.add_argument(
        "--query",
        help="the main push query: recorded, sensor 0 over VRPN (default: the first push query)",
    )
    p.add_argument("--duration", type=float, default=None, help="stop after S seconds")
    p.add_argument("--record", type=Path, default=None, help="record answers (.tfrec) + inputs")
    p.add_argument("--replay", type=Path, default=None, help="replay a recorded run offline")
    p.add_argument("--vrpn-port", type=int, default=None, help="serve answers as Tracker0 on it")
    p.add_argument("--vrpn-host", default="127.0.0.1", help="VRPN server interface")
    p.add_argument("--view", action="store_true", help="show the run in the browser (viser)")
    p.add_argument("--view-host", default="127.0.0.1", help="view bind address (loopback)")
    p.add_argument("--view-port", type=int, default=8080, help="view port (0: any free one)")
    p.add_argument(
        "--view-anchor",
        default=None,
        metavar="FRAME",
        help="the frame the view draws in (default: the room, not the query's source)",
    )
    p.add_argument(
        "--online-offsets",
        action="store_true",
        help="estimate the relative delay of every two sensors of one body while running "
        "(angular speeds over the last 30 s; a status line every 5 s, the summary's "
        "'online_offsets'); the setup's 'online_offsets:' block sets more and may apply it",
    )
    p.add_argument(
        "--online-max-offset",
        type=float,
        default=None,
        metavar="S",
        help="--online-offsets: the largest relative delay searched [s] (default 1; a setup "
        "with an 'online_offsets:' block sets its max_offset_s there)",
    )
    p.add_argument("--quiet", action="store_true", help="no status lines")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..dataflow import load_setup

    setup = load_setup(args.setup)
    if args.replay is not None:
        from ..trackers.runtime import replay

        r = replay(setup, args.replay, query=args.query)
        out = {"answers": len(r.answers), "recorded": len(r.recorded), "identical": r.identical}
        if r.mismatch:
            out["mismatch"] = r.mismatch
        print(json.dumps(out) if args.json else _lines(out))
        return 0 if r.identical else 1
    from ..trackers.runtime import run_live

    if any(spec.protocol == "optical" for spec in setup.inputs.values()):
        from .. import optical  # noqa: F401  (registers the 'optical' feed; layer 4 wires it)

    views: list = []
    offsets = _online_spec(args, setup)
    if offsets is not None:  # made here so the view can show its estimates
        from ..trackers.online_offsets import OnlineOffsets, offsets_log_path

        log = None if args.record is None else offsets_log_path(args.record)
        offsets = OnlineOffsets(setup, offsets, log)

    def on_network(net, plan, inputs) -> None:
        if args.view:
            from ..viewer import attach_view

            views.append(
                attach_view(net, setup, {plan.query.name: (plan, "")}, host=args.view_host,
                            port=args.view_port, sensor_info=_sensor_info(inputs, offsets),
                            anchor=args.view_anchor)
            )  # fmt: skip
            print(f"view: {views[0].url}", file=sys.stderr, flush=True)

    server = None
    if args.vrpn_port is not None:
        from ..trackers.vrpn_server import VrpnTrackerServer

        server = VrpnTrackerServer("Tracker0", args.vrpn_host, args.vrpn_port)
    stop, stopped_by = threading.Event(), []
    try:
        with _stop_on_signals(stop, stopped_by):
            res = run_live(
                setup,
                query=args.query,
                duration_s=args.duration,
                record=args.record,
                vrpn_out=server,
                on_status=None if args.quiet else _status,
                on_network=on_network,
                stop=stop,
                online_offsets=offsets,
            )
    finally:
        for view in views:
            view.close()
        if server is not None:
            server.close()
    out = {
        "answers": res.answers,
        "ticks": res.ticks,
        "duration_s": round(res.duration_s, 3),
        "interrupted": res.interrupted or bool(stopped_by),
        "sensors": res.statuses,
        "queries": _queries(setup, res),
        "attributes": res.attributes,
        **({"ros2": res.ros2} if res.ros2 else {}),
        **({} if res.online_offsets is None else {"online_offsets": res.online_offsets}),
        **({"online_corrections": res.online_corrections} if res.online_corrections else {}),
        "record": None if res.record is None else str(res.record),
    }
    if stopped_by:
        out["signal"] = stopped_by[0]
    print(json.dumps(out) if args.json else _lines(out))
    return 0


def _queries(setup, res) -> dict:
    """Every query of the setup: how it was served (answers pushed, or pulled on request),
    or why it could not be planned."""
    out = {}
    for name, q in setup.queries.items():
        if name in res.unplanned:
            out[name] = {"mode": q.mode, "served": False, "reason": res.unplanned[name]}
        elif q.mode == "push":
            out[name] = {"mode": q.mode, "served": True,
                         "answers": res.sinks[name].stats.events_in}  # fmt: skip
        else:
            out[name] = {"mode": q.mode, "served": True}
        if name in res.switches:  # failover: the path it ends on, answers per path, switches
            out[name].update(res.switches[name].summary())
    return out


def _online_spec(args, setup):
    """The online offsets the run makes: the setup's block, or with ``--online-offsets``
    alone an estimate-only one (``--online-max-offset`` sets its search)."""
    from ..dataflow import OnlineOffsetSpec
    from ..errors import ConfigError

    spec = setup.online_offsets
    if spec is not None:
        if args.online_max_offset is not None:
            raise ConfigError(
                "--online-max-offset: the setup's online_offsets block sets max_offset_s",
                setup.source,
                setup.lines.get("online_offsets", 0),
                "online_offsets",
            )
        return spec
    if not args.online_offsets:
        if args.online_max_offset is not None:
            raise ConfigError("--online-max-offset needs --online-offsets")
        return None
    return OnlineOffsetSpec(max_offset_s=args.online_max_offset or 1.0)


def _stop_on_signals(stop: threading.Event, stopped_by: list[str]):
    """SIGTERM and SIGHUP (a service manager's stop, a closed terminal) end the run as Ctrl-C
    does: the loop stops, the recording is closed and the summary printed (exit code 0),
    rather than the command line's default of unwinding with exit code 128 + signal. The
    signal's name goes to ``stopped_by``. Outside the main thread signals are left alone."""

    def handler(signum, frame) -> None:
        stopped_by.append(signal.Signals(signum).name)
        stop.set()

    return on_stop_signals(handler)


def _sensor_info(inputs, offsets=None):
    """What the view's graph panel shows of each live sensor beyond the network: the
    tracker's counted rejections, its measured clock offset, and with online offsets
    (``offsets``) the correction applied to it and its pair's newest estimate
    (``viewer.SensorInfo``)."""
    import time

    bodies = [(inp, b) for inp in inputs for b in inp.bodies]

    def info() -> dict[str, dict]:
        now, out = time.time_ns(), {}
        for _, b in bodies:
            try:
                s = b.status.summary(now, b.spec.stale_s)
            except RuntimeError:  # a counter changed while being read: next time
                continue
            out[b.name] = {"rejections": s["rejections"], "offset_ms": s["clock_offset_ms"]}
        if offsets is not None:
            latest = offsets.latest()
            for inp, b in bodies:
                if b.name in out:
                    out[b.name]["correction_ms"] = inp.shift_ns * 1e-6
                    out[b.name]["online"] = latest.get(b.name)
        return out

    return info


def _status(lines: list[str]) -> None:
    print(" | ".join(lines), file=sys.stderr, flush=True)


def _lines(d: dict) -> str:
    return "\n".join(f"{k}: {v}" for k, v in d.items())
