"""Placement of a sensor's filter (thesis 2.4, 7.4): it runs next to its sensor; consumers on
other hosts hold a replica fed with its states.

* :class:`StatePublisher` (on the sensor's agent) publishes the sensor filter's state after
  every measurement that changed it (``docs/wire.md``, version 2); the agent's
  :class:`StateBatch` sends the states of one dispatch round (a tracker's frame) as one
  message (version 3).
* :class:`RemoteFilter` (on a consumer's agent) is the plan's filter node of that sensor. It
  runs no Kalman update: it adopts the published states
  (:meth:`trackflow.filters.PoseKalmanFilter.adopt`), so its ``pull(t)`` - prediction ahead
  of the newest state, smoothing between states behind it - is the sensor filter's own
  ``get(t)``, computed locally without a round trip. Inversion, chaining, time alignment and
  fusion stay at the consumer, as the planner placed them.

A consumer thus receives one small state per sensor measurement instead of re-running the
sensor's filter, and its per-message work is a decode and an append.
"""

from __future__ import annotations

import numpy as np

from ..dataflow import Component, KalmanFilter, Measurement
from ..errors import InputError
from ..graph import MotionSpec
from ..math import UncertainPose
from . import wire
from .clock import time_error_covariance, twist_between
from .innovations import InnovationCheck

__all__ = ["RemoteFilter", "RemoteGet", "StateBatch", "StatePublisher", "warm_up"]

_TWIST_STEP_NS = 1_000_000  # the velocity for the clock's time error: over the last 1 ms


class StateBatch:
    """The filter states an agent's sensors made in one dispatch round, sent as one message.

    Each sensor's :class:`StatePublisher` puts its encoded states into its slot
    (:meth:`slot`); :meth:`flush` sends what the round gathered as one batch message
    (``docs/wire.md``, version 3) on ``trackflow/<realm>/states/<agent>``. The agent calls
    it whenever its scheduler has dispatched every event due
    (:attr:`trackflow.dataflow.Scheduler.drained`): the bodies of one tracker frame, or the
    recordings' samples of one instant, leave together, at most :data:`wire.MAX_BATCH` per
    message. Consumers subscribe once per agent, not once per sensor.

    Parameters
    ----------
    publisher
        A Zenoh publisher (``put(bytes)``) on ``trackflow/<realm>/states/<agent>``.
    """

    def __init__(self, publisher):
        self.publisher = publisher
        self.messages = 0  # batch messages sent
        self._entries: list[tuple[str, bytes]] = []

    @property
    def matched(self) -> bool:
        """Whether a subscriber in the realm takes these states (Zenoh's matching status)."""
        return bool(self.publisher.matching_status.matching)

    def slot(self, edge: str) -> _Slot:
        """What a :class:`StatePublisher` of sensor ``edge`` puts its states into."""
        return _Slot(self, edge)

    def add(self, edge: str, state: bytes) -> None:
        self._entries.append((edge, state))
        if len(self._entries) >= wire.MAX_BATCH:
            self.flush()

    def flush(self) -> None:
        """Send the states gathered since the last flush (nothing if there are none)."""
        if self._entries:
            entries, self._entries = self._entries, []
            self.publisher.put(wire.encode_batch(entries))
            self.messages += 1


class _Slot:
    """One sensor's way into a :class:`StateBatch` (``put(state)``, as a publisher)."""

    __slots__ = ("batch", "edge")

    def __init__(self, batch: StateBatch, edge: str):
        self.batch, self.edge = batch, edge

    def put(self, state: bytes) -> None:
        self.batch.add(self.edge, state)


