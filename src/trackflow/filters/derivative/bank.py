"""A bank of pose Kalman filters: the filters fed by one packet updated in one compiled call.

A live tracker sends the poses of many bodies in one packet, and each body has its own
:class:`PoseKalmanFilter`. Updating them one by one costs more in Python (argument
unboxing, the log record, bookkeeping) than in arithmetic. :class:`PoseFilterBank` keeps the
states of filters of one kind (same motion model, formulation, noise, angular-velocity bound
and gate) as rows of one array and runs one kernel over all the measurements of a call
(:func:`kernels.step_bank`, :func:`kernels.predict_pose_bank`): the same operations, in the
same order, as the filters' own :meth:`PoseKalmanFilter.update_pose` and
:meth:`PoseKalmanFilter.predict`, so the results are equal to the last bit, and every
filter's history, statistics, gate decisions (status and NIS in its log) and resets are the
ones it would have recorded on its own.

Each filter stays usable on its own: its state arrays are views of the bank's rows while the
bank drives it; a filter that replaced them (a reset, an out-of-order re-filtering) is taken
back into its row on the next call. A measurement the bank does not run in its kernel goes
through the filter's own method, in the order given: the filter's first measurement, a
measurement older than the filter's newest one, one due for a reset after a gated run, a
second measurement of the same filter in one call, and every filter of another class or of a
model without both position and orientation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from trackflow.math import UncertainPose, frozen

from .. import gating
from . import kernels as _source
from .streaming import PoseKalmanFilter, kernels, step_records

__all__ = ["Layouts", "PoseFilterBank", "PredictedPoses"]


class _Kind:
    """The filters of one kind (equal :class:`KernelSettings`): their states as rows of
    ``xs`` (n, nx) and ``ps`` (n, nc, nc), the packed constants and the gate of a pose
    measurement."""

    def __init__(self, f: PoseKalmanFilter, n: int):
        self.settings = s = f.kernel_settings
        self.const = frozen(s.const)  # kernel inputs read-only: one specialisation
        self.gate = s.gate
        self.nx, self.nc = s.x0.shape[0], s.p0.shape[0]
        self.xs = np.zeros((n, self.nx))
        self.ps = np.zeros((n, self.nc, self.nc))
        self.xv = list(self.xs)  # row views: the filters' state arrays while banked
        self.pv = list(self.ps)

    def fits(self, f: PoseKalmanFilter) -> bool:
        return self.settings.same_kernel(f.kernel_settings)


class _Batch:
    """The kernel's inputs for the measurements of filters of one kind: per measurement its
    ``(index, filter, time)``, the filter's row, the time step and (:meth:`update_poses`)
    the measurement, or (:meth:`update_block`) its index in the block's arrays."""

    __slots__ = (
        "kind", "ks", "fs", "sel", "dts", "zp", "zo", "r", "at", "sel_array", "out", "ts",
        "ahead",
    )  # fmt: skip

    def __init__(self, kind: _Kind):
        self.kind = kind
        self.ks: Sequence[int] = []  # per step: its index in the call
        self.fs: list = []  # its filter
        self.ts: list = []  # its time [s]
        self.sel: list = []
        self.dts: list = []
        self.zp: list = []
        self.zo: list = []
        self.r: list = []
        self.at: list = []
        self.sel_array = None  # sel as the kernel took it
        self.out = None  # the kernel's status (m,) int, NIS (m,) and (m, 0) (no records)
        self.ahead = None  # PredictedPoses made with the steps (_step's ``at``)


class Layouts:
    """What a caller works out once per layout of a packet (the tuple of bodies, sensors or
    filter indices a tracker sends again and again): ``layouts(key)`` is ``make(key)``, made
    on the first call with that key and kept (``None`` too: a layout the caller's fast path
    does not take). At most ``limit`` layouts are kept; more (a stream of changing
    layouts) start the collection afresh."""

    __slots__ = ("_make", "_limit", "_made")

    def __init__(self, make, limit: int = 64):
        self._make, self._limit = make, limit
        self._made: dict = {}

    def __call__(self, key: tuple):
        made = self._made
        value = made.get(key, made)
        if value is made:
            if len(made) >= self._limit:
                made.clear()
            value = made[key] = self._make(key)
        return value

    def __contains__(self, key: tuple) -> bool:
        return key in self._made


