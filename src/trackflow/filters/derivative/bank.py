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

import numpy as np

from trackflow.math import UncertainPose, frozen

from .. import gating
from . import kernels as _source
from .streaming import PoseKalmanFilter, _Entry, kernels

__all__ = ["PoseFilterBank"]


class _Kind:
    """The filters of one kind: their states as rows of ``xs`` (n, nx) and ``ps`` (n, nc,
    nc), the packed constants, the gate of a pose measurement and the record length."""

    def __init__(self, f: PoseKalmanFilter, n: int):
        self.const = frozen(f._const)  # kernel inputs read-only: one specialisation
        self.gate = f._gates[6]
        self.reset_after = f._policy.reset_after
        self.nx, self.nc = f._nx, f._nc
        self.size = f._log_sizes[6]
        self.xs = np.zeros((n, self.nx))
        self.ps = np.zeros((n, self.nc, self.nc))
        self.xv = list(self.xs)  # row views: the filters' state arrays while banked
        self.pv = list(self.ps)

    def fits(self, f: PoseKalmanFilter) -> bool:
        return (
            f._nx == self.nx
            and f._nc == self.nc
            and f._gates[6] == self.gate
            and f._policy.reset_after == self.reset_after
            and np.array_equal(f._const, self.const)
        )


class _Batch:
    """The kernel's inputs for the measurements of filters of one kind: per measurement its
    ``(index, filter, time)``, the filter's row, the time step and the measurement."""

    __slots__ = ("kind", "rows", "sel", "dts", "zp", "zo", "r")

    def __init__(self, kind: _Kind):
        self.kind = kind
        self.rows: list = []
        self.sel: list = []
        self.dts: list = []
        self.zp: list = []
        self.zo: list = []
        self.r: list = []


def _bankable(f) -> bool:
    return type(f) is PoseKalmanFilter and f._pose_model


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

    def _take(self, f: PoseKalmanFilter, kind: _Kind, row: int) -> None:
        """Make the filter's state arrays the bank's row (copying its state in if it
        replaced them since)."""
        x, p = kind.xv[row], kind.pv[row]
        if f._x is not x:
            x[:] = f._x
            f._x = x
        if f._p is not p:
            p[:, :] = f._p
            f._p = p

    # -- updates -----------------------------------------------------------------------------
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
        out: list = [False] * len(index)
        seen: set[int] = set()
        later: list[int] = []  # rows of a filter met before in this call: after the kernels
        batch: dict[int, _Batch] = {}  # per kind: the kernel's inputs
        filters, slots = self.filters, self._slot
        isfinite = math.isfinite
        for k, i in enumerate(index):
            if i in seen:
                later.append(k)
                continue
            seen.add(i)
            f = filters[i]
            slot = slots[i]
            tk = float(t[k])
            pose = poses[k]
            t0 = f._t
            if (
                slot is None
                or t0 is None
                or not tk >= t0
                or not isfinite(tk)
                or f._gated_run >= slot[0].reset_after  # a reset is due
                or not isinstance(pose, UncertainPose)
            ):
                out[k] = self._one(f, tk, pose)
                continue
            r = pose.covariance
            if r.ndim != 2:  # a batch of poses
                out[k] = self._one(f, tk, pose)
                continue
            kind, row = slot
            b = batch.get(id(kind))
            if b is None:
                b = batch[id(kind)] = _Batch(kind)
            if f._x is not kind.xv[row] or f._p is not kind.pv[row]:
                self._take(f, kind, row)
            p = pose.pose
            b.rows.append((k, f, tk))
            b.sel.append(row)
            b.dts.append(tk - t0)
            b.zp.append(p.position)
            b.zo.append(p.quaternion)
            b.r.append(r)
        for b in batch.values():
            self._step(b, out)
        for k in later:
            out[k] = self._one(filters[index[k]], t[k], poses[k])
        return out

    @staticmethod
    def _one(f, t, pose) -> bool:
        try:
            return bool(f.update_pose(t, pose))
        except ValueError:
            return False

    @staticmethod
    def _step(b: _Batch, out: list) -> None:
        """One kernel call for the measurements of ``b``, then each filter's log entry and
        bookkeeping by the filter's own ``_stepped`` and ``_append``."""
        kind, m = b.kind, len(b.rows)
        logs = np.empty((m, kind.size))
        status = np.empty(m, np.int64)
        nis = np.empty(m)
        kernels().step_bank(
            kind.xs, kind.ps, frozen(b.sel, np.int64), frozen(b.dts), kind.const,
            frozen(b.zp), frozen(b.zo), frozen(b.r), kind.gate, logs, status, nis,
        )  # fmt: skip
        gated = gating.GATED
        nx, nc = kind.nx, kind.nc
        for (k, f, tk), buf, st, v in zip(b.rows, logs, status.tolist(), nis.tolist()):
            if f._smooth_cache:
                f._smooth_cache = {}
            e = _Entry(tk, 0, 0, buf, nx, nc, 6)
            f._stepped(e, st, v)
            f._append(e)
            out[k] = st != gated

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
        out: list = [None] * len(index)
        batch: dict[int, tuple] = {}  # per kind: (kind, measurement indices, rows, steps)
        filters, slots = self.filters, self._slot
        for k, i in enumerate(index):
            f = filters[i]
            slot = slots[i]
            tk = float(t[k])
            if slot is None or f._t is None or not tk >= f._t or not math.isfinite(tk):
                try:
                    out[k] = f.predict(tk)
                except ValueError:
                    pass
                continue
            kind, row = slot
            b = batch.get(id(kind))
            if b is None:
                b = batch[id(kind)] = (kind, [], [], [])
            if f._x is not kind.xv[row] or f._p is not kind.pv[row]:
                self._take(f, kind, row)
            b[1].append(k)
            b[2].append(row)
            b[3].append(tk - f._t)
        trusted = UncertainPose._trusted
        for kind, ks, rows, dts in batch.values():
            m = len(ks)
            res = np.empty((m, _source.POSE_OUT))
            kernels().predict_pose_bank(
                kind.xs, kind.ps, frozen(rows, np.int64), frozen(dts), kind.const, res
            )
            pos, quat, cov = res[:, :3], res[:, 3:7], res[:, 7:].reshape(m, 6, 6)
            for k, p, q, c in zip(ks, pos, quat, cov):
                out[k] = trusted(p, q, c)
        return out
