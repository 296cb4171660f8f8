"""Distributed tracking on Zenoh: network latency, re-planning, large-graph planning, and the
thesis demo split over three agent processes (``docs/distributed.md``).

``--json`` prints exactly::

    {"local_p99_us", "remote_p50_us", "remote_p99_us", "replan_ms", "plan_1000_frames_ms"}

* ``local_p99_us``: 20 live sensors at 240 Hz in one agent (the sensors' host): time from
  stamping a measurement to its filter's new state being available there (what a query on
  that host can use), p99 [us].
* ``remote_p50_us``, ``remote_p99_us``: the same 20 x 240 Hz measurements seen by a second
  agent process on loopback that uses all 20 edges (one pull query each): time from the
  sender's stamp to the new state being adopted by the receiver's replica of the filter
  (encoded, sent, decoded, adopted) [us]. The network adds ``remote_p99_us - local_p99_us``
  at p99; the full output also gives the per-message difference (``added_p99_us``).
* ``replan_ms``: three agent processes, ``kill -9`` of the agent on the better path: time from
  the liveliness DELETE reaching the query's agent to the new plan running, worst of the runs.
* ``plan_1000_frames_ms``: ``plan_query`` on a random 1,000-frame, 3,000-edge graph (latency
  evaluation), median over random frame pairs.

Then (unless ``--no-thin``) the thinned-delivery keys: the same sender with a 30 Hz and a
60 Hz consumer agent (a push query per edge each), receiving every state (``raw_*``, 60 ms
jitter buffer) or thinned streams (``thinned_*``): ``*_bytes_per_s`` sent by the sender's
process on its TCP connections, ``*_messages_per_s`` received by the consumers,
``*_answer_p50_us``/``*_answer_p99_us`` from a tick to its answer at the consumer.

``--demo`` also runs the thesis demo split (tracker, camera and application agents) and
compares it with the single-process network on the same recordings.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from _procs import stop

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
sys.path.insert(0, str(SRC))

from trackflow.dataflow import parse_setup  # noqa: E402
from trackflow.graph import Query, random_graph  # noqa: E402
from trackflow.math import Pose, UncertainPose, quat_angle, quat_exp  # noqa: E402

N_EDGES, RATE_HZ = 20, 240.0


# -- processes ---------------------------------------------------------------------------------
def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def ep(port: int) -> str:
    return f"tcp/127.0.0.1:{port}"


def spawn(args: list[str], log: Path) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(SRC))
    out = open(log, "w")
    return subprocess.Popen([sys.executable, *args], stdout=out, stderr=subprocess.STDOUT, env=env)


def spawn_agent(yaml_path: Path, *args: str, log_dir: Path, wait: bool = True) -> subprocess.Popen:
    log = log_dir / f"{yaml_path.stem}.{time.monotonic_ns()}.log"
    p = spawn(["-m", "trackflow.cli.main", "agent", str(yaml_path), *args], log)
    p.log = log
    if wait:
        wait_ready(p)
    return p


def wait_ready(p: subprocess.Popen, timeout_s: float = 90) -> None:
    deadline = time.monotonic() + timeout_s
    while '"ready"' not in p.log.read_text():
        if p.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError(f"agent failed:\n{p.log.read_text()}")
        time.sleep(0.1)


def observer(connect: list[str]):
    import zenoh

    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("listen/endpoints", json.dumps([ep(free_port())]))
    c.insert_json5("connect/endpoints", json.dumps(connect))
    c.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(c)


def status(session, realm: str, agent: str, attempts: int = 1) -> dict:
    for _ in range(attempts):
        for r in session.get(f"trackflow/{realm}/status/{agent}", timeout=3.0):
            if r.ok is not None:
                return json.loads(r.ok.payload.to_bytes())
    return {}


def wait_for(fn, timeout_s: float):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        v = fn()
        if v:
            return v
        time.sleep(0.05)
    raise TimeoutError("condition not met")


# -- 1. planning on a large graph ----------------------------------------------------------------
def bench_plan(repeats: int = 30) -> dict:
    from trackflow.dataflow import plan_query

    rng = np.random.default_rng(1)
    g = random_graph(1000, 3000, rng)
    out = {}
    for ev in ("latency", "covariance"):
        times = []
        for _ in range(repeats):
            a, b = rng.choice(1000, size=2, replace=False)
            q = Query(f"F{a}", f"F{b}", evaluation=ev)
            t = time.perf_counter()
            plan_query(g, q)
            times.append((time.perf_counter() - t) * 1e3)
        out[ev] = float(np.median(times))
    return out


# -- 2. latency: 20 edges at 240 Hz, local and over loopback -----------------------------------
def _sensor_setup():
    sensors = [
        dict(
            name=f"e{k:02d}",
            source="W",
            target=f"X{k:02d}",
            rate_hz=RATE_HZ,
            sigma_pos_mm=0.5,
            sigma_ori_deg=0.1,
            motion={"n_dp": 1, "n_do": 1, "noise": [1, 1]},
        )
        for k in range(N_EDGES)
    ]
    return parse_setup({"sensors": sensors})


def run_sender(realm: str, listen: str, duration_s: float, thin_consumers: int = 0) -> None:
    """(Child process.) An agent with 20 live sensors fed at 240 Hz; prints, per message, its
    stamp and the time its filter's new state was available (the local path). It starts
    feeding once a receiver subscribed to every edge (or, with ``thin_consumers``, once that
    many consumers asked for a thinned stream of every edge)."""
    from trackflow.distributed import Agent, AgentConfig

    cfg = AgentConfig(
        "sender",
        _sensor_setup(),
        realm=realm,
        clock_sync="none",
        zenoh={"listen": {"endpoints": [listen]}},
    )
    n_max = int(duration_s * RATE_HZ * N_EDGES) + 10
    stamps = np.zeros(n_max, np.int64)
    updated = np.zeros(n_max, np.int64)
    count = [0]
    with Agent(cfg) as agent:
        for pub in agent.publishers.values():  # port 0: right after the filter's update
            publish = pub.push

            def timed(m, port=0, publish=publish):
                if port == 0 and count[0] < n_max:
                    stamps[count[0]] = m.t_ns
                    updated[count[0]] = time.time_ns()
                    count[0] += 1
                publish(m, port)

            pub.push = timed
        print(json.dumps({"ready": "sender"}), flush=True)
        deadline = time.monotonic() + 120  # until the receiver has subscribed to every edge

        def subscribed() -> bool:
            if thin_consumers:
                streams = agent.status()["thin_streams"]
                return all(len(streams.get(e, {})) >= thin_consumers for e in agent.publishers)
            return agent.states is not None and agent.states.matched

        while time.monotonic() < deadline and not subscribed():
            time.sleep(0.1)
        time.sleep(0.5)
        count[0] = 0
        # the sensors run unsynchronised: edge k is due at (n + k / 20) / 240 s
        slot = 1.0 / (RATE_HZ * N_EDGES)
        t_next = time.perf_counter()
        end = t_next + duration_s
        k = 0
        pose = UncertainPose(Pose([0.0, 0.0, 1.0], [0, 0, 0, 1]), np.eye(6) * 1e-6)
        while t_next < end:
            delay = t_next - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            e = k % N_EDGES
            t = agent.now_ns()
            x = 0.1 * np.sin(2 * np.pi * 0.5 * t * 1e-9 + e)
            agent.feed(
                f"e{e:02d}", t, UncertainPose(Pose([x, 0.0, 1.0], pose.quaternion), pose.covariance)
            )
            k += 1
            t_next += slot
    n = count[0]
    print(json.dumps({"stamps": stamps[:n].tolist(), "updated": updated[:n].tolist()}), flush=True)


def plot_latency(path: Path, loc: np.ndarray, rem: np.ndarray, load: str) -> None:
    """Distribution of the local and the network path (and their difference per message)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for values, label in (
        (loc, "local path: stamp -> sensor filter updated"),
        (rem, "network path: stamp -> replica updated in another process"),
        (rem - loc, "added by the network, per message"),
    ):
        v = np.sort(values)
        ax.semilogx(np.maximum(v, 1.0), np.arange(1, len(v) + 1) / len(v), label=label)
    ax.axhline(0.99, color="grey", lw=0.8, ls=":")
    ax.axvline(1000, color="r", lw=0.8, label="1 ms")
    ax.set_xlabel("latency [us]")
    ax.set_ylabel("fraction of messages")
    ax.set_title(f"20 sensors at 240 Hz on loopback, {len(loc)} messages (load {load})")
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def bench_latency(duration_s: float, work: Path, plot: Path | None = None) -> dict:
    import gc

    from trackflow.distributed import Agent, AgentConfig

    realm = f"lat{free_port()}"
    port = free_port()
    log = work / "sender.log"
    sender = spawn(
        [
            __file__,
            "--role",
            "sender",
            "--realm",
            realm,
            "--listen",
            ep(port),
            "--duration",
            str(duration_s),
        ],
        log,
    )
    # one pull query per sensor: the receiver holds a replica of every sensor's filter, as a
    # consumer of all twenty relationships must
    frames = [f"X{k:02d}" for k in range(N_EDGES)]
    queries = [dict(name=f"q{f}", source="W", target=f) for f in frames]
    app = parse_setup({"frames": ["W", *frames], "queries": queries})
    cfg = AgentConfig(
        "receiver",
        app,
        realm=realm,
        clock_sync="none",
        zenoh={"connect": {"endpoints": [ep(port)]}},
    )
    agent = Agent(cfg)
    n_max = int((duration_s + 150) * RATE_HZ * N_EDGES)
    stamps = np.zeros(n_max, np.int64)
    adopted = np.zeros(n_max, np.int64)
    count = [0]
    deliver = agent.remote.deliver

    def timed(edge, s, offset_ns, sigma_s):  # the receiver's replica adopts the state
        deliver(edge, s, offset_ns, sigma_s)
        i = count[0]
        if i < n_max:
            adopted[i] = time.time_ns()
            stamps[i] = s.stamp_ns
            count[0] = i + 1

    agent.remote.deliver = timed
    gc_pauses: list[float] = []
    gc_gens: list[int] = []
    gc_start = [0]

    def on_gc(phase, info):
        if phase == "start":
            gc_start[0] = time.perf_counter_ns()
        else:
            gc_pauses.append((time.perf_counter_ns() - gc_start[0]) * 1e-3)
            gc_gens.append(info["generation"])

    with agent:
        gc.callbacks.append(on_gc)
        cpu0, n0 = time.process_time(), None
        deadline = time.monotonic() + duration_s + 150
        receiver = agent.status()
        while sender.poll() is None and time.monotonic() < deadline:
            st = agent.status()
            if len(st["live_edges"]) >= len(receiver["live_edges"]):
                receiver = st  # while the sender runs
                if n0 is None and count[0]:
                    cpu0, n0 = time.process_time(), count[0]
            time.sleep(0.5)
        cpu = time.process_time() - cpu0
        n_cpu = count[0] - (n0 or 0)
        gc.callbacks.remove(on_gc)
        stop(sender)
        time.sleep(0.5)
    text = log.read_text()
    if '"updated"' not in text:
        raise RuntimeError(f"sender did not finish: {text[:500]}\nreceiver: {receiver}")
    sent = next(json.loads(line) for line in text.splitlines() if '"updated"' in line)
    n = count[0]
    if not n:
        raise RuntimeError(f"the receiver got nothing; receiver: {receiver}")
    local = dict(zip(sent["stamps"], np.subtract(sent["updated"], sent["stamps"])))
    remote = dict(zip(stamps[:n].tolist(), (adopted[:n] - stamps[:n]).tolist()))
    common = [t for t in sent["stamps"] if t in remote]  # sent while both were measuring
    loc = np.array([local[t] for t in common], float) * 1e-3
    rem = np.array([remote[t] for t in common], float) * 1e-3
    added = rem - loc
    if plot is not None:
        plot_latency(plot, loc, rem, f"{os.getloadavg()[0]:.1f}")
    return {
        "local_p99_us": float(np.percentile(loc, 99)),
        "remote_p50_us": float(np.percentile(rem, 50)),
        "remote_p99_us": float(np.percentile(rem, 99)),
        "local_p50_us": float(np.percentile(loc, 50)),
        "added_p50_us": float(np.percentile(added, 50)),
        "added_p99_us": float(np.percentile(added, 99)),
        "sent": len(sent["stamps"]),
        "received": len(common),
        "receiver_cpu_us_per_message": cpu / max(n_cpu, 1) * 1e6,
        "receiver_gc_collections": len(gc_pauses),
        "receiver_gc_max_pause_us": max(gc_pauses, default=0.0),
        "receiver_gc_pauses_us_by_generation": {
            g: sorted(round(t) for t, k in zip(gc_pauses, gc_gens) if k == g)[-5:]
            for g in sorted(set(gc_gens))
        },
        "receiver_rejections": receiver["rejections"],
        "receiver_lost_messages": receiver["lost_messages"],
        "receiver_running": sum(q["state"] == "running" for q in receiver["queries"].values()),
    }


