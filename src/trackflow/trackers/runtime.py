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
and ``out.<sensor>.arrival.tfrec`` the same records stamped with their dispatch time;
``out.switches.jsonl`` every move of a query between its paths (failover,
:mod:`trackflow.trackers.switch_log`).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..dataflow import (
    BACKLOG_NS,
    SAMPLE,
    Component,
    KalmanBank,
    KalmanFilter,
    Measurement,
    Network,
    OnlineOffsetSpec,
    PathSwitch,
    Plan,
    RecordingPlayer,
    Sampler,
    Scheduler,
    Setup,
    Ticker,
    WallTime,
    collect_due,
    keep_newest,
    warm_up,
)
from ..errors import InputError
from ..filters import Layouts
from ..io import RecordingWriter, read_stream
from ..math import Pose, UncertainPose, check_covariance
from ..ros2 import close_publishers, open_publishers
from .inputs import (
    CheckedSample,
    LiveInput,
    Sample,
    SampleBlock,
    host_ns,
    make_inputs,
    warm_up_inputs,
)
from .online_offsets import OnlineOffsets, offsets_log_path
from .switch_log import SwitchLog, read_switch_log, switch_log_path

__all__ = [
    "LiveSource",
    "LiveSources",
    "InputSource",
    "ReplayResult",
    "RunResult",
    "input_paths",
    "measured_attributes",
    "replay",
    "run_live",
]


