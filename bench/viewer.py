"""What a connected browser view costs the dataflow: 20 bodies at 240 Hz on the wall clock.

The network: 20 simulated sensors ``world -> body_i`` at 240 Hz (each behind its pose Kalman
filter, as the planner builds it) and one push query per body at 60 Hz, run in real time.

The dataflow's latency (the JSON figures) is the dataflow's own measure
(``CallbackSink.wall_latencies_ns``): the wall time from the scheduler dispatching an event
to its result reaching the application - a sensor event at a sink behind its filter, a query
tick at the query's recorder - over every event of the run. A view thread that held the
interpreter while the dataflow works would show here. The text output adds the lateness: wall
time from when an event was due (its arrival on the network clock mapped to the wall clock,
origin = the least-late event) to its delivery, which also counts queueing behind other work;
it is only meaningful when the machine keeps up with the 6000 events/s.

"with" runs attach :func:`trackflow.viewer.attach_view` (its taps write into shared memory; a
separate view process draws 30 frames per second at niceness +10) and have a plain
headless Chromium (SwiftShader WebGL, no DevTools client: a user's browser) connected to the
page for the whole run, so viser serialises and sends every frame. The browser runs at idle
priority too (``chrt --idle``; else nice 19): it stands in for a browser on the user's own
machine and GPU. Runs alternate without/with; the best (lowest p99) of each is reported,
because the machine is shared. The text output adds the dataflow process's CPU time per
event with and without the view (the work the taps add), which load does not inflate.

Then (unless ``--no-realm``) ``trackflow view --realm`` on the three-agent demo
(``bench/_realm_view.py``): ``"realm_view": {"agents_shown_s", "url_s", "replan_shown_s"}``.

    python bench/viewer.py [--json] [--runs 3] [--seconds 8] [--no-realm]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

from trackflow.dataflow import CallbackSink, Network, parse_setup
from trackflow.viewer import attach_view, find_chromium
from trackflow.viewer.browser import CHROMIUM_FLAGS
from trackflow.viewer.simulate import setup_sources

N_BODIES, QUERY_HZ = 20, 60.0
RATE_HZ = 240.0  # the figure; --rate-hz changes it for a lighter comparison
VIEW_HZ = 30.0  # the view's frame rate (attach_view's default; the issue: 30-60 Hz); --view-hz


def make_setup(rate_hz: float = RATE_HZ):
    return parse_setup(
        {
            "frames": ["world"] + [f"body{i}" for i in range(N_BODIES)],
            "sensors": [
                {"name": f"s{i}", "source": "world", "target": f"body{i}", "rate_hz": rate_hz,
                 "latency_ms": 4, "sigma_pos_mm": 0.5, "sigma_ori_deg": 0.2}
                for i in range(N_BODIES)
            ],
            "queries": [
                {"name": f"q{i}", "source": "world", "target": f"body{i}", "mode": "push",
                 "rate_hz": QUERY_HZ}
                for i in range(N_BODIES)
            ],
        }
    )  # fmt: skip


def build(seconds: float, rate_hz: float = RATE_HZ):
    """The network, its plans, its sinks and the list collecting (wall ns, network ns) per
    result."""
    setup = make_setup(rate_hz)
    sources = setup_sources(setup, seconds, seed=1)
    net = Network()
    stamps: list[tuple[int, int]] = []
    clock = net.clock

    def record(_m):
        stamps.append((time.perf_counter_ns(), clock.now_ns))

    plans = {}
    for name, q in setup.queries.items():
        plan = setup.plan(q)
        plan.build(sources, network=net, prefix=f"{name}:", callback=record)
        plans[name] = (plan, f"{name}:")
    for i in range(N_BODIES):  # the sensor path: a sink behind every filter
        sink = net.add(CallbackSink(f"sink{i}", record))
        net.connect(net[f"kf_s{i}"], sink, mode="push")
    sinks = [c for c in net.components.values() if isinstance(c, CallbackSink)]
    return setup, net, plans, sinks, stamps


def lateness_p99_us(stamps: list[tuple[int, int]]) -> float:
    a = np.array(stamps, dtype=np.int64)
    late = a[:, 0] - a[:, 1]  # wall - network clock (speed 1): a constant plus the lateness
    late = late - late.min()
    return float(np.percentile(late, 99)) * 1e-3


def _open_page(exe, url: str, profile: str) -> subprocess.Popen:
    """A plain headless Chromium showing ``url`` (no DevTools client: a user's browser), at
    idle CPU priority (``chrt --idle``; else nice 19), its own profile directory."""
    low = ["chrt", "--idle", "0"] if shutil.which("chrt") else ["nice", "-n", "19"]
    return subprocess.Popen(
        [*low, str(exe), "--headless=new", *CHROMIUM_FLAGS, f"--user-data-dir={profile}",
         "--window-size=1000,700", url],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip


def _close_page(page: subprocess.Popen) -> None:
    page.terminate()
    try:
        page.wait(timeout=10)
    except subprocess.TimeoutExpired:
        page.kill()
        page.wait(timeout=10)


def run_once(
    seconds: float,
    with_view: bool,
    exe=None,
    rate_hz: float = RATE_HZ,
    tmp: str = "",
    priority: str = "low",
    view_hz: float = VIEW_HZ,
) -> tuple[float, float, float]:
    """p99 processing latency [us], p99 lateness [us], view frames sent per second."""
    setup, net, plans, sinks, stamps = build(seconds, rate_hz)
    view = page = None
    if with_view:
        view = attach_view(net, setup, plans, port=0, rate_hz=view_hz, priority=priority)
    try:
        if view is not None and exe is not None:
            page = _open_page(exe, view.url, tempfile.mkdtemp(dir=tmp))
            end = time.monotonic() + 120
            while view.clients < 1:  # the page connected to the view
                if time.monotonic() > end or page.poll() is not None:
                    raise RuntimeError("the headless Chromium did not connect to the view")
                time.sleep(0.1)
            time.sleep(2.0)  # the page loaded its scene
        t0 = time.perf_counter()
        frames0 = view.frames_sent if view else 0
        net.run(realtime=True)
        wall = time.perf_counter() - t0
        fps = (view.frames_sent - frames0) / wall if view else 0.0
    finally:
        if page is not None:
            _close_page(page)
        if view is not None:
            view.close()
    lat = np.concatenate([np.asarray(s.wall_latencies_ns, dtype=float) for s in sinks])
    return float(np.percentile(lat, 99)) * 1e-3, lateness_p99_us(stamps), fps


def cpu_per_result_us(seconds: float, with_view: bool, rate_hz: float = RATE_HZ) -> float:
    """CPU time of this (the dataflow's) process per delivered result [us] on the virtual
    clock (as fast as possible): the work the taps add per event, which load does not
    inflate as it does wall-clock figures. The view process is another process."""
    setup, net, plans, sinks, stamps = build(seconds, rate_hz)
    view = attach_view(net, setup, plans, port=0, rate_hz=30.0) if with_view else None
    try:
        cpu0 = time.process_time()
        net.run()
        cpu = time.process_time() - cpu0
    finally:
        if view is not None:
            view.close()
    return cpu / max(len(stamps), 1) * 1e6


def _measure(args, exe):
    run_once(1.0, False, rate_hz=args.rate_hz)  # warm-up: compiled kernels loaded
    without, with_, fps, late_without, late_with = [], [], [], [], []
    cpu: dict[bool, list[float]] = {False: [], True: []}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.runs):
            p99, late, _ = run_once(args.seconds, False, None, args.rate_hz, tmp)
            without.append(p99)
            late_without.append(late)
            page_exe = None if args.no_browser else exe
            p99, late, f = run_once(
                args.seconds, True, page_exe, args.rate_hz, tmp, args.priority, args.view_hz
            )
            with_.append(p99)
            late_with.append(late)
            fps.append(f)
            for w in (False, True):
                cpu[w].append(cpu_per_result_us(2.0, w, args.rate_hz))
    return without, with_, fps, late_without, late_with, cpu


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--rate-hz", type=float, default=RATE_HZ, help="sensor rate [Hz]")
    ap.add_argument("--view-hz", type=float, default=VIEW_HZ, help="view frame rate target")
    ap.add_argument("--priority", default="low", help="the view process's: idle, low, normal")
    ap.add_argument("--no-browser", action="store_true", help="attach the view, connect no page")
    ap.add_argument(
        "--no-realm", action="store_true", help="skip the realm view on the three-agent demo"
    )
    args = ap.parse_args(argv)
    exe = None if args.no_browser else find_chromium()
    with contextlib.redirect_stdout(sys.stderr):  # stdout carries the result only
        without, with_, fps, late_without, late_with, cpu = _measure(args, exe)
    result = {
        "dataflow_p99_us_without": round(min(without), 1),
        "dataflow_p99_us_with": round(min(with_), 1),
        "frames_sent_per_s": round(float(np.median(fps)), 1),
    }
    if not (args.no_realm or args.no_browser):
        from _realm_view import measure_realm_view

        with contextlib.redirect_stdout(sys.stderr):
            result["realm_view"] = measure_realm_view()
    if args.json:
        print(json.dumps(result))
    else:
        print(
            f"{N_BODIES} bodies at {args.rate_hz:g} Hz, {args.runs} runs of {args.seconds:g} s each"
        )
        print(f"  p99 latency without a view: {result['dataflow_p99_us_without']:.0f} us "
              f"(runs: {', '.join(f'{v:.0f}' for v in without)})")  # fmt: skip
        print(f"  p99 latency with a view:    {result['dataflow_p99_us_with']:.0f} us "
              f"(runs: {', '.join(f'{v:.0f}' for v in with_)})")  # fmt: skip
        print(f"  p99 lateness without / with: {min(late_without):.0f} / {min(late_with):.0f} us")
        print(f"  dataflow CPU per result (virtual clock) without / with: {min(cpu[False]):.1f} / "
              f"{min(cpu[True]):.1f} us")  # fmt: skip
        ratio = min(with_) / min(without)
        print(f"  ratio {ratio:.3f}; view frames sent {result['frames_sent_per_s']:.1f}/s")
        if "realm_view" in result:
            r = result["realm_view"]
            print(f"  view --realm (three-agent demo): agents and edges shown "
                  f"{r['agents_shown_s']:.2f} s after start (URL after {r['url_s']:.2f} s), "
                  f"re-plan shown {r['replan_shown_s']:.2f} s after a kill -9")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
