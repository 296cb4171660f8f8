"""``trackflow run``: a setup's dataflow driven live by its trackers, recorded, replayable.

Live event order. Every packet is stamped on arrival (host clock, ``time.time_ns``) under one
lock that also hands out strictly increasing dispatch times (samples of one packet get
``arrival, arrival + 1 ns, ...``); the receiving thread dispatches the packet under that
lock (no hand-off to another thread), after the sampler ticks before its samples, a sample
before a tick at the same nanosecond, exactly as the virtual clock of
:meth:`trackflow.dataflow.Network.run` orders them. The scheduling thread fires, under the
same lock, the ticks that fall due while no packet arrives; a packet stamped before an
already fired tick is dispatched after it (the lock raises a floor under later stamps). The
answers therefore depend only on the recorded inputs and their dispatch times, and
:func:`replay` reproduces them bit for bit.

Recording (``record=out.tfrec``): ``out.tfrec`` holds the answers (``T_source_target`` of the
query with covariance, as :class:`trackflow.dataflow.Recorder` writes them); for every
sensor ``out.<sensor>.tfrec`` holds its measurements stamped with the mapped exposure time,
and ``out.<sensor>.arrival.tfrec`` the same records stamped with their dispatch time.
"""

from __future__ import annotations

import contextlib
import gc
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..dataflow import (
    Component,
    KalmanBank,
    KalmanFilter,
    Measurement,
    Network,
    Plan,
    RecordingPlayer,
    Sampler,
    Setup,
)
from ..filters import Layouts, PoseFilterBank
from ..io import RecordingWriter, read_stream
from ..math import Pose, UncertainPose, check_covariance
from .inputs import (
    CheckedSample,
    LiveInput,
    Sample,
    SampleBlock,
    host_ns,
    make_inputs,
    warm_up_inputs,
)

