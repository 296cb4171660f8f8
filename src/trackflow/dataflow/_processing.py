"""Processing components: inversion, inference, Kalman filter, latest-value buffer, sampler."""

from __future__ import annotations

import math
from collections.abc import Callable

from ..errors import InputError
from ..filters import make_filter
from ..graph import MotionSpec
from ..math import UncertainPose
from ._attributes import MeasuredAttributes
from ._component import Component
from ._events import Measurement
from ._sources import NO_ORIGIN

__all__ = ["Inference", "Inversion", "KalmanFilter", "LatestValue", "Sampler"]


class Inversion(Component):
    """``T_b_a = T_a_b^-1`` with ``C' = J C J^T`` (push in -> push out, or pull -> pull).

    The error convention is ``t_true = t + dt``, ``R_true = R Exp(dtheta)`` on both sides.
    """

    push_in = 1
    pull_in = 1
    push_out = True
    pull_out = True
    kind = "inversion"

    def push(self, m: Measurement, port: int = 0) -> None:
        self.stats.events_in += 1
        self.emit(Measurement(m.t_ns, m.pose.inverse(), m.origin_ns))

    def pull(self, t_ns: int) -> Measurement | None:
        m = self.inputs[0].pull(t_ns)
        if m is None:
            self.stats.reject("no input")
            return None
        self.stats.events_out += 1
        return Measurement(m.t_ns, m.pose.inverse(), m.origin_ns)


class Inference(Component):
    """Chain ``T_0 @ T_1 @ ... @ T_n`` of its pull inputs, all requested at one time.

    ``pull(t)`` asks every input for ``t``; a push on the trigger input (any event at time
    ``t``) evaluates the chain at ``t`` and pushes the result. The covariance is propagated to
    first order with the compose Jacobians (inputs treated as independent). The result is
    stamped with the latest input time (all equal when the inputs are time-aligned filters).
    """

    push_in = 1
    pull_in = -1
    push_out = True
    pull_out = True
    kind = "inference"

    def _evaluate(self, t_ns: int) -> Measurement | None:
        out: UncertainPose | None = None
        t_out, origin = None, NO_ORIGIN
        for src in self.inputs:
            m = src.pull(t_ns)
            if m is None:
                self.stats.reject("missing input")
                return None
            out = m.pose if out is None else out.compose(m.pose)
            t_out = m.t_ns if t_out is None else max(t_out, m.t_ns)
            origin = max(origin, m.origin_ns)
        return Measurement(t_out, out, origin)

    def pull(self, t_ns: int) -> Measurement | None:
        m = self._evaluate(t_ns)
        if m is not None:
            self.stats.events_out += 1
        return m

    def push(self, m: Measurement, port: int = 0) -> None:
        self.stats.events_in += 1
        out = self._evaluate(m.t_ns)
        if out is not None:
            self.emit(out)