def bench_receive_path(n: int = 2000, repeats: int = 5) -> dict:
    """CPU per message of a consumer, in process (no Zenoh), best of ``repeats``: the
    previous design (decode a raw measurement, run the sensor's Kalman update) against the
    placement (decode a filter state, adopt it in the replica) [us]."""
    from trackflow.dataflow import KalmanFilter, Measurement, Network
    from trackflow.distributed import RemoteFilter, RemoteSource, StatePublisher
    from trackflow.distributed.wire import decode, decode_state, encode

    motion = _sensor_setup().graph.edge("e00").motion
    net = Network()
    src = net.add(RemoteSource("s"))
    kf = net.add(KalmanFilter("kf_s", motion))
    states: list[bytes] = []

    class _Keep:
        put = staticmethod(states.append)

    pub = net.add(StatePublisher("publish_s", kf, _Keep()))
    net.connect(src, kf, mode="push")
    net.connect(kf, pub, mode="push", port=0)
    net.connect(src, pub, mode="push", port=1)
    raw = []
    for i in range(n):
        t = 1_700_000_000_000_000_000 + i * 4_166_667
        x = 0.1 * np.sin(2 * np.pi * 0.5 * i / RATE_HZ)
        pose = UncertainPose(Pose([x, 0.0, 1.0], [0, 0, 0, 1]), np.eye(6) * 1e-6)
        src.deliver(Measurement(t, pose, t))
        raw.append(encode(pose, seq=i + 1, exposure_ns=t, host_ns=t, origin_ns=t))

    def old_path():
        f = KalmanFilter("kf_s", motion)
        for b in raw:
            w = decode(b)
            f.push(Measurement(w.exposure_ns, w.pose, w.origin_ns))

    def new_path():
        f = RemoteFilter("kf_s", motion)
        for b in states:
            f.adopt(decode_state(b))

    out = {}
    for name, fn in (("raw_measurement_path_us", old_path), ("state_path_us", new_path)):
        best = float("inf")
        for _ in range(repeats):
            t0 = time.process_time()
            fn()
            best = min(best, (time.process_time() - t0) / n * 1e6)
        out[name] = best
    out["ratio"] = out["raw_measurement_path_us"] / out["state_path_us"]
    return out