class LiveSource(Component):
    """The push source of a live sensor: :meth:`deliver` turns a :class:`Sample` into a
    :class:`Measurement` (``t_ns`` = exposure on the host clock, ``origin_ns`` the same).
    A sample not after the previous one ("timestamp backwards"), older than
    :data:`~trackflow.dataflow.BACKLOG_NS` when it arrived (a stalled tracker's backlog) or
    with an invalid pose or covariance is a counted rejection, as in
    :class:`trackflow.dataflow.RecordingPlayer`.

    The backlog window is judged on the tracker's own times: ``shift_ns``, the online delay
    correction its connection added (:meth:`LiveInput.request_shift`), is taken back out
    first. A correction says what moment a sample shows, not how late it came: a tracker
    found 480 ms slower than its stamps still delivers every frame as it did before."""

    push_out = True
    kind = "live"

    def __init__(self, name: str):
        super().__init__(name)
        self.reset()

    def reset(self) -> None:
        super().reset()
        self._last_t: int | None = None
        self._valid_cov = None  # the last read-only covariance found valid (checked once)

    def deliver(self, s: Sample, shift_ns: int = 0) -> UncertainPose | None:
        """Take a sample (:meth:`accept`) and push its measurement to the consumers."""
        pose = self.accept(s, shift_ns)
        if pose is not None:
            self.emit(Measurement(s.t_ns, pose, s.t_ns))
        return pose

    def accept(self, s: Sample, shift_ns: int = 0) -> UncertainPose | None:
        """The sample's pose, counted and checked as :meth:`deliver` does, not yet pushed;
        ``None`` for a counted rejection. ``shift_ns``: the online correction in the
        sample's time [ns] (class docstring)."""
        if not self._fresh(s.t_ns, s.arrival_ns, shift_ns):
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

    def _fresh(self, t_ns: int, arrival_ns: int, shift_ns: int = 0) -> bool:
        """Count a sample in; ``False`` (a counted rejection) if it is not after the last
        accepted one or arrived more than :data:`~trackflow.dataflow.BACKLOG_NS` after it
        was taken (by the tracker's own time, ``t_ns - shift_ns``)."""
        self.stats.events_in += 1
        if self._last_t is not None and t_ns <= self._last_t:
            self.stats.reject("timestamp backwards")
            return False
        if arrival_ns - (t_ns - shift_ns) > BACKLOG_NS:
            self.stats.reject("older than the backlog window")
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
    the measurements of sources whose only consumer is a bankable :class:`KalmanFilter` go to
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
            dst = src.consumers[0][0] if len(src.consumers) == 1 else None
            if isinstance(dst, KalmanFilter) and dst.bankable:  # its updates may be batched
                self._row[name] = (len(kfs), list(src.consumers))
                kfs.append(src.consumers[0][0])
        #: the filters fed directly by a source, in one bank (pull answers through it)
        self.filters = KalmanBank(kfs)
        self.row = {name: r[0] for name, r in self._row.items()}
        self._lanes = Layouts(self._make_lane)  # per list of names of deliver_block

    def deliver(self, items, clock=None, shift_ns: int = 0) -> list[UncertainPose | None]:
        """Deliver ``(name, sample)`` pairs in order; the accepted poses (``None`` for a
        rejection). ``clock`` (a network's) is set to each sample's arrival before a
        consumer other than a batched filter sees it, and to the last one's at the end.
        ``shift_ns``: the online correction in the samples' times (:class:`LiveSource`)."""
        batch: list[tuple[int, Measurement]] = []
        out: list[UncertainPose | None] = []
        for name, s in items:
            src = self.sources[name]
            row = self._row.get(name)
            if row is not None and src.consumers == row[1]:
                pose = src.accept(s, shift_ns)
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
                pose = src.deliver(s, shift_ns)
            out.append(pose)
        if batch:
            self.filters.push(batch)
        if clock is not None and items:
            clock.now_ns = items[-1][1].arrival_ns
        return out

    def deliver_block(
        self, names, block: SampleBlock, arrival_ns: int, clock=None, answer=None, shift_ns: int = 0
    ) -> list:
        """:meth:`deliver` of the samples of a block, sample ``k`` of source ``names[k]``
        dispatched at ``arrival_ns + k``: the same outcome, with the block's arrays going to
        the batched filters as they are (:meth:`KalmanBank.push_block`) when every source
        feeds one only. Returns per sample whether it was accepted.

        ``answer = (at_ns, deliver)``: the packet's answers, the poses of the sources'
        filters at ``at_ns`` [ns] as :class:`~trackflow.filters.PredictedPoses` in the order
        of ``names``, go to ``deliver`` as soon as the filters are updated, before their
        bookkeeping (:meth:`KalmanBank.push_block`); every source must feed one filter.
        ``shift_ns``: the online correction in the block's time (:class:`LiveSource`)."""
        lane = self._lanes(tuple(names))
        t = block.t_ns
        if lane is not None and self._fresh_lane(lane, t, arrival_ns - (t - shift_ns)):
            srcs, index = lane
            try:  # the sources' counts after the answer: a sample in and out each
                self.filters.push_block(
                    index, t, block.position, block.quaternion, block.covariance, answer
                )
            finally:
                for src, _ in srcs:
                    src._last_t = t
                    stats = src.stats
                    stats.events_in += 1
                    stats.events_out += 1
            if clock is not None:
                clock.now_ns = arrival_ns + len(names) - 1
            return [True] * len(names)
        return self._deliver_block(names, block, arrival_ns, clock, answer, shift_ns)

    def _make_lane(self, key: tuple) -> tuple | None:
        """``(sources and their consumer lists, filter rows)`` of a list of names that feed
        one filter each (a tracker's packet layout, looked up once: :class:`Layouts`), else
        ``None``."""
        rows = [self._row.get(n) for n in key]
        if not key or None in rows or len(set(key)) != len(key):
            return None
        return [(self.sources[n], r[1]) for n, r in zip(key, rows)], [r[0] for r in rows]

    @staticmethod
    def _fresh_lane(lane: tuple, t_ns: int, age_ns: int) -> bool:
        """Whether every source of ``lane`` still feeds its one filter only and takes a
        sample at ``t_ns`` (after its last one) that arrived ``age_ns`` after it was taken
        (within the backlog window): then :meth:`deliver_block` counts them after the
        answer, else the general path counts and rejects one by one."""
        if age_ns > BACKLOG_NS:
            return False
        for src, consumers in lane[0]:
            last = src._last_t
            if src.consumers != consumers or (last is not None and t_ns <= last):
                return False
        return True

    def _deliver_block(self, names, block, arrival_ns, clock, answer, shift_ns) -> list:
        """:meth:`deliver_block` of samples not all fresh or not all feeding one filter."""
        srcs, rows = self.sources, self._row
        index = []
        for name in names:
            row = rows.get(name)
            if row is None or srcs[name].consumers != row[1]:
                lone = [n for n in names if n not in rows]
                if answer is not None and lone:
                    raise InputError(f"{lone[0]}: answers need a source that feeds one filter")
                items = _dispatched(names, block, arrival_ns)
                ok = [pose is not None for pose in self.deliver(items, clock, shift_ns)]
                if answer is not None:
                    self.filters.answer([rows[n][0] for n in names], answer)
                return ok
            index.append(row[0])
        t = block.t_ns
        ok = []
        for name in names:
            src = srcs[name]
            fresh = src._fresh(t, arrival_ns, shift_ns)
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
    #: every served query's answer sink (push: Recorder, pull: PullSink), by query name
    sinks: dict[str, Component] = field(default_factory=dict, repr=False)
    #: queries of the setup that could not be planned, with the planner's reason
    unplanned: dict[str, str] = field(default_factory=dict)
    #: failover: each query's path switch (queries with fallback paths only)
    switches: dict[str, PathSwitch] = field(default_factory=dict, repr=False)
    #: each filtered sensor's measured rate, latency and NIS beside its declared figures
    attributes: dict[str, dict] = field(default_factory=dict)
    #: queries published as ROS 2 topics (``ros2:``): topic, key expression, messages sent
    ros2: dict[str, dict] = field(default_factory=dict)
    #: online offsets (the setup's ``online_offsets:``): every pair's last estimate
    online_offsets: list[dict] | None = None
    #: ... and every correction applied (``apply: true``), as in ``out.offsets.jsonl``
    online_corrections: list[dict] | None = None


