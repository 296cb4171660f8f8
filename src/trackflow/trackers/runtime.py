"""``trackflow run``: a setup's dataflow driven live by its trackers, recorded, replayable.

Live event order. Every packet is stamped on arrival (host clock, ``time.time_ns``) under one
lock that also hands out strictly increasing dispatch times (samples of one packet get
``arrival, arrival + 1 ns, ...``), so the queue is in time order; the scheduler thread
dispatches samples and sampler ticks in time order, a sample before a tick at the same
nanosecond, exactly as the virtual clock of :meth:`trackflow.dataflow.Network.run` orders
them. A tick is fired only when no sample with an earlier time can still arrive (the lock
raises a floor under later stamps). The answers therefore depend only on the recorded inputs
and their dispatch times, and :func:`replay` reproduces them bit for bit.

Recording (``record=out.tfrec``): ``out.tfrec`` holds the answers (``T_source_target`` of the
query with covariance, as :class:`trackflow.dataflow.Recorder` writes them); for every
sensor ``out.<sensor>.tfrec`` holds its measurements stamped with the mapped exposure time,
and ``out.<sensor>.arrival.tfrec`` the same records stamped with their dispatch time.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..dataflow import (
    Component,
    KalmanFilter,
    Measurement,
    RecordingPlayer,
    Sampler,
    Setup,
)
from ..io import RecordingWriter, read_stream
from ..math import Pose, UncertainPose
from .inputs import LiveInput, Sample, host_ns, make_inputs

__all__ = [
    "LiveSource",
    "ReplayResult",
    "RunResult",
    "input_paths",
    "replay",
    "run_live",
    "warm_up",
]


class LiveSource(Component):
    """The push source of a live sensor: :meth:`deliver` turns a :class:`Sample` into a
    :class:`Measurement` (``t_ns`` = exposure on the host clock, ``origin_ns`` the same).
    A sample not after the previous one ("timestamp backwards") or with an invalid pose or
    covariance is a counted rejection, as in :class:`trackflow.dataflow.RecordingPlayer`."""

    push_out = True
    kind = "live"

    def __init__(self, name: str):
        super().__init__(name)
        self.reset()

    def reset(self) -> None:
        super().reset()
        self._last_t: int | None = None

    def deliver(self, s: Sample) -> UncertainPose | None:
        self.stats.events_in += 1
        if self._last_t is not None and s.t_ns <= self._last_t:
            self.stats.reject("timestamp backwards")
            return None
        try:
            pose = UncertainPose(Pose(s.position, s.quaternion), s.covariance)
        except ValueError:
            self.stats.reject("invalid pose or covariance")
            return None
        self._last_t = s.t_ns
        self.emit(Measurement(s.t_ns, pose, s.t_ns))
        return pose


def warm_up(net) -> None:
    """Run every Kalman filter of ``net`` once on a throwaway copy, so that compiling its
    kernels (numba, first use in a process) happens before the trackers are listened to."""
    seen = set()
    for c in net.components.values():
        if isinstance(c, KalmanFilter) and (c.motion, c.history_s) not in seen:
            seen.add((c.motion, c.history_s))
            f = c.filter_factory(c.motion, c.history_s)
            u = UncertainPose(Pose(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])), np.eye(6) * 1e-6)
            f.update_pose(0.0, u)
            f.update_pose(0.01, u)
            f.predict(0.02)


def input_paths(record, sensor: str) -> tuple[Path, Path]:
    """``(exposure-stamped, dispatch-stamped)`` input recordings of ``sensor`` next to the
    answers file ``record``."""
    record = Path(record)
    stem = record.name[: -len(record.suffix)] if record.suffix else record.name
    return (
        record.with_name(f"{stem}.{sensor}.tfrec"),
        record.with_name(f"{stem}.{sensor}.arrival.tfrec"),
    )


@dataclass
class RunResult:
    """Outcome of a live run: answers delivered, ticks, per-sensor statuses, component
    statistics, the recording and whether it ended by interruption."""

    answers: int
    ticks: int
    statuses: dict[str, dict]
    stats: dict[str, dict]
    record: Path | None
    duration_s: float
    interrupted: bool = False
    inputs: list[LiveInput] = field(default_factory=list, repr=False)


def _push_query(setup: Setup, query: str | None):
    q = setup.query(query)
    if q.mode != "push" or not q.rate_hz:
        raise ValueError(
            f"{setup.source}: query {q.name!r} must be a push query with rate_hz to run live"
        )
    return q


def _sensor_edges(plan) -> list[str]:
    return [n.params["edge"] for n in plan.nodes if n.kind == "source"]


def run_live(
    setup: Setup,
    *,
    query: str | None = None,
    duration_s: float | None = None,
    record=None,
    callback: Callable[[Measurement], None] | None = None,
    vrpn_out=None,
    on_status: Callable[[list[str]], None] | None = None,
    status_period_s: float = 1.0,
    stop: threading.Event | None = None,
    history_s: float = 1.0,
) -> RunResult:
    """Run the setup's query live until ``duration_s`` passes, ``stop`` is set or Ctrl-C.

    Parameters
    ----------
    record : path, optional
        ``.tfrec`` of the answers; the inputs go next to it (module docstring).
    callback : callable, optional
        Called with every answer (a :class:`Measurement`).
    vrpn_out : VrpnTrackerServer, optional
        Every answer is also served as sensor 0 of this VRPN tracker.
    on_status : callable, optional
        Called every ``status_period_s`` with one status line per sensor.
    """
    q = _push_query(setup, query)
    plan = setup.plan(q)
    edges = _sensor_edges(plan)
    missing = [e for e in edges if e not in setup.inputs]
    if missing:
        raise ValueError(
            f"{setup.source}: sensor(s) {missing} have no 'input:' (a live tracker); "
            "add one, or replay a recording with --replay"
        )
    sources = {e: LiveSource(e) for e in edges}

    def on_answer(m: Measurement) -> None:
        if vrpn_out is not None:
            vrpn_out.report(0, m.pose.position, m.pose.quaternion, m.t_ns)
        if callback is not None:
            callback(m)

    net, sink = plan.build(sources, callback=on_answer, record=record, history_s=history_s)
    sampler = next(c for c in net.components.values() if isinstance(c, Sampler))
    net.reset()
    warm_up(net)
    inputs = make_inputs({e: (setup.inputs[e], setup.graph.edge(e).covariance) for e in edges})
    names = {(id(inp), i): b.name for inp in inputs for i, b in enumerate(inp.bodies)}
    writers: dict[str, tuple[RecordingWriter, RecordingWriter]] = {}
    if record is not None:
        for e in edges:
            edge = setup.graph.edge(e)
            writers[e] = tuple(
                RecordingWriter(p, edge.source, edge.target, covariance=True)
                for p in input_paths(record, e)
            )

    events: queue.SimpleQueue = queue.SimpleQueue()
    lock = threading.Lock()
    last = [0]
    floor = [0]

    def packet(inp: LiveInput, data: bytes, stamp: int) -> None:
        with lock:
            a = max(stamp, last[0] + 1, floor[0])
            pairs = inp.handle(data, a)
            for k, (bi, s) in enumerate(pairs):
                events.put((a + k, names[(id(inp), bi)], s._replace(arrival_ns=a + k)))
            last[0] = a + max(len(pairs) - 1, 0)

    clock = net.clock

    def dispatch(arrival: int, name: str, s: Sample) -> None:
        clock.now_ns = arrival
        clock.dispatch_wall_ns = time.perf_counter_ns()
        pose = sources[name].deliver(s)
        if pose is not None and name in writers:
            p, qq, c = pose.position, pose.quaternion, pose.covariance
            writers[name][0].append_sample(s.t_ns, p, qq, c)
            writers[name][1].append_sample(arrival, p, qq, c)

    period = sampler.period_ns
    ticks = 0

    def fire(t: int) -> None:
        nonlocal ticks
        clock.now_ns = t
        clock.dispatch_wall_ns = time.perf_counter_ns()
        sampler.tick(t)
        ticks += 1

    t_start = host_ns()
    next_tick = -(-t_start // period) * period
    sampler.start_ns = next_tick
    deadline = None if duration_s is None else t_start + int(duration_s * 1e9)
    next_status = t_start + int(status_period_s * 1e9)
    stop = stop or threading.Event()
    interrupted = False
    for inp in inputs:
        inp.start(packet)
    for inp in inputs:
        inp.ready.wait(5.0)
    if on_status is not None:
        on_status([f"listening: {', '.join(b.name for i in inputs for b in i.bodies)}"])
    try:
        while not stop.is_set():
            now = host_ns()
            if deadline is not None and now >= deadline:
                break
            if on_status is not None and now >= next_status:
                on_status([b.status.line(now, b.spec.stale_s) for i in inputs for b in i.bodies])
                next_status = now + int(status_period_s * 1e9)
            wait = min(next_tick - now, 100_000_000)
            try:
                item = events.get(timeout=max(wait, 0) * 1e-9) if wait > 0 else events.get_nowait()
            except queue.Empty:
                item = None
            if item is not None:
                arrival, name, s = item
                while next_tick < arrival:
                    fire(next_tick)
                    next_tick += period
                dispatch(arrival, name, s)
                continue
            if host_ns() >= next_tick:
                with lock:
                    if not events.empty():
                        continue
                    floor[0] = max(floor[0], next_tick + 1)
                fire(next_tick)
                next_tick += period
    except KeyboardInterrupt:
        interrupted = True
    finally:
        for inp in inputs:
            inp.stop()
        for c in net.components.values():
            c.finish()
        for pair in writers.values():
            for w in pair:
                w.close()
    end = host_ns()
    return RunResult(
        answers=sink.stats.events_in,
        ticks=ticks,
        statuses={b.name: b.status.summary(end, b.spec.stale_s) for i in inputs for b in i.bodies},
        stats=net.stats(),
        record=None if record is None else Path(record),
        duration_s=(end - t_start) * 1e-9,
        interrupted=interrupted,
        inputs=inputs,
    )


class _ArrivalPlayer(RecordingPlayer):
    """A recorded live input: each sample arrives at its recorded dispatch time."""

    def __init__(self, name, exposure, arrival):
        self._arrival = np.asarray(arrival.t_ns, dtype=np.int64)
        super().__init__(
            name, exposure.t_ns, exposure.position, exposure.quaternion, exposure.covariance, 0
        )

    def arrivals(self) -> np.ndarray:
        return self._arrival


@dataclass
class ReplayResult:
    """Answers of a replay, the recorded answers, and where they first differ (if)."""

    answers: object
    recorded: object
    identical: bool
    mismatch: str | None


def replay(setup: Setup, record, *, query: str | None = None, history_s: float = 1.0):
    """Replay a live run recorded at ``record``: feed every sensor's recorded inputs at
    their dispatch times through the same dataflow (virtual clock) and compare the answers
    with the recorded ones, bit for bit.

    Raises
    ------
    ValueError
        Missing or inconsistent input recordings (named).
    """
    q = _push_query(setup, query)
    plan = setup.plan(q)
    recorded, _ = read_stream(record, format="native")
    players = {}
    for e in _sensor_edges(plan):
        exp_path, arr_path = input_paths(record, e)
        if not exp_path.exists() or not arr_path.exists():
            raise ValueError(f"{record}: no recorded input of sensor {e!r} ({exp_path.name})")
        exp, _ = read_stream(exp_path, format="native")
        arr, _ = read_stream(arr_path, format="native")
        n = min(len(exp), len(arr))  # a killed run may have written one file further
        exp, arr = exp[:n], arr[:n]
        if not np.array_equal(exp.position, arr.position):
            raise ValueError(f"{arr_path}: records do not match {exp_path.name}")
        players[e] = _ArrivalPlayer(e, exp, arr)
    net, sink = plan.build(players, history_s=history_s)
    sampler = next(c for c in net.components.values() if isinstance(c, Sampler))
    if len(recorded) == 0:
        raise ValueError(f"{record}: the run recorded no answers")
    offset = int(round(q.time_offset_s * 1e9))
    sampler.start_ns = int(recorded.t_ns[0]) - offset
    net.run(until_ns=int(recorded.t_ns[-1]) - offset)
    got = sink.to_stream(q.source, q.target)
    mismatch = None
    if len(got) != len(recorded):
        mismatch = f"{len(got)} answers replayed, {len(recorded)} recorded"
    else:
        for field_name in ("t_ns", "position", "quaternion", "covariance"):
            a, b = getattr(got, field_name), getattr(recorded, field_name)
            if not np.array_equal(a, b):
                bad = np.flatnonzero((a != b).reshape(len(a), -1).any(axis=1))
                mismatch = f"{field_name} differs at answer {int(bad[0])} ({len(bad)} answers)"
                break
    return ReplayResult(got, recorded, mismatch is None, mismatch)