class KalmanFilter(Component):
    """A pose Kalman filter turning pushed measurements into a pull output valid at any time.

    Depending on where the planner puts it, it acts as a buffer, predictor (future times),
    interpolator (past times, within ``history_s``), fusion filter (several push inputs) or
    static estimator (a static motion model: a recursive least-squares average).

    Measurement timestamps are corrected by the edge's known ``stamp_offset_ns`` (``true =
    stamp - offset``). Rejected updates (filter gating, out-of-order, invalid) are counted;
    requests more than ``max_extrapolation_ns`` past the last accepted measurement ("stale"),
    before the first accepted one ("before first measurement") or before the history ("before
    history") return ``None`` and are counted, so a sensor that stops produces counted
    rejections instead of a drifting answer. Accepted, time-corrected measurements are
    pushed on (a trigger for push-mode inference).

    Parameters
    ----------
    motion : MotionSpec
    role : str
        Label used by plans ("predictor", "interpolator", "fusion", "static estimator").
    prior : UncertainPose, optional
        A measurement applied before the first pushed one (at that one's time), for example
        a static path's value entering a static estimator.
    filter_factory : callable, optional
        ``filter_factory(motion, history_s)`` building an object with ``update_pose(t_s,
        UncertainPose) -> bool`` and ``predict(t_s) -> UncertainPose``; default
        :func:`trackflow.filters.make_filter`.
    """

    push_in = -1
    push_out = True
    pull_out = True
    kind = "kalman"
    #: whether a :class:`~trackflow.dataflow.KalmanBank` may run this class's pushes and
    #: pulls in a batch: true for every class keeping :class:`KalmanFilter`'s ``push``,
    #: ``pull`` and ``refusal`` (worked out per subclass)
    bankable: bool = True

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        cls.bankable = all(
            getattr(cls, name) is getattr(KalmanFilter, name)
            for name in ("push", "pull", "refusal")
        )

    def __init__(
        self,
        name: str,
        motion: MotionSpec,
        *,
        role: str = "predictor",
        history_s: float = 1.0,
        stamp_offset_ns: int = 0,
        max_extrapolation_ns: int | None = 500_000_000,
        filter_factory: Callable | None = None,
        prior: UncertainPose | None = None,
    ):
        super().__init__(name)
        self.prior = prior
        self.motion = motion
        self.role = role
        self.history_s = float(history_s)
        self.stamp_offset_ns = int(stamp_offset_ns)
        self.max_extrapolation_ns = None if motion.static else max_extrapolation_ns
        self.filter_factory = filter_factory or make_filter
        #: called with every measured pose delivered (``measured.listeners``); the filter
        #: owns the list, so listeners stay across a reset (they watch the sensor, not a run)
        self.measurement_listeners: list = []
        self.reset()

    def reset(self) -> None:
        super().reset()
        self.filter = self.filter_factory(self.motion, self.history_s)
        self._history_ns = int(self.history_s * 1e9)
        self.first_t: int | None = None
        self.last_t: int | None = None
        self.last_origin = NO_ORIGIN
        #: the sensor's rate, latency and noise as measured (dataflow/_attributes.py)
        self.measured = MeasuredAttributes(self.measurement_listeners)
        #: measurements the filter refused since the last one it took (liveness)
        self.refused_in_a_row = 0

    def same_filter(self, other: KalmanFilter) -> bool:
        """Whether ``other`` would compute exactly what this filter computes (motion model,
        stamp offset, history, extrapolation limit, filter factory and prior)."""
        return (
            self.motion == other.motion
            and self.stamp_offset_ns == other.stamp_offset_ns
            and self.history_s == other.history_s
            and self.max_extrapolation_ns == other.max_extrapolation_ns
            and self.filter_factory is other.filter_factory
            and self.prior is None
            and other.prior is None
        )

    @property
    def batchable(self) -> bool:
        """Whether the component only keeps its filter's state, so that a
        :class:`~trackflow.dataflow.KalmanBank` may batch its updates: a :attr:`bankable`
        class, no push consumers and no prior (:meth:`bank_time`)."""
        return self.bank_time(0) is not None

    # -- the bookkeeping of one measurement or answer (push, pull and KalmanBank) --------------
    def measurement_time(self, t_ns: int) -> int:
        """The filter's time [ns] of a measurement stamped ``t_ns``: ``stamp - offset``."""
        return t_ns - self.stamp_offset_ns

    def bank_time(self, t_ns: int) -> int | None:
        """:meth:`measurement_time` of a stamp ``t_ns`` when the component only keeps its
        filter's state (a :attr:`bankable` class, no push consumers, no prior: it is
        :attr:`batchable`), else ``None``: the check and the time in one call, for a bank's
        per-packet path."""
        if self.bankable and not self.consumers and self.prior is None:
            return t_ns - self.stamp_offset_ns  # measurement_time, without a second call
        return None

    def delivered(self, t: int, ok: bool, position=None, quaternion=None) -> None:
        """Note a measurement delivered at (corrected) time ``t`` [ns], taken by the filter
        (``ok``, with the NIS of its update) or refused, with its pose (``position`` (3,)
        [m], ``quaternion`` (4,); ``None``: not a measured pose) in the measured attributes:
        what the sensor delivers, whether the filter takes it or not."""
        nis = getattr(self.filter, "nis", math.nan) if ok else math.nan
        self.measured.update(t, self.clock.now_ns, nis, position, quaternion)

    def accepted(self, t: int, origin_ns: int) -> None:
        """Note a measurement the filter took at (corrected) time ``t`` [ns] of origin
        ``origin_ns``: the first and last measurement times and the newest origin."""
        if self.first_t is None or t < self.first_t:
            self.first_t = t
        if self.last_t is None or t > self.last_t:
            self.last_t = t
        if origin_ns > self.last_origin:
            self.last_origin = origin_ns

    def count_update(self, ok: bool) -> None:
        """Count one pushed measurement in, and out if the filter took it (it is pushed on,
        to the push consumers if any), else as a rejection."""
        stats = self.stats
        stats.events_in += 1
        if ok:
            stats.events_out += 1
            self.refused_in_a_row = 0
        else:
            stats.reject("filter rejected update")
            self.refused_in_a_row += 1

    def count_answer(self, ok: bool) -> None:
        """Count one answer to a pull that was not refused (:meth:`refusal`), or the
        failure of its prediction."""
        if ok:
            self.stats.events_out += 1
        else:
            self.stats.reject("prediction failed")

    def push(self, m: Measurement, port: int = 0) -> None:
        t = self.measurement_time(m.t_ns)
        if self.prior is not None and self.first_t is None and self.stats.events_in == 0:
            if not self.filter.update_pose(t * 1e-9, self.prior):
                self.stats.reject("filter rejected prior")
        try:
            ok = self.filter.update_pose(t * 1e-9, m.pose)
        except ValueError:
            ok = False
        self.count_update(ok)
        self.delivered(t, ok, m.pose.position, m.pose.quaternion)
        if not ok:
            return
        self.accepted(t, m.origin_ns)
        out = m if t == m.t_ns else Measurement(t, m.pose, m.origin_ns)
        for consumer, port_in in self.consumers:  # pushed on (counted above)
            consumer.push(out, port_in)

    def refusal(self, t_ns: int) -> str | None:
        """Why a pull at ``t_ns`` gets no answer (the rejection's reason), or ``None``."""
        last = self.last_t
        if last is None:
            return "no data yet"
        limit = self.max_extrapolation_ns
        if limit is not None and t_ns - last > limit:
            return "stale"
        if not self.motion.static:
            if t_ns < self.first_t:  # an interpolator asked before the first sample (start-up)
                return "before first measurement"
            if last - t_ns > self._history_ns:
                return "before history"
        return None

    def pull(self, t_ns: int) -> Measurement | None:
        why = self.refusal(t_ns)
        if why is not None:
            self.stats.reject(why)
            return None
        try:
            pose = self.filter.predict(t_ns * 1e-9)
        except ValueError:
            pose = None
        self.count_answer(pose is not None)
        if pose is None:
            return None
        return Measurement(int(t_ns), pose, self.last_origin)

    def describe(self) -> str:
        m = self.motion
        model = "static" if m.static else f"n_dp={m.n_dp}, n_do={m.n_do}"
        extra = f", stamp offset {self.stamp_offset_ns * 1e-6:g} ms" if self.stamp_offset_ns else ""
        return f"kalman {self.name} ({self.role}; {model}{extra})"