__all__ = [
    "LiveSource",
    "LiveSources",
    "ReplayResult",
    "calm_gc",
    "collect_due",
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
        self._valid_cov = None  # the last read-only covariance found valid (checked once)

    def deliver(self, s: Sample) -> UncertainPose | None:
        """Take a sample (:meth:`accept`) and push its measurement to the consumers."""
        pose = self.accept(s)
        if pose is not None:
            self.emit(Measurement(s.t_ns, pose, s.t_ns))
        return pose

    def accept(self, s: Sample) -> UncertainPose | None:
        """The sample's pose, counted and checked as :meth:`deliver` does, not yet pushed;
        ``None`` for a counted rejection."""
        if not self._fresh(s.t_ns):
            return None
        if type(s) is CheckedSample:
            pose = UncertainPose._trusted(s.position, s.quaternion, s.covariance)
        else:
            pose = self._plain_pose(s)
        if pose is None:  # not plainly valid: the full checks (they may normalise)
            try:
                pose = UncertainPose(Pose(s.position, s.quaternion), s.covariance)
            except ValueError:
                self.stats.reject("invalid pose or covariance")
                return None
        self._last_t = s.t_ns
        return pose

    def _fresh(self, t_ns: int) -> bool:
        """Count a sample in; ``False`` (a counted rejection) if it is not after the last
        accepted one."""
        self.stats.events_in += 1
        if self._last_t is not None and t_ns <= self._last_t:
            self.stats.reject("timestamp backwards")
            return False
        return True

    def _plain_pose(self, s: Sample) -> UncertainPose | None:
        """The sample's pose without copies when it is plainly valid (float64 arrays of the
        right shapes, a finite position, a quaternion of unit norm to rounding and a valid
        covariance), else ``None``. What :meth:`LiveInput._sample` makes always is; the
        pose shares the sample's arrays, and a read-only covariance (a body's nominal one)
        is checked only the first time it is seen."""
        p, q, c = s.position, s.quaternion, s.covariance
        if not (
            type(p) is np.ndarray
            and type(q) is np.ndarray
            and type(c) is np.ndarray
            and p.shape == (3,)
            and q.shape == (4,)
            and p.dtype == q.dtype == np.float64
        ):
            return None
        x, y, z = p.tolist()
        qx, qy, qz, qw = q.tolist()
        if not (
            math.isfinite(x + y + z) and abs(qx * qx + qy * qy + qz * qz + qw * qw - 1.0) < 1e-12
        ):
            return None
        if c is not self._valid_cov:
            try:
                if check_covariance(c) is not c:
                    return None
            except ValueError:
                return None
            if not c.flags.writeable:
                self._valid_cov = c
        return UncertainPose._trusted(p, q, c)


class LiveSources:
    """The live sources of a network delivering the samples of a packet together.

    :meth:`deliver` does what ``sources[name].deliver(sample)`` one after the other does;
    the measurements of sources whose only consumer is a plain :class:`KalmanFilter` go to
    the filters in one batched call (:class:`trackflow.dataflow.KalmanBank`), the others
    one by one, in order (the batch so far is pushed first).

    Parameters
    ----------
    sources : dict
        ``{name: LiveSource}``, wired to their consumers.
    """

    def __init__(self, sources: dict[str, LiveSource]):
        self.sources = sources
        kfs: list[KalmanFilter] = []
        self._row: dict[str, tuple[int, list]] = {}
        for name, src in sources.items():
            if len(src.consumers) == 1 and type(src.consumers[0][0]) is KalmanFilter:
                self._row[name] = (len(kfs), list(src.consumers))
                kfs.append(src.consumers[0][0])
        #: the filters fed directly by a source, in one bank (pull answers through it)
        self.filters = KalmanBank(kfs)
        self.row = {name: r[0] for name, r in self._row.items()}
        self._lanes = Layouts(self._make_lane)  # per list of names of deliver_block

    def deliver(self, items, clock=None) -> list[UncertainPose | None]:
        """Deliver ``(name, sample)`` pairs in order; the accepted poses (``None`` for a
        rejection). ``clock`` (a network's) is set to each sample's arrival before a
        consumer other than a batched filter sees it, and to the last one's at the end."""
        batch: list[tuple[int, Measurement]] = []
        out: list[UncertainPose | None] = []
        for name, s in items:
            src = self.sources[name]
            row = self._row.get(name)
            if row is not None and src.consumers == row[1]:
                pose = src.accept(s)
                if pose is not None:
                    src.stats.events_out += 1
                    batch.append((row[0], Measurement(s.t_ns, pose, s.t_ns)))
            else:
                if batch:
                    self.filters.push(batch)
                    batch = []
                if clock is not None:
                    clock.now_ns = s.arrival_ns
                    clock.dispatch_wall_ns = time.perf_counter_ns()
                pose = src.deliver(s)
            out.append(pose)
        if batch:
            self.filters.push(batch)
        if clock is not None and items:
            clock.now_ns = items[-1][1].arrival_ns
        return out

    def deliver_block(
        self, names, block: SampleBlock, arrival_ns: int, clock=None, answer=None
    ) -> list:
        """:meth:`deliver` of the samples of a block, sample ``k`` of source ``names[k]``
        dispatched at ``arrival_ns + k``: the same outcome, with the block's arrays going to
        the batched filters as they are (:meth:`KalmanBank.push_block`) when every source
        feeds one only. Returns per sample whether it was accepted.

        ``answer = (at_ns, deliver)``: the packet's answers, the poses of the sources'
        filters at ``at_ns`` [ns] as :class:`~trackflow.filters.PredictedPoses` in the order
        of ``names``, go to ``deliver`` as soon as the filters are updated, before their
        bookkeeping (:meth:`KalmanBank.push_block`); every source must feed one filter."""
        lane = self._lanes(tuple(names))
        if lane is not None and self._fresh_lane(lane, block.t_ns):
            srcs, index = lane
            try:  # the sources' counts after the answer: a sample in and out each
                self.filters.push_block(
                    index, block.t_ns, block.position, block.quaternion, block.covariance, answer
                )
            finally:
                t = block.t_ns
                for src, _ in srcs:
                    src._last_t = t
                    stats = src.stats
                    stats.events_in += 1
                    stats.events_out += 1
            if clock is not None:
                clock.now_ns = arrival_ns + len(names) - 1
            return [True] * len(names)
        return self._deliver_block(names, block, arrival_ns, clock, answer)

    def _make_lane(self, key: tuple) -> tuple | None:
        """``(sources and their consumer lists, filter rows)`` of a list of names that feed
        one filter each (a tracker's packet layout, looked up once: :class:`Layouts`), else
        ``None``."""
        rows = [self._row.get(n) for n in key]
        if not key or None in rows or len(set(key)) != len(key):
            return None
        return [(self.sources[n], r[1]) for n, r in zip(key, rows)], [r[0] for r in rows]

    @staticmethod
    def _fresh_lane(lane: tuple, t_ns: int) -> bool:
        """Whether every source of ``lane`` still feeds its one filter only and takes a
        sample at ``t_ns`` (after its last one): then :meth:`deliver_block` counts them
        after the answer, else the general path counts and rejects one by one."""
        for src, consumers in lane[0]:
            last = src._last_t
            if src.consumers != consumers or (last is not None and t_ns <= last):
                return False
        return True

    def _deliver_block(self, names, block, arrival_ns, clock, answer) -> list:
        """:meth:`deliver_block` of samples not all fresh or not all feeding one filter."""
        srcs, rows = self.sources, self._row
        index = []
        for name in names:
            row = rows.get(name)
            if row is None or srcs[name].consumers != row[1]:
                lone = [n for n in names if n not in rows]
                if answer is not None and lone:
                    raise ValueError(f"{lone[0]}: answers need a source that feeds one filter")
                items = _dispatched(names, block, arrival_ns)
                ok = [pose is not None for pose in self.deliver(items, clock)]
                if answer is not None:
                    self.filters.answer([rows[n][0] for n in names], answer)
                return ok
            index.append(row[0])
        t = block.t_ns
        ok = []
        for name in names:
            src = srcs[name]
            fresh = src._fresh(t)
            if fresh:
                src._last_t = t
                src.stats.events_out += 1
            ok.append(fresh)
        if all(ok):
            self.filters.push_block(
                index, t, block.position, block.quaternion, block.covariance, answer
            )
        elif any(ok):
            at = [k for k, good in enumerate(ok) if good]
            self.filters.push_block(
                [index[k] for k in at], t, block.position[at], block.quaternion[at],
                block.covariance[at],
            )  # fmt: skip
        if answer is not None and not all(ok):
            self.filters.answer(index, answer)
        if clock is not None and names:
            clock.now_ns = arrival_ns + len(names) - 1
        return ok


def _dispatched(names, samples, a: int) -> list[tuple[str, Sample]]:
    """``(name, sample)`` of ``(body index, sample)`` pairs (or a block), sample ``k`` of
    sensor ``names[k]`` with the dispatch time ``a + k`` as its arrival."""
    return [(n, s._replace(arrival_ns=a + k)) for k, (n, (_, s)) in enumerate(zip(names, samples))]


def warm_up(net) -> None:
    """Run every Kalman filter of ``net`` once on a throwaway copy, alone and in a filter
    bank, and the inputs' packet kernels, so that compiling them (numba, first use in a
    process) happens before the trackers are listened to."""
    seen = set()
    for c in net.components.values():
        if isinstance(c, KalmanFilter) and (c.motion, c.history_s) not in seen:
            seen.add((c.motion, c.history_s))
            f = c.filter_factory(c.motion, c.history_s)
            u = UncertainPose(Pose(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])), np.eye(6) * 1e-6)
            f.update_pose(0.0, u)
            f.update_pose(0.01, u)
            f.predict(0.02)
            # and the batched kernels a packet of several bodies runs (LiveSources)
            bank = PoseFilterBank([c.filter_factory(c.motion, c.history_s) for _ in range(2)])
            for t in (0.0, 0.01):
                bank.update_poses([0, 1], [t, t], [u, u])
            bank.predict_poses([0, 1], [0.02, 0.02])
            z = [np.stack([a, a]) for a in (u.position, u.quaternion, u.covariance)]
            bank.update_block([0, 1], [0.02, 0.02], *z, defer=True, predict_at=0.025)
            bank.settle()  # a packet with its answers (LiveSources.deliver_block)
    warm_up_inputs()  # and the inputs' kernels