def _push_query(setup: Setup, query: str | None):
    q = setup.query(query)
    if q.mode != "push" or not q.rate_hz:
        raise InputError(
            f"{setup.source}: query {q.name!r} must be a push query with rate_hz to run live"
        )
    return q


def _sensor_edges(plan) -> list[str]:
    return [n.params["edge"] for n in plan.nodes if n.kind == "source"]


def _measured(setup: Setup) -> list[str]:
    """Every sensor (measured edge) the setup names, in file order."""
    return [e.name for e in setup.graph.edges if e.kind == "measured"]


def query_record_path(record, query: str) -> Path:
    """Where the answers of push query ``query`` go when it is not the recorded main query:
    ``out.query.<name>.tfrec`` next to ``out.tfrec``."""
    record = Path(record)
    stem = record.name[: -len(record.suffix)] if record.suffix else record.name
    return record.with_name(f"{stem}.query.{query}.tfrec")


class InputSource:
    """A live input (one socket, one or more bodies) as an event source of the scheduler.

    Its receiving thread dispatches each packet itself through
    :meth:`trackflow.dataflow.Scheduler.arrival` (module docstring): the packet is decoded
    at its dispatch time, its samples go to their sensors' sources as one batch
    (:class:`LiveSources`) and the accepted ones into the input recordings.
    """

    kind = SAMPLE

    def __init__(self, inp: LiveInput, delivery: LiveSources, writers: dict):
        self.input = inp
        self.name = ", ".join(b.name for b in inp.bodies)
        self.names = [b.name for b in inp.bodies]
        self.delivery = delivery
        self.writers = writers
        self._sched: Scheduler | None = None

    def next_ns(self) -> None:
        return None  # no timed events: packets come when they come

    def fire(self, t_ns: int) -> None:  # pragma: no cover - never scheduled
        raise RuntimeError(f"live input {self.name!r} has no timed events")

    def open(self, scheduler: Scheduler) -> None:
        self._sched = scheduler
        self.input.start(self._packet)

    def close(self) -> None:
        self.input.stop()

    def _packet(self, inp: LiveInput, data: bytes, stamp: int) -> None:
        """Decode a packet and dispatch its samples at ``a, a + 1, ...`` (ticks among them
        in between, a sample first at ties)."""
        with self._sched.arrival(stamp) as arr:
            if arr is not None:
                samples = inp.handle(data, arr.at_ns)
                if samples:
                    index = (
                        samples.index if type(samples) is SampleBlock else [i for i, _ in samples]
                    )
                    names = [self.names[bi] for bi in index]
                    arr.deliver(
                        len(samples), lambda i, j, a: self.dispatch(names[i:j], samples[i:j], a)
                    )
        collect_due()  # the packet is answered: the next one is furthest away

    def dispatch(self, names: list[str], samples, a: int) -> None:
        """Deliver samples with no tick between them, sample ``k`` at ``a + k`` (one batch),
        and record the accepted ones."""
        clock = self._sched.clock
        shift = self.input.shift_ns  # changed on this (the receiving) thread only
        if type(samples) is SampleBlock:
            ok = self.delivery.deliver_block(names, samples, a, clock, shift_ns=shift)
            for k, (name, good) in enumerate(zip(names, ok)):
                if good and name in self.writers:
                    self._record(
                        name, samples.t_ns, a + k, samples.position[k],
                        samples.quaternion[k], samples.covariance[k],
                    )  # fmt: skip
            return
        items = _dispatched(names, samples, a)
        poses = self.delivery.deliver(items, clock, shift)
        for (name, s), pose in zip(items, poses):
            if pose is not None and name in self.writers:
                self._record(
                    name, s.t_ns, s.arrival_ns, pose.position, pose.quaternion, pose.covariance
                )

    def _record(self, name: str, t_ns: int, arrival_ns: int, p, q, c) -> None:
        """An accepted sample into its sensor's input recordings (exposure and dispatch)."""
        exposure, arrival = self.writers[name]
        exposure.append_sample(t_ns, p, q, c)
        arrival.append_sample(arrival_ns, p, q, c)