# -- 3. re-planning after kill -9 --------------------------------------------------------------
# -- 3. thinned delivery: 20 edges at 240 Hz to a 30 Hz and a 60 Hz consumer ------------------
def _tcp_bytes_sent(pid: int) -> int:
    """Bytes the process has sent on its established TCP connections (the kernel's
    ``tcpi_bytes_sent``, read with ``ss``: Zenoh's framing included) [B]."""
    out = subprocess.run(
        ["ss", "-tinpH", "state", "established"], capture_output=True, text=True, timeout=10
    ).stdout
    total, mine = 0, False
    for line in out.splitlines():
        if not line.startswith(("\t", " ")):
            mine = f"pid={pid}," in line
        elif mine:
            for field in line.split():
                if field.startswith("bytes_sent:"):
                    total += int(field.split(":")[1])
    return total


def bench_thin(
    duration_s: float, work: Path, thin: bool, reorder_ms: float = 60.0, pair: bool = False
) -> dict:
    """The 20 x 240 Hz sender and two consumer agent processes, one with a 30 Hz and one with
    a 60 Hz push query per edge (40 queries), receiving every state (``thin=False``) or
    thinned streams. Measures what crosses loopback (the sender's socket writes, the
    consumers' received messages and bytes) and each answer's latency at its consumer (from
    the tick to the result being published). ``pair``: instead, a thinned and an unthinned
    consumer at 30 Hz side by side, whose answers are compared at equal stamps."""
    from trackflow.distributed.wire import decode

    if pair:
        tag, spec = "pair", [("t30", 30, True), ("r30", 30, False)]
    else:
        tag = "thin" if thin else f"raw{reorder_ms:g}"
        spec = [("c30", 30, thin), ("c60", 60, thin)]
    realm = f"{tag}{free_port()}"
    port = free_port()
    log = work / f"sender_{tag}.log"
    n_thin = sum(t for _, _, t in spec)
    args = ["--role", "sender", "--realm", realm, "--listen", ep(port)]
    args += ["--duration", str(duration_s), "--thin-consumers", str(n_thin)]
    sender = spawn([__file__, *args], log)
    frames = [f"X{k:02d}" for k in range(N_EDGES)]
    consumers, files = {}, {}
    for name, rate, thinned in spec:
        queries = [
            dict(name=f"{name}_{f}", source="W", target=f, mode="push", rate_hz=rate)
            for f in frames
        ]
        files[name] = work / f"{tag}_{name}.yaml"
        doc = {
            "agent": {
                "name": name,
                "realm": realm,
                "clock_sync": "none",
                "reorder_ms": reorder_ms,
                "thin": thinned,
                "zenoh": {"connect": {"endpoints": [ep(port)]}},
            },
            "frames": ["W", *frames],
            "queries": queries,
        }
        files[name].write_text(yaml.safe_dump(doc, sort_keys=False))
    answers: dict[str, list] = {name: [] for name, _, _ in spec}
    session = None
    try:
        for name, f in files.items():
            consumers[name] = spawn_agent(f, "--duration", str(duration_s + 90), log_dir=work)
        session = observer([ep(port)])

        def on_result(sample) -> None:
            w = decode(sample.payload.to_bytes())
            who, frame = str(sample.key_expr).rsplit("/", 1)[-1].split("_")
            answers[who].append((w.exposure_ns, w.host_ns, frame, w.pose))

        sub = session.declare_subscriber(f"trackflow/{realm}/result/**", on_result)
        deadline = time.monotonic() + 150
        while time.monotonic() < deadline and '"ready"' not in log.read_text():
            time.sleep(0.1)
        # measure the middle of the run: from 1 s after feeding started, for duration - 2 s
        wait_for(lambda: all(answers.values()), 150)  # the sender feeds
        time.sleep(1.0)
        # each agent's counters are read with the time of its reply (the middle of the
        # call), and turned into rates over that agent's own window: on a loaded host a
        # status reply can take seconds, and one window for all would count what came
        # while the others were asked
        st0 = {n: _timed_status(session, realm, n) for n in (*consumers, "sender")}
        w0, t0 = _tcp_bytes_sent(sender.pid), time.monotonic()
        for a in answers.values():
            a.clear()
        time.sleep(max(1.0, duration_s - 2.0))
        w1, t1 = _tcp_bytes_sent(sender.pid), time.monotonic()
        got = {n: list(a) for n, a in answers.items()}
        st1 = {n: _timed_status(session, realm, n) for n in (*consumers, "sender")}
        sub.undeclare()
    finally:
        if session is not None:
            session.close()
        for p in (sender, *consumers.values()):
            stop(p)
    span = t1 - t0

    def rate(names, count) -> float:
        return sum((count(st1[n][0]) - count(st0[n][0])) / (st1[n][1] - st0[n][1]) for n in names)

    out = {"mode": tag, "reorder_ms": reorder_ms, "seconds": round(span, 2)}
    out["consumers"] = [f"{n}: {r} Hz, {'thinned' if t else 'every state'}" for n, r, t in spec]
    # states made by the sensors' filters
    out["fed_per_s"] = rate(["sender"], lambda st: st.get("published_states", 0))
    out["sender_bytes_per_s"] = (w1 - w0) / span
    for key, field in (
        ("received_messages_per_s", "received_messages"),
        ("received_payload_bytes_per_s", "received_bytes"),
        ("received_heartbeats_per_s", "received_heartbeats"),
    ):
        out[key] = rate(consumers, lambda st, f=field: st[f])
    # the sender's side of the thinned streams: states sent on their tick, heartbeats (a tick
    # with no new state) and late states (made before a tick already completed: sent at once,
    # a second message for that tick)
    for k in ("sent", "heartbeats", "late"):
        out[f"sender_thin_{k}_per_s"] = rate(["sender"], lambda st, k=k: _thin_totals(st)[k])
    st1 = {n: st for n, (st, _) in st1.items()}
    if pair:  # the same stamps of the same relationship, thinned and not
        ref = {(f, e): pose for e, _, f, pose in got["r30"]}
        both = [(ref[(f, e)], pose) for e, _, f, pose in got["t30"] if (f, e) in ref]
        dp = np.array([np.linalg.norm(a.position - b.position) for a, b in both])
        da = np.degrees([quat_angle(a.quaternion, b.quaternion) for a, b in both])
        out["same_stamps"] = len(both)
        out["within_0.1mm_0.01deg"] = float(np.mean((dp <= 1e-4) & (da <= 0.01)))
        out["max_pos_diff_mm"] = float(dp.max() * 1e3)
        out["max_ang_diff_deg"] = float(da.max())
    for n in consumers:
        lat = np.array([h - e for e, h, _, _ in got[n]], float) * 1e-3
        # answers per second of the ticks they answer (a tick's answer published after the
        # window closed still counts for its tick, one that came in it for an earlier tick
        # too: the span of their ticks, not of the window)
        ticks = sorted({(f, e) for e, _, f, _ in got[n]})
        frames = {f for f, _ in ticks}
        if len(ticks) > len(frames):
            ends = {f: [e for g, e in ticks if g == f] for f in frames}
            per = [(len(v) - 1) / ((v[-1] - v[0]) * 1e-9) for v in ends.values() if len(v) > 1]
            out[f"{n}_answers_per_s"] = float(np.sum(per))
        else:
            out[f"{n}_answers_per_s"] = 0.0
        out[f"{n}_answer_p50_us"] = float(np.percentile(lat, 50)) if len(lat) else None
        out[f"{n}_answer_p99_us"] = float(np.percentile(lat, 99)) if len(lat) else None
        out[f"{n}_late_events"] = st1[n]["late_events"]
        out[f"{n}_tick_wait_ms"] = st1[n]["tick_wait_ms"]
        out[f"{n}_thin_arrival_ms"] = st1[n]["thin_arrival_ms"]
        out[f"{n}_lost_messages"] = st1[n]["lost_messages"]
    lat = np.array([h - e for a in got.values() for e, h, _, _ in a], float) * 1e-3
    out["answer_p50_us"] = float(np.percentile(lat, 50))
    out["answer_p99_us"] = float(np.percentile(lat, 99))
    out["_latencies_us"] = lat  # for --plot-thin; not printed
    return out


