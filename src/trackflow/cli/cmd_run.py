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
        "'online_offsets')",
    )
    p.add_argument(
        "--online-max-offset",
        type=float,
        default=1.0,
        metavar="S",
        help="--online-offsets: the largest relative delay searched [s] (default 1)",
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
    offsets = None
    if args.online_offsets:
        offsets = _OnlineOffsets(setup, max_offset_s=args.online_max_offset, quiet=args.quiet)

    def on_network(net, plan, inputs) -> None:
        if offsets is not None:
            offsets.attach(net)
        if args.view:
            from ..viewer import attach_view

            views.append(
                attach_view(net, setup, {plan.query.name: (plan, "")}, host=args.view_host,
                            port=args.view_port, sensor_info=_sensor_info(inputs),
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
            )
    finally:
        if offsets is not None:
            offsets.close()
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
        **({} if offsets is None else {"online_offsets": offsets.final()}),
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


class _OnlineOffsets:
    """``--online-offsets``: an :class:`~trackflow.calibration.OnlineClockOffset` per pair
    of sensors of one body (:func:`~trackflow.calibration.rigid_pairs`), estimated on a
    thread of its own every :attr:`PERIOD_S` (off the dispatch thread), with a status line."""

    PERIOD_S = 5.0

    def __init__(self, setup, *, max_offset_s: float, quiet: bool):
        from ..calibration import OnlineClockOffset, rigid_pairs

        self.estimators = [
            OnlineClockOffset(a, b, max_offset_s=max_offset_s) for a, b in rigid_pairs(setup.graph)
        ]
        self.quiet = quiet
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def attach(self, net) -> None:
        for est in self.estimators:
            net.components[f"kf_{est.a}"].measured.listeners.append(est.add_a)
            net.components[f"kf_{est.b}"].measured.listeners.append(est.add_b)
        self._thread = threading.Thread(target=self._loop, name="online-offsets", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while not self._stop.wait(self.PERIOD_S):
            for est in self.estimators:
                r = est.estimate()
                if not self.quiet:
                    print(f"online offset {_offset_text(r)}", file=sys.stderr, flush=True)

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()

    def final(self) -> list[dict]:
        """The estimate of every pair over the run's last window."""
        return [est.estimate() for est in self.estimators]


def _offset_text(r: dict) -> str:
    head = f"{r['a']} - {r['b']}: "
    if "why" in r:
        return head + r["why"]
    return head + f"{r['offset_ms']:.1f} +- {r['sigma_ms']:.1f} ms over {r['span_s']:.0f} s"


def _stop_on_signals(stop: threading.Event, stopped_by: list[str]):
    """SIGTERM and SIGHUP (a service manager's stop, a closed terminal) end the run as Ctrl-C
    does: the loop stops, the recording is closed and the summary printed (exit code 0),
    rather than the command line's default of unwinding with exit code 128 + signal. The
    signal's name goes to ``stopped_by``. Outside the main thread signals are left alone."""

    def handler(signum, frame) -> None:
        stopped_by.append(signal.Signals(signum).name)
        stop.set()

    return on_stop_signals(handler)


def _sensor_info(inputs):
    """What the view's graph panel shows of each live sensor beyond the network: the
    tracker's counted rejections and its measured clock offset (``viewer.SensorInfo``)."""
    import time

    bodies = [b for inp in inputs for b in inp.bodies]

    def info() -> dict[str, dict]:
        now, out = time.time_ns(), {}
        for b in bodies:
            try:
                s = b.status.summary(now, b.spec.stale_s)
            except RuntimeError:  # a counter changed while being read: next time
                continue
            out[b.name] = {"rejections": s["rejections"], "offset_ms": s["clock_offset_ms"]}
        return out

    return info


def _status(lines: list[str]) -> None:
    print(" | ".join(lines), file=sys.stderr, flush=True)


def _lines(d: dict) -> str:
    return "\n".join(f"{k}: {v}" for k, v in d.items())