def _accounted(body, source: LiveSource, now_ns: int) -> dict:
    """A sensor's status summary with what became of its measurements after the input:
    ``accepted`` (handed to the dataflow, and recorded) and ``dropped`` by reason
    (:class:`LiveSource`'s rejections), so that ``measurements == accepted + sum(dropped)``."""
    out = body.status.summary(now_ns, body.spec.stale_s)
    out["accepted"] = source.stats.events_out
    out["dropped"] = dict(sorted(source.stats.rejections.items()))
    return out


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


def _require_inputs(setup: Setup, edges: list[str]) -> None:
    """Every sensor of a live run needs a live tracker: refused naming file, line and key."""
    missing = [e for e in edges if e not in setup.inputs]
    if missing:
        line = setup.lines.get(f"sensors.{missing[0]}", 0)
        where = f"{setup.source}:{line}" if line else setup.source
        raise InputError(
            f"{where}: sensor(s) {missing} have no 'input:' (a live tracker); trackflow run "
            "opens and records every sensor of the setup: add one, or replay a recording "
            "with --replay"
        )


@dataclass
class _Served:
    """The queries a live run serves: the network, the main query's plan and answer sink,
    every other query's sink, and the queries that could not be planned (with why)."""

    net: Network
    plan: Plan
    sink: Component
    sinks: dict[str, Component]
    unplanned: dict[str, str]
    switches: dict[str, PathSwitch]


