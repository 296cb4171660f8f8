"""Kalman filter components pushed and pulled together: one batched event per packet.

A live tracker's packet carries the poses of many bodies, each feeding its own
:class:`KalmanFilter`. :class:`KalmanBank` takes all of a packet's measurements (or all the
requests for answers at some times) in one call and runs the filters' arithmetic through one
:class:`trackflow.filters.PoseFilterBank` call, while every component keeps its own
statistics, rejections, first/last times and origin exactly as its :meth:`KalmanFilter.push`
and :meth:`KalmanFilter.pull` would have kept them.
"""

from __future__ import annotations

import operator
from collections.abc import Sequence

from ..filters import PoseFilterBank
from ._events import Measurement
from ._processing import KalmanFilter

__all__ = ["KalmanBank"]


def _same(a: list, b: list) -> bool:
    """Whether two lists hold the same objects in the same order."""
    return len(a) == len(b) and all(map(operator.is_, a, b))


class KalmanBank:
    """Several :class:`KalmanFilter` components driven together (module docstring).

    Parameters
    ----------
    components : sequence of KalmanFilter
        Addressed by their index in :meth:`push` and :meth:`pull`. A component that pushes
        its accepted measurements on (it has push consumers), has a prior, or is a subclass
        (such as :class:`InertialKalmanFilter`) is pushed through its own :meth:`push`, in
        order, so that its consumers see every other filter as they would have.
    """

    def __init__(self, components: Sequence[KalmanFilter]):
        self.components = list(components)
        self._bank: PoseFilterBank | None = None

    def _filters(self) -> PoseFilterBank:
        """The filter bank over the components' current filters (rebuilt after a reset)."""
        bank = self._bank
        filters = [c.filter for c in self.components]
        if bank is None or not _same(bank.filters, filters):
            bank = self._bank = PoseFilterBank(filters)
        return bank

    def push(self, items: Sequence[tuple[int, Measurement]]) -> None:
        """``components[i].push(m)`` for every ``(i, m)``, in order, with the updates of the
        components that only keep their state (no push consumers) batched."""
        comps = self.components
        run: list[tuple[int, Measurement]] = []
        index: list[int] = []
        times: list[float] = []
        poses: list = []
        for i, m in items:
            c = comps[i]
            if c.consumers or c.prior is not None or type(c) is not KalmanFilter:
                if run:
                    self._push_run(run, index, times, poses)
                    run, index, times, poses = [], [], [], []
                c.push(m)
                continue
            c.stats.events_in += 1
            run.append((i, m))
            index.append(i)
            times.append((m.t_ns - c.stamp_offset_ns) * 1e-9)
            poses.append(m.pose)
        if run:
            self._push_run(run, index, times, poses)

    def _push_run(self, run, index, times, poses) -> None:
        """The batched updates of ``run`` (counted in already), then each component's
        bookkeeping as :meth:`KalmanFilter.push` does it."""
        comps = self.components
        accepted = self._filters().update_poses(index, times, poses)
        for (i, m), ok in zip(run, accepted):
            c = comps[i]
            if not ok:
                c.stats.reject("filter rejected update")
                continue
            t = m.t_ns - c.stamp_offset_ns
            if c.first_t is None or t < c.first_t:
                c.first_t = t
            if c.last_t is None or t > c.last_t:
                c.last_t = t
            if m.origin_ns > c.last_origin:
                c.last_origin = m.origin_ns
            c.stats.events_out += 1  # emitted, to no consumer

    def pull(self, items: Sequence[tuple[int, int]]) -> list[Measurement | None]:
        """``components[i].pull(t_ns)`` for every ``(i, t_ns)``: the answers (or ``None``,
        a counted rejection) in order, the predictions of one call batched."""
        out: list[Measurement | None] = [None] * len(items)
        index, times, where = [], [], []
        for k, (i, t_ns) in enumerate(items):
            c = self.components[i]
            if type(c) is not KalmanFilter:
                out[k] = c.pull(t_ns)
                continue
            if c.last_t is None:
                c.stats.reject("no data yet")
            elif c.max_extrapolation_ns is not None and t_ns - c.last_t > c.max_extrapolation_ns:
                c.stats.reject("stale")
            elif not c.motion.static and t_ns < c.first_t:
                c.stats.reject("before first measurement")
            elif not c.motion.static and c.last_t - t_ns > c._history_ns:
                c.stats.reject("before history")
            else:
                index.append(i)
                times.append(t_ns * 1e-9)
                where.append(k)
        if index:
            poses = self._filters().predict_poses(index, times)
            for k, i, pose in zip(where, index, poses):
                c = self.components[i]
                if pose is None:
                    c.stats.reject("prediction failed")
                    continue
                c.stats.events_out += 1
                out[k] = Measurement(int(items[k][1]), pose, c.last_origin)
        return out
