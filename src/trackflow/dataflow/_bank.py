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
from collections.abc import Callable, Sequence

import numpy as np

from ..filters import Layouts, PoseFilterBank, PredictedPoses
from ..math import UncertainPose
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
        Addressed by their index in :meth:`push` and :meth:`pull`. A component that is not
        :attr:`~KalmanFilter.batchable` (it pushes its accepted measurements on to push
        consumers, has a prior, or its class has a push or pull of its own, such as
        :class:`InertialKalmanFilter`) is pushed and pulled through its own methods, in
        order, so that its consumers see every other filter as they would have. The
        bookkeeping of the batched ones is the components' own
        (:meth:`KalmanFilter.measurement_time`, :meth:`~KalmanFilter.accepted`,
        :meth:`~KalmanFilter.count_update`, :meth:`~KalmanFilter.count_answer`).
    """

    def __init__(self, components: Sequence[KalmanFilter]):
        self.components = list(components)
        self._bank: PoseFilterBank | None = None
        self._lanes = Layouts(self._make_lane)  # per index list of push_block

    def _filters(self) -> PoseFilterBank:
        """The filter bank over the components' current filters (rebuilt after a reset)."""
        bank = self._bank
        filters = [c.filter for c in self.components]
        if bank is None or not _same(bank.filters, filters):
            if bank is not None:
                bank.settle()
            bank = self._bank = PoseFilterBank(filters)
        return bank

    @staticmethod
    def _plain(c: KalmanFilter) -> bool:
        """Whether a component only keeps its state (its updates can be batched)."""
        return c.batchable

    def push(self, items: Sequence[tuple[int, Measurement]]) -> None:
        """``components[i].push(m)`` for every ``(i, m)``, in order, with the updates of the
        components that only keep their state (no push consumers) batched."""
        comps = self.components
        run: list[tuple[int, Measurement]] = []
        for i, m in items:
            c = comps[i]
            if not self._plain(c):
                if run:
                    self._push_run(run)
                    run = []
                c.push(m)
                continue
            run.append((i, m))
        if run:
            self._push_run(run)

    def _push_run(self, run: list[tuple[int, Measurement]]) -> None:
        """The batched updates of ``run``, counted and accounted for as
        :meth:`KalmanFilter.push` does."""
        index = [i for i, _ in run]
        times, ns = self._times(index, [m.t_ns for _, m in run])
        poses = [m.pose for _, m in run]
        accepted = self._filters().update_poses(index, times, poses)
        position = [p.position for p in poses]
        quaternion = [p.quaternion for p in poses]
        self._account(index, ns, [m.origin_ns for _, m in run], accepted, position, quaternion)

    def push_block(
        self,
        index: Sequence[int],
        t_ns: int,
        position,
        quaternion,
        covariance,
        answer: tuple[int, Callable[[PredictedPoses], object]] | None = None,
    ) -> None:
        """``components[index[k]].push(m_k)`` for every ``k``, for trusted measurements of
        one time given as arrays: ``m_k`` is ``Measurement(t_ns, pose_k, t_ns)`` with
        ``pose_k`` made of ``position[k]`` (m, 3), ``quaternion[k]`` (m, 4) and
        ``covariance[k]`` (m, 6, 6) as :meth:`UncertainPose._trusted` takes them
        (:meth:`PoseFilterBank.update_block`: no object per measurement).

        ``answer = (at_ns, deliver)`` answers the packet as soon as the filters are updated:
        ``deliver`` gets :meth:`pull_block` of the same components at ``at_ns`` [ns], before
        the bookkeeping (the filters', :meth:`PoseFilterBank.settle`, and the components'
        counts, right after ``deliver`` returns). ``deliver`` must not call into the
        components. A list of components pushed again and again (a tracker's packet) is
        looked up once (:class:`Layouts`) and checked per call for what may have changed."""
        cs = self._lanes(tuple(index))
        lane = None if cs is None else self._lane_times(cs, index, t_ns)
        if lane is None:  # not a lane, or a component changed since: the general checks
            comps = self.components
            cs = [comps[i] for i in index]
            if not all(map(self._plain, cs)):
                self._push_objects(index, t_ns, position, quaternion, covariance, answer)
                return
            times, ns = self._times(index, [t_ns] * len(index))
            self._filters()
        else:
            times, ns = lane
        bank = self._bank
        if answer is None:
            accepted = bank.update_block(index, times, position, quaternion, covariance)
            self._account(index, ns, [t_ns] * len(index), accepted, position, quaternion)
            return
        at_ns, deliver = answer
        accepted, ahead = bank.update_block(
            index, times, position, quaternion, covariance, defer=True, predict_at=at_ns * 1e-9
        )
        answered = None
        try:  # answers first; the counts, the answers' and the filters' bookkeeping after
            if self._timed(cs, ns, t_ns, accepted, at_ns, position, quaternion):
                answered = ahead.ok
                deliver(ahead)
            else:  # a refusal: counted as pull_block counts it
                self._counted(cs, accepted)
                accepted = None
                deliver(self._pulled(index, [at_ns] * len(index), None))
        finally:
            if accepted is not None:
                self._counted(cs, accepted)
            if answered is not None:
                self._answers_counted(cs, answered)
            bank.settle()

    def _make_lane(self, key: tuple) -> list | None:
        """The components of an index list pushed again and again (a tracker's packet),
        looked up once (:class:`Layouts`); ``None`` unless each is of a
        :attr:`~KalmanFilter.bankable` class and comes once."""
        cs = [self.components[i] for i in key]
        once = len(set(key)) == len(key)
        return cs if once and all(c.bankable for c in cs) else None

    def _lane_times(self, cs: list, index: Sequence[int], t_ns: int) -> tuple | None:
        """The filter times of a block stamped ``t_ns`` for the components ``cs`` (at
        ``index``), in seconds and in nanoseconds (:meth:`KalmanFilter.bank_time`), when
        each only keeps its state and the bank holds its current filter, else ``None`` (the
        general path)."""
        bank = self._bank
        if bank is None:
            return None
        filters = bank.filters
        times, ns = [], []
        for c, i in zip(cs, index):
            t = c.bank_time(t_ns)
            if t is None or c.filter is not filters[i]:
                return None
            ns.append(t)
            times.append(t * 1e-9)
        return times, ns

    def _timed(self, cs, ns, t_ns, accepted, at_ns, position, quaternion) -> bool:
        """The components' first/last times and origin after their updates at ``ns`` (the
        stamp ``t_ns`` corrected; :meth:`_account`'s) of the poses ``position[k]``,
        ``quaternion[k]``, then whether each answers at ``at_ns`` (no refusal)."""
        for k, (c, t, ok) in enumerate(zip(cs, ns, accepted)):
            c.delivered(t, ok, position[k], quaternion[k])
            if ok:
                c.accepted(t, t_ns)
        return all(c.refusal(at_ns) is None for c in cs)

    @staticmethod
    def _counted(cs: list, accepted: list) -> None:
        """The components' counts after their updates (:meth:`_account`'s)."""
        for c, ok in zip(cs, accepted):
            c.count_update(ok)

    @staticmethod
    def _answers_counted(cs: list, ok: list) -> None:
        """The components' counts after answering (``ok[k]``) or failing to predict."""
        for c, good in zip(cs, ok):
            c.count_answer(good)

    def _push_objects(self, index, t_ns, position, quaternion, covariance, answer) -> None:
        """:meth:`push_block` of components not all plain: their measurements as objects,
        in order (:meth:`push`), then the answers."""
        trusted = UncertainPose._trusted
        self.push(
            [
                (i, Measurement(t_ns, trusted(position[k], quaternion[k], covariance[k]), t_ns))
                for k, i in enumerate(index)
            ]
        )
        if answer is not None:
            self.answer(index, answer)

    def answer(self, index: Sequence[int], answer: tuple[int, Callable]) -> None:
        """``deliver(pull_block(index, [at_ns] * len(index)))`` for ``answer = (at_ns,
        deliver)``: the answers of the components ``index`` at one time."""
        at_ns, deliver = answer
        deliver(self.pull_block(index, [at_ns] * len(index)))

    def _times(self, index: Sequence[int], t_ns: Sequence[int]) -> tuple[list, list]:
        """The filter times of measurements stamped ``t_ns`` for components ``index``, in
        seconds and in nanoseconds (:meth:`KalmanFilter.measurement_time`)."""
        comps = self.components
        ns = [comps[i].measurement_time(t) for i, t in zip(index, t_ns)]
        return [t * 1e-9 for t in ns], ns

    def _account(self, index, ns, origins, accepted, position, quaternion) -> None:
        """Each component's bookkeeping after its batched update (measurements in and out,
        rejections, first/last times and origin, measured attributes), as
        :meth:`KalmanFilter.push` keeps it, for updates at filter times ``ns`` [ns] of
        origins ``origins`` with the poses ``position[k]``, ``quaternion[k]``."""
        comps = self.components
        for k, (i, t, origin, ok) in enumerate(zip(index, ns, origins, accepted)):
            comps[i].delivered(t, ok, position[k], quaternion[k])
            if ok:
                comps[i].accepted(t, origin)
        self._counted([comps[i] for i in index], accepted)

    def pull(self, items: Sequence[tuple[int, int]]) -> list[Measurement | None]:
        """``components[i].pull(t_ns)`` for every ``(i, t_ns)``: the answers (or ``None``,
        a counted rejection) in order, the predictions of one call batched."""
        out: list[Measurement | None] = [None] * len(items)
        index, times, where = [], [], []
        for k, (i, t_ns) in enumerate(items):
            c = self.components[i]
            if not c.bankable:
                out[k] = c.pull(t_ns)
            else:
                index.append(i)
                times.append(t_ns)
                where.append(k)
        if index:
            res = self.pull_block(index, times)
            trusted = UncertainPose._trusted
            for k, i, t_ns, ok, p, q, cov in zip(
                where, index, times, res.ok, res.position, res.quaternion, res.covariance
            ):
                if ok:
                    origin = self.components[i].last_origin
                    out[k] = Measurement(int(t_ns), trusted(p, q, cov), origin)
        return out

    def pull_block(self, index: Sequence[int], t_ns: Sequence[int]) -> PredictedPoses:
        """The poses of ``components[index[k]].pull(t_ns[k])`` for every ``k`` as arrays
        (``ok[k]`` is ``False`` for a counted rejection), the predictions batched; every
        component is of a :attr:`~KalmanFilter.bankable` class."""
        return self._pulled(index, t_ns, None)

    def _pulled(self, index, t_ns, ahead: PredictedPoses | None) -> PredictedPoses:
        """:meth:`pull_block`; ``ahead``, if given, holds the filters' predictions for
        every request (made with their update), used when none is rejected."""
        comps = self.components
        index_ok, times, where = [], [], []
        for k, (i, t) in enumerate(zip(index, t_ns)):
            c = comps[i]
            if not c.bankable:
                raise TypeError(f"{c.name}: pull_block takes bankable KalmanFilter components")
            why = c.refusal(t)
            if why is None:
                index_ok.append(i)
                times.append(t * 1e-9)
                where.append(k)
            else:
                c.stats.reject(why)
        if ahead is not None and len(where) == len(index):
            res = ahead
        else:
            res = self._filters().predict_block(index_ok, times)
        self._answers_counted([comps[i] for i in index_ok], res.ok)
        if len(where) == len(index):
            return res
        m = len(index)
        full = PredictedPoses(
            np.full((m, 3), np.nan), np.full((m, 4), np.nan), np.full((m, 6, 6), np.nan),
            [False] * m,
        )  # fmt: skip
        for j, k in enumerate(where):
            full.position[k], full.quaternion[k] = res.position[j], res.quaternion[j]
            full.covariance[k], full.ok[k] = res.covariance[j], res.ok[j]
        return full