class _Lane:
    """A list of filters updated together again and again (a tracker's packet): all
    banked, of one kind, each once. Their rows and state arrays are looked up once, so a
    call checks only what changes between calls (:meth:`PoseFilterBank._lane_batch`)."""

    __slots__ = ("kind", "filters", "xv", "pv", "sel", "ks", "out")

    def __init__(self, kind: _Kind, filters: list, rows: list):
        self.kind, self.filters = kind, filters
        self.xv = [kind.xv[r] for r in rows]
        self.pv = [kind.pv[r] for r in rows]
        self.sel = frozen(rows, np.int64)
        self.ks = range(len(rows))
        self.out = _kernel_out(len(rows))  # rewritten by every call (a call settles first)


class PredictedPoses(NamedTuple):
    """Poses predicted by a :class:`PoseFilterBank` (:meth:`~PoseFilterBank.predict_block`),
    one row per request: ``position`` (m, 3) [m], ``quaternion`` (m, 4) ``(x, y, z, w)``,
    ``covariance`` (m, 6, 6) over ``(dt, dtheta)``, and ``ok`` (m,) ``False`` where the
    filter has no answer (its row holds NaN)."""

    position: np.ndarray
    quaternion: np.ndarray
    covariance: np.ndarray
    ok: list


def _kernel_out(m: int) -> tuple:
    """The outputs of :func:`kernels.step_bank` for ``m`` steps: status, NIS and the
    records, of length 0 (:func:`_records` writes them)."""
    return np.empty(m, np.int64), np.empty(m), np.empty((m, 0))


def _records(b: _Batch, zp, zo, r) -> np.ndarray:
    """The log records (m, size) of the kernel steps of batch ``b`` with the measurements
    ``zp`` (m, 3), ``zo`` (m, 4), ``r`` (m, 6, 6) (:func:`step_records`), copied from the
    rows the kernel left: it writes none itself, so that the copies come after an answer."""
    kind = b.kind
    return step_records(kind.xs[b.sel_array], kind.ps[b.sel_array], zp, zo, r)


def _bankable(f) -> bool:
    """Whether the bank runs ``f``'s pose steps in its kernel
    (:attr:`PoseKalmanFilter.batchable`)."""
    return isinstance(f, PoseKalmanFilter) and f.batchable