class LatestValue(Component):
    """Naive buffer: ``pull(t)`` returns the newest pushed measurement unchanged, whatever
    ``t`` (no time alignment; the event-based behaviour of section 9.2.2)."""

    push_in = 1
    pull_out = True
    kind = "latest"

    def reset(self) -> None:
        super().reset()
        self.last: Measurement | None = None

    def __init__(self, name: str):
        super().__init__(name)
        self.reset()

    def push(self, m: Measurement, port: int = 0) -> None:
        self.stats.events_in += 1
        self.last = m

    def pull(self, t_ns: int) -> Measurement | None:
        if self.last is None:
            self.stats.reject("no data yet")
            return None
        self.stats.events_out += 1
        return self.last


class Sampler(Component):
    """Pushes ``input.pull(tick + offset)`` at a fixed rate (thesis 7.3.4).

    Ticks fall at ``start_ns + k * period`` on the network clock; ``offset_ns`` > 0 predicts,
    < 0 interpolates in the past. Unanswered requests are counted ("no result").
    """

    pull_in = 1
    push_out = True
    kind = "sampler"

    def __init__(self, name: str, rate_hz: float, offset_ns: int = 0, start_ns: int = 0):
        super().__init__(name)
        if not 0 < rate_hz < 1e9:
            raise InputError(f"sampler {name!r}: rate_hz must be > 0")
        self.period_ns = int(round(1e9 / rate_hz))
        self.offset_ns = int(offset_ns)
        self.start_ns = int(start_ns)

    def tick(self, t_ns: int) -> None:
        self.stats.events_in += 1
        m = self.inputs[0].pull(t_ns + self.offset_ns)
        if m is None:
            self.stats.reject("no result")
            return
        self.emit(m)

    def describe(self) -> str:
        return (
            f"sampler {self.name} ({1e9 / self.period_ns:g} Hz, "
            f"offset {self.offset_ns * 1e-6:+g} ms)"
        )