def _chain(*callbacks):
    """One callback calling each of ``callbacks`` that is not ``None`` (``None`` if none)."""
    calls = [c for c in callbacks if c is not None]
    if len(calls) <= 1:
        return calls[0] if calls else None

    def call(m: Measurement) -> None:
        for c in calls:
            c(m)

    return call


def _serve_all(setup, main, sources, on_answer, record, history_s, vrpn_out, log,
               ros2=None) -> _Served:  # fmt: skip
    """Build every query of the setup into one network: ``main`` answers to ``on_answer``
    and ``record``; other push queries to ``out.query.<name>.tfrec`` (and VRPN sensor
    1, 2, ... in setup order); pull queries to :class:`PullSink` objects; a query with a
    publisher in ``ros2`` (query name -> callable) to it as well. Path switches report to
    ``log`` (a :class:`SwitchLog`)."""
    ros2 = ros2 or {}
    net = Network()
    plan = setup.plan(main)
    net, sink = plan.build(
        sources, callback=_chain(on_answer, ros2.get(main.name)), record=record,
        history_s=history_s, network=net,
        on_switch=log.callback(main.name),
    )  # fmt: skip
    sinks, unplanned, vrpn_index = {main.name: sink}, {}, 0
    for name, q in setup.queries.items():
        if name == main.name:
            continue
        try:
            other = setup.plan(q)
        except ValueError as exc:
            unplanned[name] = str(exc)
            continue
        callback = None
        if q.mode == "push" and vrpn_out is not None:
            vrpn_index += 1

            def callback(m: Measurement, k=vrpn_index) -> None:
                vrpn_out.report(k, m.pose.position, m.pose.quaternion, m.t_ns)

        path = None if record is None or q.mode != "push" else query_record_path(record, name)
        _, sinks[name] = other.build(
            sources, callback=_chain(callback, ros2.get(name)), record=path,
            history_s=history_s, network=net, prefix=f"{name}:", on_switch=log.callback(name),
        )  # fmt: skip
    for name, src in sources.items():  # sensors no query uses are still opened and recorded
        if name not in net.components:
            net.add(src)
    switches = {}
    for name in sinks:
        c = net.components.get("switch" if name == main.name else f"{name}:switch")
        if isinstance(c, PathSwitch):
            switches[name] = c
    return _Served(net, plan, sink, sinks, unplanned, switches)


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
    online_offsets: OnlineOffsetSpec | OnlineOffsets | None = None,
) -> RunResult:
    """Run the setup live until ``duration_s`` passes, ``stop`` is set or Ctrl-C.

    Every sensor of the setup is opened (its ``input:``) and recorded, and every query is
    served: ``query`` (default: the first push query) is the main one, whose answers go to
    ``callback``, ``record`` and VRPN sensor 0; the other push queries' answers go to
    ``out.query.<name>.tfrec`` and VRPN sensors 1, 2, ...; pull queries are answered by the
    :class:`PullSink` objects in :attr:`RunResult.sinks` (and the network ``on_network``
    gets).

    Parameters
    ----------
    record : path, optional
        ``.tfrec`` of the answers; the inputs go next to it (module docstring).
    callback : callable, optional
        Called with every answer of the main query (a :class:`Measurement`).
    vrpn_out : VrpnTrackerServer, optional
        Answers are also served as sensors of this VRPN tracker.
    on_status : callable, optional
        Called once with ``["listening: ..."]`` when the inputs are open, then every
        ``status_period_s`` with one status line per sensor.
    on_network : callable, optional
        Called once with the built network (reset, filters warmed up), the main query's plan
        and the live inputs (their :attr:`LiveInput.bodies` carry each sensor's status) before
        the trackers are listened to: the place to add push consumers, such as a browser view
        (``trackflow run --view``). Each sensor's source is the component named like its edge.
    online_offsets : OnlineOffsetSpec or OnlineOffsets, optional
        Estimate (and with ``apply``, correct) the relative delays of the trackers that see
        one body while running (:mod:`trackflow.trackers.online_offsets`); default: the
        setup's ``online_offsets:`` block. Corrections go to ``out.offsets.jsonl``. An
        :class:`OnlineOffsets` made by the caller (to show its estimates while the run goes
        on) is attached and closed by the run.
    """
    if query is None:
        push = [n for n, q in setup.queries.items() if q.mode == "push" and q.rate_hz]
        query = push[0] if push else None
    main = _push_query(setup, query)
    edges = _measured(setup)
    _require_inputs(setup, edges)
    sources = {e: LiveSource(e) for e in edges}

    def on_answer(m: Measurement) -> None:
        if vrpn_out is not None:
            vrpn_out.report(0, m.pose.position, m.pose.quaternion, m.t_ns)
        if callback is not None:
            callback(m)

    log = SwitchLog(None if record is None else switch_log_path(record))
    offsets = None
    publishers = open_publishers(setup.ros2)  # before any input: a refused link fails here
    try:
        served = _serve_all(
            setup, main, sources, on_answer, record, history_s, vrpn_out, log, publishers
        )
        net = served.net
        keep_newest(net.components.values())  # answers go to the file and callbacks
        net.reset()
        warm_up(net)
        warm_up_inputs()
        inputs = make_inputs({e: (setup.inputs[e], setup.graph.edge(e).covariance) for e in edges})
        if on_network is not None:
            on_network(net, served.plan, inputs)
        spec = setup.online_offsets if online_offsets is None else online_offsets
        if isinstance(spec, OnlineOffsets):
            offsets = spec
        elif spec is not None:
            log_path = None if record is None else offsets_log_path(record)
            offsets = OnlineOffsets(setup, spec, log_path)
        if offsets is not None:
            offsets.attach(net, inputs)
        writers = _writers(setup, edges, record)
        delivery = LiveSources(sources)
        t_start = host_ns()
        sched = net.scheduler(t_start, None, WallTime(host_ns))
        for inp in inputs:
            sched.add(InputSource(inp, delivery, writers))
        main_ticks = _main_ticker(sched, net, served.sink)
        bodies = [b for i in inputs for b in i.bodies]
        events = [log.new_lines] + ([] if offsets is None else [offsets.new_lines])
        status = _status_printer(
            on_status, bodies, inputs, served.unplanned, status_period_s, events
        )
        deadline = None if duration_s is None else t_start + int(duration_s * 1e9)
        interrupted = False
        try:
            sched.run(deadline, stop=stop, on_idle=status, calm=True)
        except KeyboardInterrupt:
            interrupted = True
        finally:
            if offsets is not None:
                offsets.close()
            net.finish()
            log.close()
            for pair in writers.values():
                for w in pair:
                    w.close()
        end = host_ns()
        result = RunResult(
            answers=served.sink.stats.events_in,
            ticks=main_ticks.fired,
            statuses={b.name: _accounted(b, sources[b.name], end) for b in bodies},
            stats=net.stats(),
            record=None if record is None else Path(record),
            duration_s=(end - t_start) * 1e-9,
            interrupted=interrupted,
            inputs=inputs,
            sinks=served.sinks,
            unplanned=served.unplanned,
            switches=served.switches,
            attributes=measured_attributes(net, setup.graph, edges),
        )
        result.ros2 = {name: p.status() for name, p in publishers.items()}
        if offsets is not None:
            result.online_offsets = offsets.final()
            result.online_corrections = list(offsets.events)
        return result
    finally:
        close_publishers(publishers)


