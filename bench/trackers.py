"""Live tracker inputs: decoding speed of every protocol and packet-to-answer latency.

* ``decode_frames_per_s``: frames of 20 bodies decoded per second, best of ``--repeat`` runs:
  DTrack (``fr``, ``ts2``, ``6d`` with 20 bodies), NatNet 3.1 (the version both decoders
  read correctly; trackflow decodes 4.1 as fast), VRPN (20 Pos_Quat messages cut from a TCP
  byte stream).
* ``natnet_pkg_frames_per_s``: the same NatNet 3.1 frames with the ``natnet`` package 0.3.0
  (``DataFrame.read_from_buffer``), the peer, measured in the same run.
* ``e2e_latency_us``: a ``trackflow simulate natnet`` process sends 20 bodies at 240 Hz
  (TUM-VI room1 replayed at twice its speed) over loopback; this process, pinned to one
  core, receives each packet, decodes it, maps the exposure time and, in the receiving
  thread as ``trackflow run`` does, pushes the packet's 20 measurements as arrays (a
  ``SampleBlock``) into 20 pose Kalman filters (``LiveSources.deliver_block``: the filters'
  updates and their answers, the 20 filtered poses at the packet's arrival time as arrays,
  in one compiled call), handed to a callback as soon as the filters are updated; the
  bookkeeping (the filters' times and log records, the counts) follows it. The latency is
  from the packet's receipt (the kernel's receive stamp, so time in the socket buffer
  counts) to the answers' delivery (``time.time_ns`` on entering the callback, same clock).
  The input runs with the options named in ``options``: ``spin_us`` 200 by default (it
  sleeps until 0.2 ms before each frame is due, then polls the socket); ``cpu_share`` is
  this process's CPU (of a core) while the sender ran. ``plain`` is the same run, made
  first, with the input's defaults (asleep until a packet): the same keys, for comparison.

* ``cpu_us_per_body`` ``{"hot", "live"}``: CPU time per body update (decode, filter, answer,
  bookkeeping) of a 20-body packet, in the hot loop of ``bench/trackers_cpu.py`` (one
  thread, packets back to back) and live (the receiving thread of the end-to-end run with
  the input's defaults, ``plain``, from one packet's end to the next's: waking included),
  with ``live_over_hot``; the same at 100 bodies (``cpu_us_per_body_100``, a second
  end-to-end run, defaults too) and ``bodies_per_core_240hz`` from it (None when the
  100-body figure is not within 20 % of the 20-body one). ``cpu_us_per_body_spin`` is the
  live figure of the ``spin_us`` run: the polling the option trades for latency is CPU the
  defaults do not spend, so it is not counted as the cost of an update.

Usage: ``python bench/trackers.py [--json] [--seconds S] [--repeat R] [--spin-us U]``. The
machine is shared: take the figures as the best of a few runs.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from trackflow.dataflow import KalmanFilter, calm_gc, collect_due, parse_input, warm_up
from trackflow.graph import MotionSpec
from trackflow.math import quat_exp, quat_to_matrix
from trackflow.trackers import dtrack, natnet, vrpn
from trackflow.trackers.inputs import SampleBlock, make_inputs
from trackflow.trackers.runtime import LiveSource, LiveSources

BODIES, RATE = 20, 240
ROOT = Path(__file__).resolve().parents[1]


def _bodies(rng):
    p = rng.normal(0, 1, (BODIES, 3))
    q = quat_exp(rng.normal(0, 1, (BODIES, 3)))
    return p, q


def _rate(fn, data, repeat: int, n: int = 2000) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(n):
            fn(data)
        best = min(best, time.perf_counter() - t0)
    return n / best


def decode_rates(repeat: int) -> dict:
    rng = np.random.default_rng(0)
    p, q = _bodies(rng)
    dt = dtrack.DTrackFrame(
        123,
        None,
        (1_700_000_000, 250_000, 4_000),
        BODIES,
        tuple(
            dtrack.DTrackBody(k, 1.0, tuple(p[k] * 1e3), tuple(quat_to_matrix(q[k]).ravel()))
            for k in range(BODIES)
        ),
    )
    dt_raw = dtrack.encode_dtrack(dt)
    v = (3, 1)
    nn = natnet.NatNetFrame(
        123,
        tuple(
            natnet.NatNetRigidBody(k + 1, tuple(p[k]), tuple(q[k]), 2e-4, True)
            for k in range(BODIES)
        ),
        12.5,
        10_000,
        10_100,
        10_200,
    )
    nn_raw = natnet.encode_frame(nn, v)
    vr_raw = b"".join(
        vrpn.encode_message(1, 2, 0, 0, vrpn.encode_pos_quat(k, p[k], q[k])) for k in range(BODIES)
    )
    head = (
        vrpn.make_cookie()
        + vrpn.encode_description(-1, 0, "Tracker0")
        + vrpn.encode_description(-2, 0, vrpn.POS_QUAT)
    )
    dec = vrpn.StreamDecoder()
    dec.feed(head)
    assert len(dec.feed(vr_raw)) == BODIES

    def natnet_ours(raw):
        msg, payload = natnet.decode_message(raw)
        return natnet.decode_frame(payload, v)

    out = {
        "dtrack": _rate(dtrack.decode_dtrack, dt_raw, repeat),
        "natnet": _rate(natnet_ours, nn_raw, repeat),
        "vrpn": _rate(dec.feed, vr_raw, repeat),
    }
    pkg = None
    try:
        from natnet.data_frame import DataFrame
        from natnet.packet_buffer import PacketBuffer
        from natnet.version import Version

        ver = Version(*v)

        def natnet_pkg(raw):
            return DataFrame.read_from_buffer(PacketBuffer(raw[4:]), ver)

        theirs = natnet_pkg(nn_raw)
        assert [b.id_num for b in theirs.rigid_bodies] == list(range(1, BODIES + 1))
        pkg = _rate(natnet_pkg, nn_raw, repeat, 500)
    except ImportError:
        print("natnet package not installed (pip install '.[bench]')", file=sys.stderr)
    return {"decode": out, "pkg": pkg}


def e2e_latency(seconds: float, recording: Path, spin_us: float = 0.0, bodies: int = BODIES):
    """Packet receipt -> the filtered answers of ``bodies`` bodies delivered [us] (module
    docstring); ``spin_us`` is the input's polling window around a frame's due time (0: it
    sleeps until a packet). ``thread_cpu_us_per_packet``: the receiving thread's CPU time
    from one packet's end to the next's (waking, receiving, decoding, filtering, answering,
    bookkeeping), averaged after the first second."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    cores = sorted(os.sched_getaffinity(0))
    me, other = cores[0], cores[-1]
    os.sched_setaffinity(0, {me})
    specs = {
        f"b{k}": (
            parse_input(
                {
                    "natnet": {
                        "command_port": port,
                        "body": k,
                        "spin_us": spin_us,
                    }
                }
            ),  # fmt: skip
            np.eye(6) * 1e-6,
        )
        for k in range(1, bodies + 1)
    }
    (inp,) = make_inputs(specs)
    # white acceleration / angular acceleration noise for hand motion replayed at twice its
    # speed (TUM-VI room1 reaches several m/s^2 and hundreds of deg/s)
    motion = MotionSpec(static=False, n_dp=1, n_do=1, noise=(0.0, 30.0, 0.0, 100.0))
    sources, filters = {}, {}
    for name in specs:
        sources[name] = LiveSource(name)
        filters[name] = KalmanFilter(f"kf_{name}", motion)
        sources[name].consumers.append((filters[name], 0))
    for kf in filters.values():  # compile the filter kernels before listening

        class _Net:
            components = {"kf": kf}

        warm_up(_Net)
    lock = threading.Lock()
    latencies: list[int] = []
    service: list[int] = []  # a packet decoded -> its last answer
    service_cpu: list[int] = []  # the same, CPU time of the receiving thread
    woken: list[int] = []  # receipt -> the packet in this process (wake-up, receive call)
    handled: list[int] = []  # decoding, clock mapping and the samples (handle)
    thread_cpu: list[int] = []  # the receiving thread's CPU time at each packet's end

    names = [b.name for b in inp.bodies]
    delivery = LiveSources(sources)

    def answer(samples, t0, entered):
        taken, cpu = time.time_ns(), time.thread_time_ns()

        def delivered(answers):  # the packet's 20 answers, as arrays
            now = time.time_ns()
            if answers.ok[-1]:
                latencies.append(now - t0)
                service.append(now - taken)
                service_cpu.append(time.thread_time_ns() - cpu)
                woken.append(entered - t0)
                handled.append(taken - entered)

        sensors = [names[bi] for bi in samples.index]
        delivery.deliver_block(
            sensors, samples, samples.arrival_ns, answer=(samples.arrival_ns, delivered)
        )

    def sink(i, data, arrival):
        t0 = arrival  # the kernel's receive stamp (host clock): socket queueing counts
        entered = time.time_ns()
        with lock:  # as trackflow run dispatches a packet: in the receiving thread
            samples = i.handle(data, arrival)
            if type(samples) is SampleBlock:  # else not every body valid: not timed
                answer(samples, t0, entered)
        collect_due()  # as trackflow run does once a packet is answered
        thread_cpu.append(time.thread_time_ns())

    cpu0, wall0 = time.process_time(), time.perf_counter()
    with calm_gc():  # as trackflow run does once the network is warm
        inp.start(sink)
        inp.ready.wait(5)
        env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
        sender = subprocess.Popen(
            [
                sys.executable, "-m", "trackflow.cli.main", "simulate", "natnet", str(recording),
                "--port", str(port), "--bodies", str(bodies), "--speed", str(RATE / 120),
                "--duration", str(seconds * RATE / 120), "--jitter-ms", "0", "--wait", "30",
            ],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            preexec_fn=lambda: os.sched_setaffinity(0, {other}),
        )  # fmt: skip
        try:
            sender.communicate(timeout=seconds + 120)
        finally:
            if sender.poll() is None:
                sender.kill()
            cpu_share = (time.process_time() - cpu0) / (time.perf_counter() - wall0)
            time.sleep(0.2)
            inp.stop()
            os.sched_setaffinity(0, cores)  # for a next run: both cores again
    lat = np.asarray(latencies[RATE:], dtype=float) * 1e-3  # skip the first second
    if len(lat) == 0:
        raise RuntimeError(f"no answers; input status: {inp.status.summary(time.time_ns())}")
    svc = np.asarray(service[RATE:], dtype=float) * 1e-3
    cpu = np.asarray(service_cpu[RATE:], dtype=float) * 1e-3
    wake = np.asarray(woken[RATE:], dtype=float) * 1e-3
    hdl = np.asarray(handled[RATE:], dtype=float) * 1e-3
    return {
        "wake_p50": float(np.percentile(wake, 50)),
        "wake_p99": float(np.percentile(wake, 99)),
        "handle_p50": float(np.percentile(hdl, 50)),
        "p50": float(np.percentile(lat, 50)),
        "p99": float(np.percentile(lat, 99)),
        "service_p50": float(np.percentile(svc, 50)),
        "service_p99": float(np.percentile(svc, 99)),
        "service_cpu_p50": float(np.percentile(cpu, 50)),
        "cpu_share": cpu_share,  # of a core: this process while the sender ran
        "polled_share": inp.waiting.polled_s / seconds,  # of a core
        "caught_share": inp.waiting.caught / max(len(latencies), 1),
        "thread_cpu_us_per_packet": (thread_cpu[-1] - thread_cpu[RATE])
        * 1e-3
        / max(len(thread_cpu) - 1 - RATE, 1),
    }