def _timed_status(session, realm: str, name: str) -> tuple[dict, float]:
    """An agent's status and the monotonic time of its reply (the middle of the call)."""
    for _ in range(3):  # a loaded host may miss a reply: ask again
        a = time.monotonic()
        st = status(session, realm, name, 5)
        if st:
            return st, (a + time.monotonic()) / 2
    raise TimeoutError(f"agent {name!r} gave no status in 3 tries")


def _thin_totals(st: dict) -> dict:
    """Sums of the sender's thinned-stream counters over its edges and consumers."""
    tot = {"sent": 0, "heartbeats": 0, "late": 0}
    for streams in (st or {}).get("thin_streams", {}).values():
        for c in streams.values():
            for k in tot:
                tot[k] += c.get(k, 0)
    return tot


def plot_thin(path: Path, runs: list[dict], load: str) -> None:
    """Answer latency (tick -> answer at the consumer) of each delivery, as distributions."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for r in runs:
        v = np.sort(r["_latencies_us"]) * 1e-3
        name = {"raw60": "every state, 60 ms buffer", "raw0": "every state, no buffer"}
        label = (
            f"{name.get(r['mode'], 'thinned')}: {r['sender_bytes_per_s'] / 1e6:.2f} MB/s sent, "
            f"{r['fed_per_s']:.0f} of 4800 states/s made"
        )
        ax.semilogx(v, np.arange(1, len(v) + 1) / len(v), label=label)
    ax.axhline(0.99, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("answer latency at the consumer (tick -> answer) [ms]")
    ax.set_ylabel("fraction of answers")
    ax.set_title(f"20 sensors at 240 Hz, consumers at 30 and 60 Hz (load {load})")
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _write_agent(path: Path, name: str, realm: str, zenoh: dict, start_ns: int = 0, **setup):
    doc = {"agent": {"name": name, "realm": realm, "zenoh": zenoh, "start_ns": int(start_ns)}}
    doc.update(setup)
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def _recording(path: Path, source: str, target: str, seconds: float, seed: int) -> Path:
    from trackflow.io import PoseStream, write_stream

    rng = np.random.default_rng(seed)
    t = np.arange(0, seconds, 0.01)
    pos = np.stack([0.2 * np.sin(t), 0.1 * np.cos(t), 1 + 0 * t], 1) + rng.normal(
        0, 1e-3, (len(t), 3)
    )
    quat = quat_exp(np.stack([0 * t, 0 * t, 0.3 * np.sin(t)], 1))
    cov = np.broadcast_to(np.diag([1e-6] * 3 + [1e-5] * 3), (len(t), 6, 6)).copy()
    write_stream(
        path,
        PoseStream(source, target, np.round(t * 1e9).astype(np.int64), pos, quat, covariance=cov),
    )
    return path


def bench_replan(work: Path, kills: int = 3) -> dict:
    realm = f"rp{free_port()}"
    ports = {n: free_port() for n in "abc"}
    others = {"a": [], "b": ["a"], "c": ["a", "b"]}

    def z(n):
        return {
            "listen": {"endpoints": [ep(ports[n])]},
            "connect": {"endpoints": [ep(ports[o]) for o in others[n]]},
        }

    start_ns = time.time_ns()
    motion = {"n_dp": 1, "n_do": 1, "noise": [1.0, 1.0]}
    common = dict(rate_hz=100, sigma_pos_mm=1.0, sigma_ori_deg=0.2, motion=motion)
    a_yaml = _write_agent(
        work / "a.yaml",
        "a",
        realm,
        z("a"),
        start_ns,
        sensors=[
            dict(
                name="s1",
                source="W",
                target="X",
                latency_ms=5,
                recording=str(_recording(work / "s1.tfrec", "W", "X", 600, 1)),
                **common,
            )
        ],
    )
    b_yaml = _write_agent(
        work / "b.yaml",
        "b",
        realm,
        z("b"),
        start_ns,
        sensors=[
            dict(
                name="s2",
                source="W",
                target="X",
                latency_ms=20,
                recording=str(_recording(work / "s2.tfrec", "W", "X", 600, 2)),
                **common,
            )
        ],
    )
    c_yaml = _write_agent(
        work / "c.yaml",
        "c",
        realm,
        z("c"),
        frames=["W", "X"],
        queries=[dict(name="q", source="W", target="X", mode="push", rate_hz=50)],
    )
    procs = [spawn_agent(b_yaml, log_dir=work), spawn_agent(c_yaml, log_dir=work)]
    session = observer([ep(ports["b"]), ep(ports["c"])])
    deletes: list[int] = []

    def on_token(s):
        import zenoh

        if s.kind == zenoh.SampleKind.DELETE and str(s.key_expr).endswith("/a/s1"):
            deletes.append(time.perf_counter_ns())

    tok = session.liveliness().declare_subscriber(f"trackflow/{realm}/alive/**", on_token)
    replans, detect = [], []
    try:
        for _ in range(kills):
            a = spawn_agent(a_yaml, log_dir=work)
            procs.append(a)

            def on(sensor):
                q = status(session, realm, "c").get("queries", {}).get("q", {})
                return q if any(sensor in p for p in q.get("paths", [])) else None

            wait_for(lambda: on("s1"), 60)
            time.sleep(1.0)
            seen = sum("s1 of agent a left" in e["reason"] for e in on("s1")["events"])
            t_kill = time.perf_counter_ns()
            a.send_signal(signal.SIGKILL)
            a.wait(timeout=10)
            q = wait_for(lambda: on("s2"), 30)
            left = [e for e in q["events"] if "s1 of agent a left" in e["reason"]]
            assert len(left) > seen, q  # status keeps the last 20 events
            replans.append(left[-1]["replan_ms"])
            wait_for(lambda: deletes, 10)
            detect.append((deletes[-1] - t_kill) * 1e-6)
    finally:
        tok.undeclare()
        session.close()
        for p in procs:
            stop(p)
    return {"replan_ms": max(replans), "replan_all_ms": replans, "kill_to_delete_ms": detect}


# -- 4. the thesis demo split over three processes ---------------------------------------------
def make_demo_recordings(out: Path, seconds: float, seed: int = 7) -> dict[str, Path]:
    """The demo realm's recordings (``trackflow demo --realm`` writes the same)."""
    from trackflow.demo.realm import demo_realm_recordings

    return demo_realm_recordings(out, seconds, seed)