@contextlib.contextmanager
def calm_gc():
    """Within the block, garbage collection stays off the packets' path.

    Entered once the network is built and warm: it collects, then freezes every object alive
    (:func:`gc.freeze`), so that the collections a live run makes look only at the objects
    made since (a full collection over the imported modules and compiled kernels would
    otherwise stall one packet by milliseconds), and turns the automatic collector off: a
    thread calls :func:`collect_due` where it has just finished its work (after a packet's
    answers, when the next packet is furthest away) to make the collections the collector
    would have made. On exit the collector is on and the objects unfrozen again.
    """
    gc.collect()
    gc.freeze()
    was_on = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_on:
            gc.enable()
        gc.unfreeze()


def collect_due() -> None:
    """The collection the automatic collector would make now (by its thresholds: the oldest
    generation whose count is due), or none; for use inside :func:`calm_gc`."""
    t0, t1, t2 = gc.get_threshold()
    c0, c1, c2 = gc.get_count()
    if c0 > t0:
        gc.collect(2 if c2 > t2 else 1 if c1 > t1 else 0)


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


class _Scheduler:
    """Time-ordered dispatch of live samples and sampler ticks (module docstring).

    A receiving thread dispatches its packet itself (:meth:`packet`: no hand-off to another
    thread, so a packet's answers are not delayed by a thread switch); the scheduling
    thread (:meth:`loop`) fires the ticks that fall due while no packet arrives. Both hold
    one lock, so events are dispatched one at a time, in time order.
    """

    def __init__(self, net, sampler: Sampler, sources: dict, inputs: list, writers: dict):
        self.clock = net.clock
        self.sampler = sampler
        self.sources = sources
        self.delivery = LiveSources(sources)
        self.writers = writers
        self.names = {id(i): [b.name for b in i.bodies] for i in inputs}
        self.lock = threading.Lock()
        self.last = 0  # the latest dispatch time handed out
        self.floor = 0  # no dispatch time at or below a fired tick
        self.next_tick = 0  # the next tick to fire (set before the inputs start)
        self.ticks = 0
        self.error: BaseException | None = None  # raised in a receiving thread
        self.stop = threading.Event()

    def packet(self, inp: LiveInput, data: bytes, stamp: int) -> None:
        """Decode a packet and dispatch its samples with strictly increasing dispatch times
        ``a, a + 1, ...``, after the ticks before them (a sample first at ties)."""
        with self.lock:
            if self.stop.is_set():  # the run is over (or failed): nothing more dispatched
                return
            try:
                a = max(stamp, self.last + 1, self.floor)
                samples = inp.handle(data, a)
                self.last = a + max(len(samples) - 1, 0)
                if samples:
                    names = self.names[id(inp)]
                    if type(samples) is SampleBlock:
                        index = samples.index
                    else:
                        index = [bi for bi, _ in samples]
                    self._dispatch_packet([names[bi] for bi in index], samples, a)
            except BaseException as exc:  # reported by the scheduling thread, which stops
                self.error = exc
                self.stop.set()
        collect_due()  # the packet is answered: the next one is furthest away

    def _dispatch_packet(self, names: list[str], samples, a: int) -> None:
        """The samples of one packet (``(body index, sample)`` pairs or a block), sample
        ``k`` of sensor ``names[k]`` at dispatch time ``a + k``, split at the ticks among
        them."""
        period = self.sampler.period_ns
        i, n = 0, len(samples)
        while i < n:
            while self.next_tick < a + i:
                self.fire(self.next_tick)
                self.next_tick += period
            j = min(n, self.next_tick - a + 1)  # the samples at or before the next tick
            self.dispatch(names[i:j], samples[i:j], a + i)
            i = j

    def dispatch(self, names: list[str], samples, a: int) -> None:
        """Deliver samples with no tick between them, sample ``k`` at ``a + k`` (one batch,
        :class:`LiveSources`), and record the accepted ones."""
        self.clock.now_ns = a
        self.clock.dispatch_wall_ns = time.perf_counter_ns()
        if type(samples) is SampleBlock:
            ok = self.delivery.deliver_block(names, samples, a, self.clock)
            if self.writers:
                for k, (name, good) in enumerate(zip(names, ok)):
                    if good and name in self.writers:
                        self._record(
                            name, samples.t_ns, a + k, samples.position[k],
                            samples.quaternion[k], samples.covariance[k],
                        )  # fmt: skip
            return
        items = _dispatched(names, samples, a)
        poses = self.delivery.deliver(items, self.clock)
        if self.writers:
            for (name, s), pose in zip(items, poses):
                if pose is not None and name in self.writers:
                    self._record(
                        name, s.t_ns, s.arrival_ns, pose.position, pose.quaternion,
                        pose.covariance,
                    )  # fmt: skip

    def _record(self, name: str, t_ns: int, arrival_ns: int, p, q, c) -> None:
        """An accepted sample into its sensor's input recordings (exposure and dispatch)."""
        exposure, arrival = self.writers[name]
        exposure.append_sample(t_ns, p, q, c)
        arrival.append_sample(arrival_ns, p, q, c)

    def fire(self, t: int) -> None:
        self.clock.now_ns = t
        self.clock.dispatch_wall_ns = time.perf_counter_ns()
        self.sampler.tick(t)
        self.ticks += 1

    def loop(self, deadline: int | None, stop: threading.Event, status) -> None:
        """Fire the ticks that fall due until ``deadline`` (host ns) or ``stop``;
        ``status(now)`` is called between them. An error raised while a receiving thread
        dispatched its packet is raised here."""
        period = self.sampler.period_ns
        while not (stop.is_set() or self.stop.is_set()):
            now = host_ns()
            if deadline is not None and now >= deadline:
                break
            status(now)
            collect_due()  # also when no packet comes
            wait = min(self.next_tick - now, 100_000_000)
            if wait > 0:
                self.stop.wait(wait * 1e-9)
                continue
            with self.lock:  # no sample stamped before the tick may still come after it
                if host_ns() >= self.next_tick and self.error is None:
                    self.floor = max(self.floor, self.next_tick + 1)
                    self.fire(self.next_tick)
                    self.next_tick += period
        with self.lock:
            self.stop.set()
        if self.error is not None:
            raise self.error