def cpu_per_body(seconds: float, recording: Path, live20: dict) -> dict:
    """CPU per body update [us], one run (issue 31's keys): ``hot`` from the in-thread loop
    of ``bench/trackers_cpu.py`` (p50 of a packet's total over its bodies), ``live`` from the
    receiving thread of the end-to-end run with the input's defaults (``live20``, and a
    100-body run; its CPU per packet over the bodies); ``bodies_per_core_240hz`` from the
    live 100-body figure, only when it is within 20 % of the 20-body one (else linear
    extrapolation does not hold: None)."""
    from trackers_cpu import measure as hot_loop

    hot = {n: hot_loop(1000, bodies=n)["p50"]["total_us"] / n for n in (20, 100)}
    live100 = e2e_latency(seconds, recording, bodies=100)
    live = {20: live20["thread_cpu_us_per_packet"] / 20,
            100: live100["thread_cpu_us_per_packet"] / 100}  # fmt: skip
    linear = abs(live[100] / live[20] - 1) <= 0.2
    return {
        "cpu_us_per_body": {"hot": round(hot[20], 2), "live": round(live[20], 2)},
        "cpu_us_per_body_100": {"hot": round(hot[100], 2), "live": round(live[100], 2)},
        "live_over_hot": round(live[20] / hot[20], 2),
        "bodies_per_core_240hz": round(1e6 / (RATE * live[100])) if linear else None,
    }