def single_process(recordings: dict[str, Path], rate_hz: float = 60.0):
    """The demo query (at ``rate_hz``) on one network, virtual clock, on the same
    recordings."""
    path = ROOT / "examples" / "demo_setup.yaml"
    doc = yaml.safe_load(path.read_text())
    doc["queries"][0]["rate_hz"] = rate_hz
    setup = parse_setup(doc, str(path), path.parent)
    setup.recordings = dict(recordings)
    net, rec = setup.plan().build(setup.players())
    net.run()
    return {int(m.t_ns): m.pose for m in rec.events}


def _plot_demo(path: Path, ref: dict, results: dict, common: list, clock_sync: str) -> None:
    """Position of the answer (single process vs three agents) and their difference."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.array(common) * 1e-9
    a = np.array([ref[k].position for k in common])
    b = np.array([results[k].position for k in common])
    diff = np.linalg.norm(a - b, axis=1) * 1e3
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for i, axis in enumerate("xyz"):
        ax1.plot(t, a[:, i], lw=2.5, alpha=0.4, label=f"{axis}, one process")
        ax1.plot(t, b[:, i], lw=0.8, label=f"{axis}, three agents")
    ax1.set_ylabel("T_P_M position [m]")
    ax1.legend(ncol=3, fontsize=8)
    ax1.set_title(f"thesis demo split over three agent processes (clock_sync: {clock_sync})")
    ax2.semilogy(t, np.maximum(diff, 1e-9), ".", ms=3)
    ax2.axhline(0.1, color="r", lw=1, label="0.1 mm")
    ax2.set_ylabel("|difference| [mm]")
    ax2.set_xlabel("recording time [s]")
    ax2.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def bench_demo(
    work: Path,
    seconds: float,
    clock_sync: str,
    plot: Path | None = None,
    thin: bool = False,
    rate_hz: float = 60.0,
) -> dict:
    from trackflow.distributed.wire import decode

    work = work / f"demo_{clock_sync}_{'thin' if thin else 'raw'}_{rate_hz:g}"
    work.mkdir(exist_ok=True)
    recs = make_demo_recordings(work, seconds)
    realm = f"demo{free_port()}"
    ports = {n: free_port() for n in ("tracker", "camera", "app")}
    files = {}
    for n in ports:
        doc = yaml.safe_load((ROOT / "examples" / "distributed" / f"{n}.yaml").read_text())
        doc["agent"]["realm"] = realm
        doc["agent"]["clock_sync"] = clock_sync
        if n == "app":
            doc["agent"]["thin"] = thin
            doc["queries"][0]["rate_hz"] = rate_hz
        files[n] = work / f"{n}.yaml"
        files[n].write_text(yaml.safe_dump(doc, sort_keys=False))
    period = int(round(1e9 / rate_hz))
    start_ns = -(-(time.time_ns() + 20_000_000_000) // period) * period
    connect = {"tracker": [], "camera": ["tracker"], "app": ["tracker", "camera"]}
    procs, results, latency = [], {}, []
    session = None
    try:
        for n in ("tracker", "camera", "app"):
            args = [
                "--listen",
                ep(ports[n]),
                "--start-ns",
                str(start_ns),
                "--duration",
                str(seconds + 40),
            ]
            for o in connect[n]:
                args += ["--connect", ep(ports[o])]
            procs.append(spawn_agent(files[n], *args, log_dir=work, wait=False))
        for p in procs:  # started together: the slowest start-up counts, not their sum
            wait_ready(p)
        session = observer([ep(p) for p in ports.values()])

        def on_result(sample) -> None:
            w = decode(sample.payload.to_bytes())
            results[w.exposure_ns - start_ns] = w.pose  # recording time of the result
            latency.append(w.host_ns - w.exposure_ns)  # tick -> answer published (app clock)

        sub = session.declare_subscriber(f"trackflow/{realm}/result/*/sheep", on_result)
        st = wait_for(
            lambda: (
                (s := status(session, realm, "app"))
                and s["queries"]["sheep"]["state"] == "running"
                and s
            ),
            60,
        )
        ready_before_start = time.time_ns() < start_ns
        end = start_ns + int((seconds + 1.5) * 1e9)
        while time.time_ns() < end:
            time.sleep(0.2)
        st = status(session, realm, "app")
        sub.undeclare()
    finally:
        if session is not None:
            session.close()
        for p in procs:
            stop(p)
    ref = single_process(recs, rate_hz)
    common = sorted(set(ref) & set(results))
    if plot is not None:
        _plot_demo(plot, ref, results, common, clock_sync)
    dp = np.array([np.linalg.norm(ref[t].position - results[t].position) for t in common])
    da = np.array([quat_angle(ref[t].quaternion, results[t].quaternion) for t in common])
    lat = np.array(latency, float) * 1e-3
    return {
        "clock_sync": clock_sync,
        "thin": thin,
        "rate_hz": rate_hz,
        "answer_p50_us": float(np.percentile(lat, 50)) if len(lat) else None,
        "answer_p99_us": float(np.percentile(lat, 99)) if len(lat) else None,
        "seconds": seconds,
        "single_results": len(ref),
        "distributed_results": len(results),
        "same_stamps": len(common),
        "max_pos_diff_mm": float(dp.max() * 1e3) if len(dp) else None,
        "max_ang_diff_deg": float(np.degrees(da.max())) if len(da) else None,
        "within_0.1mm_0.01deg": float(np.mean((dp <= 1e-4) & (np.degrees(da) <= 0.01)))
        if len(dp)
        else None,
        "mismatch_times_s": [
            round(t * 1e-9, 3)
            for t, p, a in zip(common, dp, da)
            if p > 1e-4 or np.degrees(a) > 0.01
        ][:10],
        "ready_before_start": bool(ready_before_start),
        "app_status": {
            k: st.get(k)
            for k in (
                "rejections",
                "late_events",
                "missed_ticks",
                "clocks",
                "lost_messages",
                "received_messages",
                "received_bytes",
                "received_heartbeats",
                "tick_wait_ms",
            )
        },
        "paths": st["queries"]["sheep"]["paths"],
    }


def _printable(out: dict) -> dict:
    return {k: v for k, v in out.items() if not k.startswith("_")}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print the issue's keys only")
    ap.add_argument("--demo", action="store_true", help="also run the three-agent demo")
    ap.add_argument("--demo-seconds", type=float, default=30.0)
    ap.add_argument("--latency-seconds", type=float, default=10.0)
    ap.add_argument("--only-demo", action="store_true", help="skip the other measurements")
    ap.add_argument(
        "--only-latency", action="store_true", help="only the 20 x 240 Hz latency (full output)"
    )
    ap.add_argument("--plot-latency", type=Path, help="with --only-latency: write the CDF here")
    ap.add_argument("--plot", type=Path, help="write the demo comparison (clock_sync none) here")
    ap.add_argument("--role", choices=("sender",), help=argparse.SUPPRESS)
    ap.add_argument("--realm", help=argparse.SUPPRESS)
    ap.add_argument("--listen", help=argparse.SUPPRESS)
    ap.add_argument("--duration", type=float, help=argparse.SUPPRESS)
    ap.add_argument("--thin-consumers", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--no-thin", action="store_true", help="skip the thinned-delivery measurement")
    ap.add_argument(
        "--only-thin", action="store_true", help="only thinned vs full delivery (full output)"
    )
    ap.add_argument("--thin-seconds", type=float, default=10.0)
    ap.add_argument("--plot-thin", type=Path, help="with --only-thin: write the latency CDFs")
    ap.add_argument("--demo-thin", action="store_true", help="the demo's app agent thins")
    ap.add_argument("--demo-rate", type=float, default=60.0, help="the demo query's rate [Hz]")
    args = ap.parse_args()
    if args.role == "sender":
        run_sender(args.realm, args.listen, args.duration, args.thin_consumers)
        return 0
    work = Path(tempfile.mkdtemp(prefix="trackflow-distributed-"))
    try:
        if args.only_demo:
            for sync in ("none", "estimate"):
                plot = args.plot if sync == "none" else None
                out = bench_demo(
                    work, args.demo_seconds, sync, plot, args.demo_thin, args.demo_rate
                )
                print(json.dumps(out, indent=2))
            return 0
        if args.only_thin:  # full delivery with and without the jitter buffer, thinned
            runs = []
            for thin, reorder in ((False, 60.0), (False, 0.0), (True, 60.0)):
                runs.append(bench_thin(args.thin_seconds, work, thin, reorder))
                print(json.dumps(_printable(runs[-1]), indent=2))
            if args.plot_thin is not None:
                plot_thin(args.plot_thin, runs, f"{os.getloadavg()[0]:.1f}")
            pair = bench_thin(args.thin_seconds, work, True, pair=True)
            print(json.dumps(_printable(pair), indent=2))
            return 0
        if args.only_latency:
            out = {"receive_path": bench_receive_path()}
            out.update(bench_latency(args.latency_seconds, work, args.plot_latency))
            print(json.dumps(out, indent=2))
            return 0
        plan = bench_plan()
        lat = bench_latency(args.latency_seconds, work)
        rep = bench_replan(work)
        keys = {
            "local_p99_us": lat["local_p99_us"],
            "remote_p50_us": lat["remote_p50_us"],
            "remote_p99_us": lat["remote_p99_us"],
            "replan_ms": rep["replan_ms"],
            "plan_1000_frames_ms": plan["latency"],
        }
        thin = {}
        if not args.no_thin:
            raw, thinned = (bench_thin(args.thin_seconds, work, t) for t in (False, True))
            thin = {"thin_raw": _printable(raw), "thin_thinned": _printable(thinned)}
            keys.update(
                {
                    "raw_bytes_per_s": raw["sender_bytes_per_s"],
                    "thinned_bytes_per_s": thinned["sender_bytes_per_s"],
                    "raw_messages_per_s": raw["received_messages_per_s"],
                    "thinned_messages_per_s": thinned["received_messages_per_s"],
                    "raw_answer_p50_us": raw["answer_p50_us"],
                    "raw_answer_p99_us": raw["answer_p99_us"],
                    "thinned_answer_p50_us": thinned["answer_p50_us"],
                    "thinned_answer_p99_us": thinned["answer_p99_us"],
                }
            )
        if args.json:
            print(json.dumps(keys))
        else:
            print(
                json.dumps(
                    {
                        **keys,
                        "plan_1000_frames_covariance_ms": plan["covariance"],
                        "receive_path": bench_receive_path(),
                        "latency": lat,
                        "replan": rep,
                        **thin,
                    },
                    indent=2,
                )
            )
        if args.demo:  # with --json on stderr, so stdout holds exactly the keys
            for sync in ("none", "estimate"):
                out = bench_demo(work, args.demo_seconds, sync)
                print(json.dumps(out, indent=2), file=sys.stderr if args.json else sys.stdout)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