class StatePublisher(Component):
    """Publishes the state of a sensor's filter after each measurement that changed it.

    Parameters
    ----------
    name : str
    kf : KalmanFilter
        The sensor's filter component (its filter must offer ``snapshot()``, as
        :class:`trackflow.filters.PoseKalmanFilter` does).
    publisher
        Where each encoded state goes (``put(bytes)``): the sensor's slot in its agent's
        :class:`StateBatch`.

    Connect ``kf -> publisher`` (push port 0) before any other consumer of the filter: an
    accepted measurement's state is then encoded before local inference runs. Connect the
    sensor's source to the publisher as well (port 1), after its connection to ``kf``: a
    gated measurement leaves a predicted state in the filter's history, which is published
    from there, so the replicas hold the filter's exact history and answer past queries to
    the last bit as the filter does. Each state is published once.

    ``tap`` (optional, ``tap(host_ns, buf)``) is handed each encoded state after it was
    published, with its send stamp: the agent's thinned streams take theirs from there
    (:mod:`trackflow.distributed.thinning`).
    """

    push_in = 2
    kind = "state publisher"

    def __init__(self, name: str, kf: KalmanFilter, publisher):
        super().__init__(name)
        if not hasattr(kf.filter, "snapshot"):
            raise InputError(
                f"{name}: the filter of {kf.name} ({type(kf.filter).__name__}) cannot be "
                "replicated (no snapshot())"
            )
        self.kf = kf
        self.publisher = publisher
        self.seq = 0
        self.tap = None
        self._last_x = None

    def push(self, m: Measurement, port: int = 0) -> None:
        self.stats.events_in += 1
        f = self.kf.filter  # reset() may have replaced it
        if not f.initialized:
            return
        snap = f.snapshot()
        if snap.x is self._last_x:
            return  # the filter refused the measurement outright: nothing new
        self._last_x = snap.x
        stamp = m.t_ns if port == 0 else m.t_ns - self.kf.stamp_offset_ns  # filter's time
        if stamp * 1e-9 != snap.t:  # inserted out of order: the newest state is a later one
            stamp = int(round(snap.t * 1e9))
        model = f.model
        self.seq += 1
        buf = wire.encode_state(
            snap,
            seq=self.seq,
            stamp_ns=stamp,
            host_ns=self.clock.now_ns,
            origin_ns=self.kf.last_origin,  # of the accepted measurements, as kf.pull
            n_dp=model.n_dp,
            n_do=model.n_do,
            formulation=f.formulation,
        )
        self.publisher.put(buf)
        self.stats.events_out += 1
        if self.tap is not None:
            self.tap(self.clock.now_ns, buf)


class RemoteFilter(KalmanFilter):
    """The filter node of another agent's sensor: a replica fed with that filter's states.

    Built with the edge's motion model and stamp offset exactly as the sensor's agent builds
    its filter, so a plan sharing the sensor's filter node (``same_filter``) uses it. Stamps
    arrive on the sender's clock and are mapped by ``stamp + offset_ns`` (receiver minus
    sender, the :mod:`trackflow.timesync` sign); ``time_sigma_s``
    (the clock offset's uncertainty) enters every answer's covariance through the
    relationship's velocity, ``C += sigma_t^2 xi xi^T``
    (:func:`trackflow.distributed.time_error_covariance`).

    Every adopted state is judged against the sensor's innovations
    (:class:`~trackflow.distributed.innovations.InnovationCheck`, ``innovations``): while
    the sensor advertises a covariance far below what its corrections support, the state's
    covariance is adopted scaled by the measured ratio, counted as ``covariance below its
    innovations``.
    """

    kind = "remote filter"

    def __init__(self, name: str, motion: MotionSpec, *, stamp_offset_ns: int = 0):
        super().__init__(name, motion, role="predictor", stamp_offset_ns=stamp_offset_ns)
        self.time_sigma_s = 0.0

    def reset(self) -> None:
        super().reset()
        model = self.filter.model
        self._model_key = (model.n_dp, model.n_do, self.filter.formulation)
        self.innovations = InnovationCheck(model, self.filter.formulation)
        self.last_judged: list[str] = []

    def push(self, m: Measurement, port: int = 0) -> None:
        raise InputError(f"{self.name}: a remote filter adopts filter states, not measurements")

    def adopt(self, s: wire.StateSample, offset_ns: int = 0, sigma_s: float = 0.0) -> bool:
        """Adopt one received state (counted rejections: another motion model, older than
        the newest state); pushes a trigger at the state's time to push consumers."""
        self.stats.events_in += 1
        f = self.filter
        if (s.n_dp, s.n_do, s.formulation) != self._model_key:
            self.stats.reject("another motion model")
            return False
        t = s.stamp_ns + offset_ns
        snap = s.snapshot(offset_ns)
        for why in self.judge(snap):
            self.stats.reject(why)
        scale = self.innovations.scale
        if scale > 1.0:  # adopted, scaled
            snap = snap._replace(p=snap.p * scale)
        if not f.adopt(snap):
            self.stats.reject("older than the newest state")
            return False
        origin = s.origin_ns + offset_ns
        self.delivered(t, True)
        self.accepted(t, origin)
        self.time_sigma_s = float(sigma_s)
        if self.consumers:  # a trigger (push-mode inference reads the time only)
            self.emit(Measurement(t, f.predict(t * 1e-9), origin))
        return True

    def judge(self, snap) -> list[str]:
        """The innovation check of a state about to be adopted: the reasons to count
        (``covariance below its innovations``: adopted scaled; ``covariance above its
        prediction``, ``correction without information``: adopted as sent)."""
        check = self.innovations
        before = dict(check.counts)
        check.check(snap)
        why = [
            reason
            for key, reason in (
                ("above", "covariance above its prediction"),
                ("degenerate", "correction without information"),
            )
            if check.counts[key] > before[key]
        ]
        if check.scale > 1.0:
            why.append("covariance below its innovations")
        self.last_judged = why
        return why

    def pull(self, t_ns: int) -> Measurement | None:
        m = super().pull(t_ns)
        if m is None or self.time_sigma_s <= 0.0:
            return m
        try:
            before = self.filter.predict((t_ns - _TWIST_STEP_NS) * 1e-9)
        except ValueError:
            return m  # at the start of the history: no velocity yet
        p = m.pose
        xi = twist_between(
            before.position, before.quaternion, p.position, p.quaternion, _TWIST_STEP_NS * 1e-9
        )
        cov = p.covariance + time_error_covariance(xi, self.time_sigma_s)
        return Measurement(m.t_ns, UncertainPose(p.pose, cov), m.origin_ns)

    def describe(self) -> str:
        return super().describe().replace("kalman", "remote filter", 1)