class PoseFilterBank:
    """Pose Kalman filters updated and predicted together (module docstring).

    Parameters
    ----------
    filters : sequence of PoseFilter
        The filters, addressed by their index in the calls. Filters of
        :class:`PoseKalmanFilter` with a model of both position and orientation are grouped
        by kind (one kernel call per kind and call); any other filter is driven through its
        own methods.
    """

    def __init__(self, filters: Sequence):
        self.filters = list(filters)
        self._kinds: list[_Kind] = []
        self._slot: list[tuple[_Kind, int] | None] = []
        self._unlogged: list = []  # kernel steps whose bookkeeping waits (settle)
        self._lanes = Layouts(self._make_lane)  # per index list of update_block
        members: list[list[int]] = []
        for i, f in enumerate(self.filters):
            k = None
            if _bankable(f):
                k = next((j for j, kind in enumerate(self._kinds) if kind.fits(f)), None)
                if k is None:
                    self._kinds.append(_Kind(f, len(self.filters)))
                    members.append([])
                    k = len(self._kinds) - 1
                members[k].append(i)
            self._slot.append(None if k is None else (self._kinds[k], len(members[k]) - 1))
        for kind, rows in zip(self._kinds, members):  # only as many rows as members
            kind.xs = kind.xs[: len(rows)].copy()
            kind.ps = kind.ps[: len(rows)].copy()
            kind.xv, kind.pv = list(kind.xs), list(kind.ps)

    @property
    def kinds(self) -> int:
        """Number of filter kinds run by the bank's kernels (one kernel call each)."""
        return len(self._kinds)

    @staticmethod
    def _take(f: PoseKalmanFilter, kind: _Kind, row: int) -> None:
        """Make the filter's state arrays the bank's row (copying its state in if it
        replaced them since)."""
        x, p = kind.xv[row], kind.pv[row]
        if not f.holds_state(x, p):
            f.bind_state(x, p)

    # -- updates -----------------------------------------------------------------------------
    def _ready(self, f, slot, tk: float) -> float | None:
        """The time step when the kernel can take a measurement at ``tk`` of filter ``f`` (in
        bank slot ``slot``): a banked filter whose own update would be one plain kernel step
        (:meth:`PoseKalmanFilter.step_time`); its state arrays are made the bank's row.
        Otherwise ``None``: the filter's own method takes it."""
        if slot is None:
            return None
        dt = f.step_time(tk)
        if dt is not None:
            self._take(f, *slot)
        return dt

    @staticmethod
    def _batch(batch: dict, slot, k: int, f, tk: float, dt: float) -> _Batch:
        """Measurement ``k`` of filter ``f`` at ``tk`` (``dt`` after its state) added to
        its kind's batch."""
        kind, row = slot
        b = batch.get(id(kind))
        if b is None:
            b = batch[id(kind)] = _Batch(kind)
        b.ks.append(k)
        b.fs.append(f)
        b.ts.append(tk)
        b.sel.append(row)
        b.dts.append(dt)
        return b

    def update_poses(self, index: Sequence[int], t: Sequence[float], poses: Sequence) -> list:
        """Integrate pose measurement ``poses[k]`` at time ``t[k]`` [s] into filter
        ``index[k]``, for every ``k``, exactly as ``filters[index[k]].update_pose(t[k],
        poses[k])`` one after the other would.

        Returns
        -------
        list of bool
            Per measurement: ``True`` if integrated, ``False`` if rejected (gated, older than
            the history, or a measurement the filter's own method refuses with
            ``ValueError``, such as a non-finite time). The gate decision and NIS of each
            measurement are in the filter's log (:attr:`PoseKalmanFilter.nis`, ``stats``).
        """
        if self._unlogged:
            self.settle()
        out: list = [False] * len(index)
        seen: set[int] = set()
        later: list[int] = []  # rows of a filter met before in this call: after the kernels
        batch: dict[int, _Batch] = {}  # per kind: the kernel's inputs
        filters, slots = self.filters, self._slot
        for k, i in enumerate(index):
            if i in seen:
                later.append(k)
                continue
            seen.add(i)
            f = filters[i]
            slot = slots[i]
            tk = float(t[k])
            pose = poses[k]
            dt = None
            if isinstance(pose, UncertainPose) and pose.covariance.ndim == 2:  # not a batch
                dt = self._ready(f, slot, tk)
            if dt is None:
                out[k] = self._one(f, tk, pose)
                continue
            b = self._batch(batch, slot, k, f, tk, dt)
            p = pose.pose
            b.zp.append(p.position)
            b.zo.append(p.quaternion)
            b.r.append(pose.covariance)
        for b in batch.values():
            self._step(b, b.zp, b.zo, b.r, out)
        for k in later:
            out[k] = self._one(filters[index[k]], t[k], poses[k])
        return out

    def update_block(
        self,
        index: Sequence[int],
        t: Sequence[float],
        position,
        quaternion,
        covariance,
        defer: bool = False,
        predict_at: float | None = None,
    ):
        """:meth:`update_poses` of trusted pose measurements given as arrays: the pose of
        measurement ``k`` is ``position[k]`` (m, 3) [m], ``quaternion[k]`` (m, 4) unit
        ``(x, y, z, w)`` and ``covariance[k]`` (m, 6, 6), as :class:`UncertainPose` takes
        them without checks (finite, unit, valid). No object is made per measurement on the
        kernel's path: the arrays go to it as they are. With ``defer``, the filters'
        bookkeeping after the kernel (times, gate runs, log entries) waits for :meth:`settle`
        (an answer first, the bookkeeping after it): call nothing on the filters themselves
        until then. A list of filters updated together again (a tracker's packet) is looked
        up once (:meth:`_lane_batch`).

        Returns the list of :meth:`update_poses`; with ``predict_at`` [s], the pair of it and
        ``predict_block(index, [predict_at] * m)``, made right after the update (for a lane
        not answered in the past, in the kernel call of the update, from the rows it has
        just written)."""
        if self._unlogged:
            self.settle()
        b = self._lane_batch(index, t)
        if b is not None:  # every filter in the kernel, in order: the arrays as they are
            out: list = [False] * len(index)
            at = None  # answers from the rows just stepped, in the same kernel call
            if predict_at is not None and math.isfinite(predict_at) and predict_at >= max(b.ts):
                at = predict_at
            plain = self._step(b, position, quaternion, covariance, out, defer, at)
            if predict_at is None:
                return out
            if plain and at is not None:
                return out, b.ahead
            return out, self._ahead(index, predict_at)  # a past time: the filters' own
        filters, slots = self.filters, self._slot
        if len(set(index)) != len(index):  # a filter twice: in order, through update_poses
            out = self._update_trusted(index, t, position, quaternion, covariance)
            return out if predict_at is None else (out, self._ahead(index, predict_at))
        out = [False] * len(index)
        batch: dict[int, _Batch] = {}
        for k, i in enumerate(index):
            f = filters[i]
            tk = float(t[k])
            dt = self._ready(f, slots[i], tk)
            if dt is not None:
                self._batch(batch, slots[i], k, f, tk, dt).at.append(k)
            else:
                trusted = UncertainPose._trusted(position[k], quaternion[k], covariance[k])
                out[k] = self._one(f, tk, trusted)
        for b in batch.values():
            at = np.asarray(b.at)
            self._step(b, position[at], quaternion[at], covariance[at], out, defer)
        return out if predict_at is None else (out, self._ahead(index, predict_at))

    def _lane_batch(self, index: Sequence[int], t: Sequence[float]) -> _Batch | None:
        """The kernel's batch for :meth:`update_block` when the filters ``index`` form a lane
        (:class:`_Lane`) and each is ready at its time ``t[k]`` [s] as :meth:`_ready` has
        it (a state not after it, no reset due, the bank's row as its state), else ``None``:
        the general path then takes the call."""
        lane = self._lanes(tuple(index))
        if lane is None:
            return None
        ts = list(map(float, t))
        b = _Batch(lane.kind)
        dts = b.dts
        for f, x, p, tk in zip(lane.filters, lane.xv, lane.pv, ts):
            dt = f.step_time(tk, x, p)
            if dt is None:
                return None
            dts.append(dt)
        b.ks, b.fs, b.ts = lane.ks, lane.filters, ts
        b.sel_array, b.out = lane.sel, lane.out
        return b

    def _make_lane(self, key: tuple) -> _Lane | None:
        """The lane of the filters ``key``, or ``None`` if they do not form one."""
        if not key or len(set(key)) != len(key):
            return None
        slots = [self._slot[i] for i in key]
        if any(s is None for s in slots) or any(s[0] is not slots[0][0] for s in slots):
            return None
        return _Lane(slots[0][0], [self.filters[i] for i in key], [s[1] for s in slots])

    def _ahead(self, index: Sequence[int], t: float) -> PredictedPoses:
        return self.predict_block(index, [t] * len(index))

    def _update_trusted(self, index, t, position, quaternion, covariance) -> list:
        trusted = UncertainPose._trusted
        poses = [trusted(position[k], quaternion[k], covariance[k]) for k in range(len(index))]
        return self.update_poses(index, t, poses)

    @staticmethod
    def _one(f, t, pose) -> bool:
        try:
            return bool(f.update_pose(t, pose))
        except ValueError:
            return False

    def _step(
        self, b: _Batch, zp, zo, r, out: list, defer: bool = False, at: float | None = None
    ) -> bool:
        """One kernel call for the measurements of ``b`` (their positions ``zp`` (m, 3),
        quaternions ``zo`` (m, 4) and covariances ``r`` (m, 6, 6), arrays or sequences of
        rows), then the filters' bookkeeping (:meth:`settle`; at once unless ``defer``). A
        diverged step re-initialises its filter (:meth:`PoseKalmanFilter.commit_steps`): the
        bookkeeping of every filter of the call is then done at once. Returns whether none
        diverged (every filter's state is still its row).

        With ``at`` [s] (finite, not before any step's time ``b.ts``), the same call also
        predicts the filters' poses at ``at`` from the rows it has just written
        (:func:`kernels.step_predict_bank`) into ``b.ahead``: ``predict_block(index, [at] *
        m)``'s answers, to the bit, used when none diverged."""
        kind = b.kind
        if b.sel_array is None:
            b.sel_array = frozen(b.sel, np.int64)
        status, nis, no_records = b.out or _kernel_out(len(b.fs))
        zp, zo, r = frozen(zp), frozen(zo), frozen(r)
        args = (kind.xs, kind.ps, b.sel_array, frozen(b.dts), kind.const, zp, zo, r, kind.gate)
        if at is None:  # no records: _records writes them from the rows, later
            kernels().step_bank(*args, no_records, status, nis)
        else:
            m = len(b.fs)
            res = np.empty((m, _source.POSE_OUT))
            kernels().step_predict_bank(*args, no_records, status, nis, at, frozen(b.ts), res)
            b.ahead = PredictedPoses(
                res[:, :3], res[:, 3:7], res[:, 7:].reshape(m, 6, 6), [True] * m
            )
        gated = gating.GATED
        codes = status.tolist()
        for k, st in zip(b.ks, codes):
            out[k] = st != gated
        if gating.DIVERGED in codes:
            PoseKalmanFilter.commit_steps(b.fs, b.ts, _records(b, zp, zo, r), codes, nis.tolist())
            return False
        self._unlogged.append((b, zp, zo, r, codes, nis.tolist()))
        if not defer:
            self.settle()
        return True

    def settle(self) -> None:
        """The bookkeeping of the kernel steps an update left pending
        (``update_block(..., defer=True)``): each filter's time and run of gated
        measurements and its log entry (the record of the measurement and the state after
        it (:func:`_records`), gate decision and NIS), as its own update would have recorded
        them (:meth:`PoseKalmanFilter.commit_steps`). Until then only the filters' states
        (the bank's rows) are current: the bank's own calls settle first, and nothing else
        may call into the filters."""
        pending, self._unlogged = self._unlogged, []
        for b, zp, zo, r, codes, nis in pending:
            PoseKalmanFilter.commit_steps(b.fs, b.ts, _records(b, zp, zo, r), codes, nis)

    # -- predictions -------------------------------------------------------------------------
    def predict_poses(self, index: Sequence[int], t: Sequence[float]) -> list:
        """``filters[index[k]].predict(t[k])`` for every ``k`` [s].

        Returns
        -------
        list of UncertainPose or None
            The predicted (or, for a past time, smoothed) pose of each request, equal to the
            filter's own answer to the last bit; ``None`` where the filter's
            :meth:`~PoseKalmanFilter.predict` raises ``ValueError`` (no measurement yet, a
            time before its history or not finite).
        """
        res = self.predict_block(index, t)
        trusted = UncertainPose._trusted
        return [
            trusted(p, q, c) if ok else None
            for ok, p, q, c in zip(res.ok, res.position, res.quaternion, res.covariance)
        ]

    def predict_block(self, index: Sequence[int], t: Sequence[float]) -> PredictedPoses:
        """:meth:`predict_poses` with the poses as arrays (:class:`PredictedPoses`)."""
        if self._unlogged:  # the filters' times
            self.settle()
        m = len(index)
        res = np.empty((m, _source.POSE_OUT))
        ok = [False] * m
        batch: dict[int, tuple] = {}  # per kind: (kind, measurement indices, rows, steps)
        filters, slots = self.filters, self._slot
        for k, i in enumerate(index):
            f = filters[i]
            slot = slots[i]
            tk = float(t[k])
            t0 = f.time
            if slot is None or t0 is None or not t0 <= tk < math.inf:
                try:
                    pose = f.predict(tk)
                except ValueError:
                    continue
                res[k, :3], res[k, 3:7] = pose.position, pose.quaternion
                res[k, 7:] = pose.covariance.reshape(-1)
                ok[k] = True
                continue
            kind, row = slot
            b = batch.get(id(kind))
            if b is None:
                b = batch[id(kind)] = (kind, [], [], [])
            self._take(f, kind, row)
            b[1].append(k)
            b[2].append(row)
            b[3].append(tk - t0)
            ok[k] = True
        for kind, ks, rows, dts in batch.values():
            whole = len(ks) == m  # every request, in order: straight into the result
            dst = res if whole else np.empty((len(ks), _source.POSE_OUT))
            kernels().predict_pose_bank(
                kind.xs, kind.ps, frozen(rows, np.int64), frozen(dts), kind.const, dst
            )
            if not whole:
                res[ks] = dst
        if not all(ok):
            res[[k for k in range(m) if not ok[k]]] = np.nan
        return PredictedPoses(res[:, :3], res[:, 3:7], res[:, 7:].reshape(m, 6, 6), ok)