def _writers(setup: Setup, edges: list[str], record) -> dict:
    out = {}
    if record is not None:
        for e in edges:
            edge = setup.graph.edge(e)
            out[e] = tuple(
                RecordingWriter(p, edge.source, edge.target, covariance=True)
                for p in input_paths(record, e)
            )
    return out


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
    on_network: Callable[[Network, Plan, list[LiveInput]], object] | None = None,
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
        Called once with ``["listening: ..."]`` when the inputs are open, then every
        ``status_period_s`` with one status line per sensor.
    on_network : callable, optional
        Called once with the built network (reset, filters warmed up), the query's plan and
        the live inputs (their :attr:`LiveInput.bodies` carry each sensor's status) before the
        trackers are listened to: the place to add push consumers, such as a browser view
        (``trackflow run --view``). Each sensor's source is the component named like its edge.
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
    if on_network is not None:
        on_network(net, plan, inputs)
    writers = _writers(setup, edges, record)
    sched = _Scheduler(net, sampler, sources, inputs, writers)
    bodies = [b for i in inputs for b in i.bodies]
    next_status = [0]

    def status(now: int) -> None:
        if on_status is not None and now >= next_status[0]:
            on_status([b.status.line(now, b.spec.stale_s) for b in bodies])
            next_status[0] = now + int(status_period_s * 1e9)

    t_start = host_ns()
    next_tick = -(-t_start // sampler.period_ns) * sampler.period_ns
    sampler.start_ns = sched.next_tick = next_tick
    deadline = None if duration_s is None else t_start + int(duration_s * 1e9)
    next_status[0] = t_start + int(status_period_s * 1e9)
    interrupted = False
    for inp in inputs:
        inp.start(sched.packet)
    try:
        for inp in inputs:
            inp.ready.wait(5.0)
        if on_status is not None:
            on_status([f"listening: {', '.join(b.name for b in bodies)}"])
        with calm_gc():
            sched.loop(deadline, stop or threading.Event(), status)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        with sched.lock:  # no packet is dispatched from here on (also after Ctrl-C)
            sched.stop.set()
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
        ticks=sched.ticks,
        statuses={b.name: b.status.summary(end, b.spec.stale_s) for b in bodies},
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