class RemoteGet(KalmanFilter):
    """The filter node of another agent's sensor for pull queries that ask the sensor's agent
    per request (agent option ``pull_via: get``): ``pull(t)`` is one Zenoh query to
    ``get/<edge>?t=`` (a round trip; nothing is streamed).

    Parameters
    ----------
    name : str
    motion : MotionSpec
    fetch : callable
        ``fetch(t_ns) -> Measurement | None``: the sensor filter's answer at ``t_ns`` on this
        agent's clock (the agent maps the clocks and adds the offset's uncertainty).
    stamp_offset_ns : int
        The edge's stamp offset (only so that plans recognise the node as the sensor's
        filter).
    """

    kind = "remote get"

    def __init__(self, name: str, motion: MotionSpec, fetch, *, stamp_offset_ns: int = 0):
        super().__init__(name, motion, role="predictor", stamp_offset_ns=stamp_offset_ns)
        self.fetch = fetch

    def push(self, m: Measurement, port: int = 0) -> None:
        raise InputError(f"{self.name}: a remote get has no push input")

    def pull(self, t_ns: int) -> Measurement | None:
        m = self.fetch(int(t_ns))
        if m is None:
            self.stats.reject("no answer from the sensor's agent")
            return None
        self.stats.events_out += 1
        return m

    def describe(self) -> str:
        return super().describe().replace("kalman", "remote get", 1)


def warm_up(motion: MotionSpec | None = None) -> None:
    """Run the data path's compiled kernels once (filter update, prediction, smoothing,
    state encoding and checks), so that the first real message does not wait for them to
    be compiled or loaded from the cache (a start-up stall of 0.05-2 s otherwise)."""
    from ..dataflow import Network
    from ..math import Pose

    motion = motion or MotionSpec(False, 1, 1, 1.0)
    net = Network()
    kf = net.add(KalmanFilter("kf_warm", motion))
    sent: list[bytes] = []

    class _Keep:
        put = staticmethod(sent.append)

    pub = net.add(StatePublisher("publish_warm", kf, _Keep()))
    net.connect(kf, pub, mode="push", port=0)
    rep = RemoteFilter("kf_warm", motion)
    pose = UncertainPose(Pose([0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0]), np.eye(6) * 1e-6)
    for k in range(3):
        kf.push(Measurement(k * 10_000_000, pose, k * 10_000_000))
    for buf in sent:
        rep.adopt(wire.decode_state(buf))
    for t in (5_000_000, 20_000_000, 30_000_000):
        rep.pull(t)
