"""Failover between a query's candidate paths (thesis 2.4.4: the setup adapts to the trackers
that are present).

The planner gives a query its best path and, where the graph has them, fallback paths that
share no sensor with the better ones (:func:`trackflow.dataflow.plan_query`). A
:class:`PathSwitch` pulls the query's answer from one of them:

* A path is **live** while every sensor filter on it took a measurement of an exposure
  within its sensor's ``stale`` time (the newest measurement's time against the network's
  clock at the pull: a backlog of old measurements that arrives late does not make a sensor
  live) and refused fewer than ``refused_down`` measurements in a row since it last took
  one. Nothing is judged
  until some sensor of the switch has delivered (the start); a sensor that has not
  delivered yet counts as live for its ``stale`` time after the start (the trackers of a
  starting setup come up at slightly different times), then as down.
* The switch answers from the path it is on while that path is live. When it is not, it
  moves at once to the best live path (lowest index); when none is live it stays.
* It returns to a better path once that path has been live for ``hold`` without a break, so
  a sensor that flickers does not make the answers flap.
* With the query's ``require`` (:class:`~trackflow.graph.Requirements`), every answer is
  checked: one that does not meet it is flagged (:attr:`Measurement.broken`, counted in
  :attr:`PathSwitch.broken`), and a path whose answers break it ``refused_down`` times in a
  row is left for a live path, if there is one, and not taken again for ``hold``.
* With the candidate ``paths`` and the query's evaluation function, the switch re-scores
  the paths once a second (:data:`RESCORE_NS` of the network clock) with each sensor's
  measured rate, latency and noise in place of the declared ones
  (:meth:`~trackflow.dataflow.MeasuredAttributes.edge`; thesis 6.4: the planner learns
  what the trackers actually do) once every sensor has taken :data:`WARM_MEASUREMENTS`.
  A path that scores more than :data:`MARGIN` better than the one preferred so far becomes
  the preferred one; the answers move to it like to any better path (once it has been live
  for ``hold``), with the two scores in the event's reason.
* Every move is a :class:`SwitchEvent` with its time and reason (the newest
  :data:`KEPT_EVENTS` in :attr:`PathSwitch.events`, every one given to ``on_switch``); every
  answer carries the index of the path that produced it (:attr:`Measurement.path`).

Liveness is judged from the dispatch times the scheduler gives the network, so a replay of
recorded arrivals switches exactly where the live run did.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from ..graph import Path, PathStep, Requirements
from ._component import Component
from ._events import Measurement
from ._sources import NO_ORIGIN

__all__ = ["KEPT_EVENTS", "MARGIN", "RESCORE_NS", "WARM_MEASUREMENTS", "PathSwitch",
           "SwitchEvent"]  # fmt: skip

#: the switches a :class:`PathSwitch` keeps (the newest; ``on_switch`` sees every one)
KEPT_EVENTS = 1000
#: how often the paths are re-scored with the measured attributes [ns of the network clock]
RESCORE_NS = 1_000_000_000
#: measurements each sensor takes before its measured figures replace the declared ones
WARM_MEASUREMENTS = 256
#: a path must score this fraction better than the preferred one to take its place
MARGIN = 0.1


@dataclass(frozen=True)
class SwitchEvent:
    """A move of a query's answers from one path to another.

    Parameters
    ----------
    t_ns : int
        The network clock when it happened (the dispatch time of the pull that moved).
    from_path, to_path : int
        Path indices (0 = the preferred path).
    reason : str
        Why: the sensor that went down and how ("sensor natnet: no data for 212 ms"), or
        that the better path is back ("path 0 live for 2.00 s").
    """

    t_ns: int
    from_path: int
    to_path: int
    reason: str

    def as_dict(self) -> dict:
        return {"t_ns": self.t_ns, "from": self.from_path, "to": self.to_path,
                "reason": self.reason}  # fmt: skip


class PathSwitch(Component):
    """Answers a pull from the query's current live path (module docstring).

    Parameters
    ----------
    name : str
    sensors : sequence of sequence of (str, Component, int)
        Per candidate path (input ``k`` is path ``k``): its sensors as ``(sensor name, filter
        component, stale time [ns])``. The filter components are
        :class:`~trackflow.dataflow.KalmanFilter` objects (``last_t``, the newest
        measurement's time, and ``refused_in_a_row`` tell their liveness).
    hold_ns : int
        How long a better path must have been live before the answers return to it.
    refused_down : int
        A sensor whose filter refused this many measurements in a row is down.
    on_switch : callable, optional
        Called with every :class:`SwitchEvent` as it happens.
    require : Requirements, optional
        What the answers need (module docstring).
    paths : sequence of Path, optional
        The candidate paths (:class:`~trackflow.graph.Path`, input ``k`` is path ``k``),
        with ``evaluate`` (the query's evaluation function, lower is better): re-score them
        with the measured attributes (module docstring). Without them the order is the
        planner's.
    """

    pull_in = -1
    pull_out = True
    kind = "switch"

    def __init__(
        self,
        name: str,
        sensors: Sequence[Sequence[tuple[str, Component, int]]],
        *,
        hold_ns: int = 2_000_000_000,
        refused_down: int = 5,
        on_switch: Callable[[SwitchEvent], None] | None = None,
        require: Requirements | None = None,
        paths: Sequence[Path] | None = None,
        evaluate: Callable[[Path], float] | None = None,
    ):
        super().__init__(name)
        self.sensors = [list(s) for s in sensors]
        if (paths is None) != (evaluate is None) or (paths and len(paths) != len(sensors)):
            raise ValueError("paths and evaluate go together, one path per input")
        self.paths = None if paths is None else list(paths)
        self.evaluate = evaluate
        self.hold_ns = int(hold_ns)
        self.refused_down = int(refused_down)
        self.on_switch = on_switch
        self.require = require
        self.reset()

    def reset(self) -> None:
        super().reset()
        self.current = 0
        self.events: deque[SwitchEvent] = deque(maxlen=KEPT_EVENTS)
        self.switch_count = 0
        self._live_since: list[int | None] = [None] * len(self.sensors)
        self.answers_by_path = [0] * len(self.sensors)
        self._start_ns: int | None = None
        #: answers that broke a requirement, by the requirement's name
        self.broken: dict[str, int] = {}
        self._breaking = 0  # answers of the current path breaking one in a row
        self._barred: list[tuple[int, str]] = [(0, "")] * len(self.sensors)  # (until, why)
        #: the paths, most preferred first (the planner's order until re-scored)
        self.order = list(range(len(self.sensors)))
        #: the paths' scores with the measured attributes (the latest re-scoring; empty
        #: before the sensors are warm)
        self.measured_scores: list[float] = []
        self._rescored_ns: int | None = None
        self._why_better = ""  # why the preferred path changed, for the move to it

    def down(self, path: int, now_ns: int) -> str | None:
        """Why path ``path`` is not live at ``now_ns`` (its first sensor that is down, or the
        requirement it kept breaking within the hold time), or ``None``."""
        until, why = self._barred[path]
        if now_ns < until:
            return why
        for sensor, kf, stale_ns in self.sensors[path]:
            taken = kf.last_t
            if taken is None:
                if now_ns - self._start_ns > stale_ns:
                    waited = (now_ns - self._start_ns) * 1e-6
                    return f"sensor {sensor}: no data since the start ({waited:.0f} ms)"
                continue
            if now_ns - taken > stale_ns:
                return f"sensor {sensor}: no data for {(now_ns - taken) * 1e-6:.0f} ms"
            if kf.refused_in_a_row >= self.refused_down:
                return f"sensor {sensor}: {kf.refused_in_a_row} measurements refused in a row"
        return None

    def _started(self) -> bool:
        """Whether some sensor of the switch has delivered."""
        return any(kf.last_t is not None for path in self.sensors for _, kf, _ in path)

    def _move(self, now_ns: int, to: int, reason: str) -> None:
        event = SwitchEvent(now_ns, self.current, to, reason)
        self.current = to
        self.events.append(event)
        self.switch_count += 1
        if self.on_switch is not None:
            self.on_switch(event)

    def choose(self, now_ns: int) -> int:
        """The path to answer from at ``now_ns`` (moving, with an event, if it changes)."""
        why = [self.down(k, now_ns) for k in range(len(self.sensors))]
        since = self._live_since
        for k, w in enumerate(why):
            if w is not None:
                since[k] = None
            elif since[k] is None:
                since[k] = now_ns
        cur = self.current
        if why[cur] is not None:
            live = [k for k in self.order if why[k] is None]
            if live:
                self._move(now_ns, live[0], why[cur])
            return self.current
        for k in self.order[: self.order.index(cur)]:  # a better path, live for the hold
            if since[k] is not None and now_ns - since[k] >= self.hold_ns:
                live_for = f"path {k} live for {(now_ns - since[k]) * 1e-9:.2f} s"
                self._move(now_ns, k, self._why_better or live_for)
                break
        return self.current

    def rescore(self, now_ns: int) -> None:
        """Score the paths with their sensors' measured attributes, at most once per
        :data:`RESCORE_NS`, once all are warm; prefer a path that scores more than
        :data:`MARGIN` better than the preferred one."""
        if self.paths is None:
            return
        if self._rescored_ns is not None and now_ns - self._rescored_ns < RESCORE_NS:
            return
        self._rescored_ns = now_ns
        filters = {e: kf for path in self.sensors for e, kf, _ in path}
        if any(kf.measured.n < WARM_MEASUREMENTS for kf in filters.values()):
            return
        scores = [self.evaluate(_measured_path(p, filters)) for p in self.paths]
        self.measured_scores = scores
        best = min(range(len(scores)), key=lambda k: (scores[k], k))
        first = self.order[0]
        if best != first and scores[best] < (1.0 - MARGIN) * scores[first]:
            self.order = sorted(range(len(scores)), key=lambda k: (scores[k], k))
            self._why_better = (
                f"path {best} measured better: {scores[best]:.4g} vs {scores[first]:.4g} "
                f"({getattr(self.evaluate, '__name__', 'evaluation')})"
            )

    def pull(self, t_ns: int) -> Measurement | None:
        now = self.clock.now_ns
        if self._start_ns is None and self._started():
            self._start_ns = now
        if self._start_ns is not None:
            self.rescore(now)
            k = self.choose(now)
        else:
            k = self.current
        m = self.inputs[k].pull(t_ns)
        if m is None:
            self.stats.reject(f"path {k} did not answer")
            return None
        self.stats.events_out += 1
        self.answers_by_path[k] += 1
        broken = "" if self.require is None else self._check(m, now, k)
        if k == 0 and not broken:
            return m
        return Measurement(m.t_ns, m.pose, m.origin_ns, k, broken)

    def _check(self, m: Measurement, now_ns: int, k: int) -> str:
        """The requirement answer ``m`` of path ``k`` breaks (counted), and the move away
        from a path that keeps breaking one."""
        age = None if m.origin_ns == NO_ORIGIN else now_ns - m.origin_ns
        broken = self.require.answer_broken(m.pose.covariance, age) or ""
        if not broken:
            self._breaking = 0
            return ""
        key = broken.split(" ", 1)[0]
        self.broken[key] = self.broken.get(key, 0) + 1
        self._breaking += 1
        if self._breaking >= self.refused_down:
            why = f"path {k} kept breaking {broken}"
            live = [j for j in self.order if j != k and self.down(j, now_ns) is None]
            if live:
                self._barred[k] = (now_ns + self.hold_ns, why)
                self._live_since[k] = None
                self._breaking = 0
                self._move(now_ns, live[0], why)
        return broken

    def summary(self, last: int = 20) -> dict:
        """The current path, answers per path, the number of switches and the ``last``
        newest (plain data, for status)."""
        return {
            "path": self.current,
            "answers_by_path": list(self.answers_by_path),
            "switch_count": self.switch_count,
            "broken": dict(self.broken),
            "order": list(self.order),
            "measured_scores": [float(f"{x:.4g}") for x in self.measured_scores],
            "switches": [e.as_dict() for e in list(self.events)[-last:]],
        }

    def describe(self) -> str:
        return f"switch {self.name} ({len(self.sensors)} paths, hold {self.hold_ns * 1e-9:g} s)"


def _measured_path(path: Path, filters: dict) -> Path:
    """``path`` with each sensor edge's measured figures in place of the declared ones
    (``filters``: sensor name -> its filter component with ``measured``)."""
    steps = []
    for step in path.steps:
        kf = filters.get(step.edge.name)
        edge = step.edge if kf is None else kf.measured.edge(step.edge)
        steps.append(PathStep(edge, step.inverted))
    return Path(tuple(steps))