def measured_attributes(net: Network, graph, edges) -> dict[str, dict]:
    """Each sensor of ``edges`` with a filter in ``net``: its measured and declared
    attributes (:class:`trackflow.dataflow.MeasuredAttributes`)."""
    out = {}
    for e in edges:
        kf = net.components.get(f"kf_{e}")
        if isinstance(kf, KalmanFilter):
            out[e] = kf.measured.summary(graph.edge(e))
    return out


def _main_ticker(sched: Scheduler, net: Network, sink: Component) -> Ticker:
    """The ticker of the sampler that feeds ``sink`` (the main query's)."""
    name = next(
        n
        for n, c in net.components.items()
        if isinstance(c, Sampler) and any(dst is sink for dst, _ in c.consumers)
    )
    return next(s for s in sched.sources if isinstance(s, Ticker) and s.name == name)


def _status_printer(on_status, bodies, inputs, unplanned, period_s, events):
    """The run's idle callback: once the inputs are listening, ``listening: ...`` (and the
    queries not served, with why), then a status line per sensor every ``period_s``, and as
    soon as they happen the lines of ``events`` (callables giving the lines since their last
    call: path switches of a :class:`SwitchLog`, online offsets) and a line per change of a
    sensor's notes (``head: 6d ids seen: 0, 1``)."""

    def event_lines() -> list[str]:
        return [line for new_lines in events for line in new_lines()]

    state = {"next": None}
    shown = {b.name: b.status.notes for b in bodies}

    def new_notes() -> list[str]:
        out = []
        for b in bodies:
            notes = b.status.notes  # replaced whole by the input: a new object is new
            if notes is not shown[b.name]:
                shown[b.name] = notes
                out += [f"{b.name}: {text}" for text in notes.values()]
        return out

    def status(now: int) -> None:
        if on_status is None:
            return
        if state["next"] is None:
            for inp in inputs:
                inp.ready.wait(5.0)
            lines = [f"listening: {', '.join(b.name for b in bodies)}"]
            lines += [f"query {n!r} not served: {why}" for n, why in unplanned.items()]
            on_status(lines)
            state["next"] = now + int(period_s * 1e9)
        elif now >= state["next"]:
            new_notes()  # the status lines show them
            on_status([b.status.line(now, b.spec.stale_s) for b in bodies] + event_lines())
            state["next"] = now + int(period_s * 1e9)
        else:
            lines = new_notes() + event_lines()
            if lines:
                on_status(lines)

    return status


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
    with the recorded ones, bit for bit, and the query's path switches with the recorded
    ones (``out.switches.jsonl``, when the run recorded it).

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
            raise InputError(f"{record}: no recorded input of sensor {e!r} ({exp_path.name})")
        exp, _ = read_stream(exp_path, format="native")
        arr, _ = read_stream(arr_path, format="native")
        n = min(len(exp), len(arr))  # a killed run may have written one file further
        exp, arr = exp[:n], arr[:n]
        if not np.array_equal(exp.position, arr.position):
            raise InputError(f"{arr_path}: records do not match {exp_path.name}")
        players[e] = _ArrivalPlayer(e, exp, arr)
    switched = []
    net, sink = plan.build(players, history_s=history_s, on_switch=switched.append)
    sampler = next(c for c in net.components.values() if isinstance(c, Sampler))
    if len(recorded) == 0:
        raise InputError(f"{record}: the run recorded no answers")
    offset = int(round(q.time_offset_s * 1e9))
    # the live run ticked from its start on this grid: from the first tick after the first
    # recorded arrival on, so that a path switch starts judging where the live one did
    first_tick = int(recorded.t_ns[0]) - offset
    period = sampler.period_ns
    first_arrival = min(int(p.arrivals()[0]) for p in players.values() if len(p.t_ns))
    sampler.start_ns = first_tick - max(first_tick - first_arrival, 0) // period * period
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
    log = switch_log_path(record)
    if mismatch is None and log.exists():
        wanted = read_switch_log(log).get(q.name, [])
        moves = [(e.t_ns, e.from_path, e.to_path) for e in switched]
        if moves != [(e.t_ns, e.from_path, e.to_path) for e in wanted]:
            mismatch = f"path switches differ: {len(switched)} replayed, {len(wanted)} recorded"
    return ReplayResult(got, recorded, mismatch is None, mismatch)