def _report(name: str, lat: dict) -> None:
    print(
        f"{name}: e2e p50 {lat['p50']:.0f} us, p99 {lat['p99']:.0f} us; processing one packet "
        f"(20 updates + 20 answers) once decoded: p50 {lat['service_p50']:.0f} us, p99 "
        f"{lat['service_p99']:.0f} us (period {1e6 / RATE:.0f} us), CPU p50 "
        f"{lat['service_cpu_p50']:.0f} us"
    )
    print(
        f"  before that: receipt (kernel stamp) -> packet in the receiving thread p50 "
        f"{lat['wake_p50']:.0f} us, p99 {lat['wake_p99']:.0f} us (wake-up, receive call); "
        f"decoding and samples (handle) p50 {lat['handle_p50']:.0f} us"
    )
    if lat["polled_share"]:
        print(
            f"  polling: {100 * lat['polled_share']:.1f} % of a core, "
            f"{100 * lat['caught_share']:.0f} % of the packets caught while polling"
        )
    print(f"  this process's CPU: {100 * lat['cpu_share']:.1f} % of a core")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--seconds", type=float, default=20.0, help="latency run length")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument(
        "--spin-us",
        type=float,
        default=200.0,
        help="the NatNet input's spin_us: it polls from that long before each frame is due",
    )
    ap.add_argument(
        "--recording",
        type=Path,
        default=ROOT.parent / "shared" / "data" / "tumvi" / "dataset-room1_512_16.txt",
    )
    args = ap.parse_args(argv)
    if not args.recording.exists():
        args.recording = Path("/work/shared/data/tumvi/dataset-room1_512_16.txt")
    d = decode_rates(args.repeat)
    # the plain input first: a second run in the same process is not favoured by its place
    plain = e2e_latency(args.seconds, args.recording)
    lat = e2e_latency(args.seconds, args.recording, args.spin_us)
    out = {
        "decode_frames_per_s": {k: round(v) for k, v in d["decode"].items()},
        "natnet_pkg_frames_per_s": None if d["pkg"] is None else round(d["pkg"]),
        "e2e_latency_us": {k: round(lat[k], 1) for k in ("p50", "p99")},
        "bodies": BODIES,
        "rate_hz": RATE,
    }
    out["options"] = {"spin_us": args.spin_us}
    out.update(cpu_per_body(args.seconds, args.recording, plain))
    out["cpu_us_per_body_spin"] = round(lat["thread_cpu_us_per_packet"] / BODIES, 2)
    out["cpu_share"] = round(lat["cpu_share"], 4)
    out["plain"] = {
        "e2e_latency_us": {k: round(plain[k], 1) for k in ("p50", "p99")},
        "cpu_share": round(plain["cpu_share"], 4),
    }
    if args.json:
        print(json.dumps(out))
        return 0
    for k, v in out.items():
        print(f"{k}: {v}")
    if d["pkg"]:
        print(f"natnet decode vs the natnet package: {d['decode']['natnet'] / d['pkg']:.1f}x")
    _report(f"spin_us {args.spin_us:g}", lat)
    _report("the input's defaults (sleeping until a packet)", plain)
    return 0


if __name__ == "__main__":
    sys.exit(main())
