"""Streaming pose Kalman filter: predict, interpolate, fuse and estimate static poses."""

from __future__ import annotations

import bisect
import logging
import math
from typing import NamedTuple

import numpy as np

from trackflow.math import Pose, UncertainPose, check_covariance, check_quaternion, kernels_for

from ...errors import InputError
from .. import gating
from ..contract import FilterClock, FilterStatus, MeasurementFunction
from ..gating import GatePolicy, chi2_gate
from . import kernels as _source
from .model import MotionModel

__all__ = ["FilterSnapshot", "KernelSettings", "PoseKalmanFilter", "chi2_gate", "step_records"]


def kernels():
    """The derivative-model kernels for the active backend."""
    return kernels_for(_source)


log = logging.getLogger("trackflow.filters")

_PRIOR_SIGMA_POSITION = 10.0  # m, m/s, m/s^2, ... for parts no measurement has reached yet
_PRIOR_SIGMA_ANGLE = math.pi  # rad
_PRIOR_SIGMA_RATE = 10.0  # rad/s, rad/s^2, ...
# statuses after which the state does not continue the previous one (no smoothing across)
_SEGMENT_START = (FilterStatus.INITIALIZED, FilterStatus.RESET, FilterStatus.DIVERGED)


_F64 = np.dtype(np.float64)


def _kernel_array(a) -> np.ndarray:
    """``a`` itself when a kernel can take it as is (a writable C-contiguous float64
    ndarray), else a float64 copy. The filter never writes to it; the log copies it."""
    if type(a) is np.ndarray and a.dtype is _F64:
        f = a.flags
        if f.c_contiguous and f.writeable:
            return a
    return np.array(a, dtype=float)


class FilterSnapshot(NamedTuple):
    """A filter's state right after a measurement: all another copy of the same filter (same
    motion model, formulation and history) needs to answer ``predict`` as this one does.

    Parameters
    ----------
    t : float
        Time of the state [s] (the measurement's time).
    x : ndarray (n,)
        Nominal state (pose, then its derivatives; layout of :class:`MotionModel`).
    p : ndarray (m, m)
        Its covariance (over the error state of the formulation).
    segment_start : bool
        The filter (re)started at this state (first measurement, reset, divergence):
        past queries do not smooth across it.
    """

    t: float
    x: np.ndarray
    p: np.ndarray
    segment_start: bool


class KernelSettings(NamedTuple):
    """A filter's constant inputs to the derivative-model kernels
    (:attr:`PoseKalmanFilter.kernel_settings`): what a compiled loop over its measurements
    (:mod:`.offline`) or a batched step of many filters (:class:`~.bank.PoseFilterBank`)
    needs of it. Two filters with equal settings (:meth:`same_kernel`) compute the same
    step from the same state and measurement.

    Parameters
    ----------
    params : tuple
        :meth:`MotionModel.kernel_params` of the filter's formulation: ``(n_dp, n_do,
        additive, kind, sigma_p, sigma_o)``.
    const : ndarray
        The same parameters and the angular-velocity bound packed in one read-only array
        (:func:`kernels.constants`).
    gate : float
        NIS threshold of a measurement of the pose parts the model estimates (6 degrees of
        freedom for a model of position and orientation, else 3).
    reset_after : int
        Consecutive gated measurements after which the next absolute one re-initialises.
    max_angular_velocity : float
        Bound on the estimated angular velocity [rad/s] (0: none).
    x0 : ndarray (nx,)
        The prior state (read-only): the state's length is ``x0.size``.
    p0 : ndarray (nc, nc)
        Its covariance (read-only), over the formulation's error state.
    record_size : int
        Length of a pose measurement's log record (:func:`step_records`).
    """

    params: tuple
    const: np.ndarray
    gate: float
    reset_after: int
    max_angular_velocity: float
    x0: np.ndarray
    p0: np.ndarray
    record_size: int

    def same_kernel(self, other: KernelSettings) -> bool:
        """Whether a filter with ``other`` settings computes what one with these does."""
        return (
            self.x0.shape == other.x0.shape
            and self.p0.shape == other.p0.shape
            and self.gate == other.gate
            and self.reset_after == other.reset_after
            and np.array_equal(self.const, other.const)
        )


def step_records(x, p, zp, zo, r) -> np.ndarray:
    """The log records (m, size) of ``m`` pose steps, as the filter keeps them
    (:meth:`PoseKalmanFilter.commit_steps`): the state after the step ``x`` (m, nx), its
    covariance ``p`` (m, nc, nc) row by row, the measured position ``zp`` (m, 3) [m],
    quaternion ``zo`` (m, 4) ``(x, y, z, w)`` and noise ``r`` (m, 6, 6) row by row (arrays)."""
    m, nx = x.shape
    o = nx + p.shape[1] * p.shape[2]
    logs = np.empty((m, o + 43))
    logs[:, :nx] = x
    logs[:, nx:o] = p.reshape(m, -1)
    logs[:, o : o + 3] = zp
    logs[:, o + 3 : o + 7] = zo
    logs[:, o + 7 :] = r.reshape(m, -1)
    return logs


class _Entry:
    """One logged measurement and the filter state right after it, in one flat record
    ``buf`` (:func:`kernels.log_size`): ``x``, ``P`` row by row, ``zp``, ``zo``, ``r``."""

    __slots__ = (
        "t", "lp", "lo", "fn", "status", "nis", "gated_run", "buf", "nx", "nc", "m", "_state"
    )  # fmt: skip

    def __init__(self, t, lp, lo, buf, nx, nc, m, fn=None):
        self.t, self.lp, self.lo, self.buf, self.nx, self.nc, self.m = t, lp, lo, buf, nx, nc, m
        self.fn = fn  # a MeasurementFunction (lp = lo = -1), or None for a built-in measurement
        self.status = -1
        self.nis = math.nan
        self.gated_run = 0
        self._state = None  # views (x, P) of the record, made on first use

    def _views(self) -> tuple[np.ndarray, np.ndarray]:
        if self._state is None:
            o, n = self.nx, self.nc
            self._state = (self.buf[:o], self.buf[o : o + n * n].reshape(n, n))
        return self._state

    @property
    def x(self) -> np.ndarray:
        """The state after the measurement (the same view object on every access)."""
        return self._views()[0]

    @property
    def p(self) -> np.ndarray:
        return self._views()[1]

    def replace_record(self) -> None:
        """Give the entry a fresh copy of its record before it is written again, so arrays
        handed out earlier keep their values."""
        self.buf = self.buf.copy()
        self._state = None

    @property
    def zp(self) -> np.ndarray:
        o = self.nx + self.nc * self.nc
        return self.buf[o : o + 3]

    @property
    def zo(self) -> np.ndarray:
        o = self.nx + self.nc * self.nc + 3
        return self.buf[o : o + 4]

    @property
    def r(self) -> np.ndarray:
        o = self.nx + self.nc * self.nc + 7
        return self.buf[o : o + self.m * self.m].reshape(self.m, self.m)

    def store_measurement(self, zp, zo, r) -> None:
        o = self.nx + self.nc * self.nc
        self.buf[o : o + 3] = zp
        self.buf[o + 3 : o + 7] = zo
        self.buf[o + 7 :] = np.reshape(r, -1)

    def store_state(self, x, p) -> None:
        self.buf[: self.nx] = x
        self.buf[self.nx : self.nx + self.nc * self.nc] = p.reshape(-1)


class PoseKalmanFilter(FilterClock):
    """Kalman filter of one spatial relationship ``T_a_b(t)`` built from a motion model.

    Serves prediction (``predict(t)`` in the future, covariance growing with the motion
    model), measurement simultaneity (``predict(t)`` in the past, smoothed from the stored
    states), sensor fusion (SCAAT style: each measurement of any kind is integrated on its own,
    at its own time) and static estimation (``MotionModel.static()``: recursive least squares).

    Parameters
    ----------
    model : MotionModel
    history : float
        Seconds of measurements and states kept for out-of-order insertion and past queries.
    gate_probability : float or None
        Innovations whose NIS exceeds the chi-square quantile of this probability (degrees of
        freedom = measured dimensions) are rejected and counted (``stats["rejected_gate"]``).
        ``None`` disables gating.
    formulation : {"error_state", "additive"}
        ``"error_state"`` (default): the covariance is over the multiplicative rotation error
        ``R_true = R Exp(dtheta)`` (``docs/conventions.md``), so poses come out in trackflow's
        convention directly. ``"additive"``: the thesis's filter (section 6.2) with the
        quaternion treated as a 4-vector, normalised after each update.
    max_angular_velocity : float
        Upper bound (rad/s) on the estimated angular velocity's norm, applied to the mean only
        (the covariance stays as the Kalman update made it). ``0`` disables.
    reset_after : int
        After this many consecutive gated measurements, the next pose or position or orientation
        measurement re-initialises the filter (a diverged or lost filter); resets are logged on
        the ``trackflow.filters`` logger and counted in ``stats["resets"]``, as are resets after a
        singular innovation covariance or a non-finite state.

    Notes
    -----
    Every state part a measurement has not reached yet starts at zero (identity rotation)
    with a wide prior (10 m and 10 m/s^k; pi rad and 10 rad/s^k). The first measurement sets the
    parts it measures outright (the limit of an infinitely wide prior), so a static model
    reproduces batch least squares over all its measurements.
    """

    def __init__(
        self,
        model: MotionModel,
        history: float = 1.0,
        gate_probability: float | None = 0.999,
        formulation: str = "error_state",
        max_angular_velocity: float = 50.0,
        reset_after: int = 10,
    ):
        if not isinstance(model, MotionModel):
            raise InputError(f"model must be a MotionModel, got {type(model).__name__}")
        if not (math.isfinite(history) and history >= 0):
            raise InputError(f"history must be finite and >= 0 seconds, got {history}")
        if not (math.isfinite(max_angular_velocity) and max_angular_velocity >= 0):
            raise InputError(f"max_angular_velocity must be >= 0, got {max_angular_velocity}")
        self._model = model
        self._formulation = formulation
        self._params = model.kernel_params(formulation)
        self._additive = self._params[2]
        self._history = float(history)
        self._policy = GatePolicy(gate_probability, reset_after)
        self._gates = {m: self._policy.threshold(m) for m in (3, 6)}
        self._reset_after = self._policy.reset_after
        self._wmax = float(max_angular_velocity)
        self._x0, self._p0 = self._prior()
        n_dp, n_do, add = self._params[:3]
        self._nx, self._nc = self._x0.shape[0], self._p0.shape[0]
        self._log_sizes = {m: _source.log_size(n_dp, n_do, add, m) for m in (0, 3, 6)}
        self._last_r = (None, None)  # (caller's read-only noise, its writable copy)
        self._pose_model = n_dp >= 0 and n_do >= 0
        self._const = _source.constants(*self._params, self._wmax)
        x0, p0, const = self._x0.copy(), self._p0.copy(), self._const.copy()
        for a in (x0, p0, const):
            a.flags.writeable = False
        self._settings = KernelSettings(
            self._params, const, self._gates[6 if self._pose_model else 3],
            self._policy.reset_after, self._wmax, x0, p0, self._log_sizes[6],
        )  # fmt: skip
        self.reset()

    # -- state -----------------------------------------------------------------------------
    def _prior(self):
        n_dp, n_do, add = self._params[:3]
        npl, nol, nx, nc = _source.dims(n_dp, n_do, add)
        x = self._model.initial_state()
        var = [_PRIOR_SIGMA_POSITION**2] * (3 * npl)
        for lvl in range(nol):
            s = _PRIOR_SIGMA_ANGLE if lvl == 0 else _PRIOR_SIGMA_RATE
            var += [s * s] * (4 if (add and lvl == 0) else 3)
        if add and nol:  # quaternion components: half-angle units
            var[3 * npl : 3 * npl + 4] = [(_PRIOR_SIGMA_ANGLE / 2) ** 2] * 4
        return x, np.diag(var)

    def reset(self) -> None:
        """Forget everything: state, history and statistics."""
        self._x = self._x0.copy()
        self._p = self._p0.copy()
        self._t: float | None = None
        self._gated_run = 0
        self._log: list[_Entry] = []
        self._times: list[float] = []
        self._base: _Entry | None = None  # state before the oldest logged measurement
        self._smooth_cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._counts = {"rejected_old": 0, "out_of_order": 0, "rejected_uninitialized": 0}
        self._pruned = dict.fromkeys(range(6), 0)

    @property
    def model(self) -> MotionModel:
        return self._model

    @property
    def formulation(self) -> str:
        return self._formulation

    @property
    def nis(self) -> float:
        """Normalised innovation squared of the newest measurement (NaN if none was formed)."""
        return self._log[-1].nis if self._log else math.nan

    @property
    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of the nominal state vector and its covariance at :attr:`time`."""
        return self._x.copy(), self._p.copy()

    @property
    def stats(self) -> dict:
        """Counters: ``updates`` (integrated, including (re)initialisations),
        ``rejected_gate``, ``rejected_old`` (older than the history window), ``resets``,
        ``out_of_order`` (inserted by re-filtering), ``rejected_invalid`` and
        ``rejected_uninitialized`` (measurement functions, :meth:`update_measurement`)."""
        c = dict(self._pruned)
        for e in self._log:
            c[e.status] += 1
        return {
            "updates": c[FilterStatus.ACCEPTED]
            + c[FilterStatus.INITIALIZED]
            + c[FilterStatus.RESET]
            + c[FilterStatus.DIVERGED],
            "rejected_gate": c[FilterStatus.GATED],
            "rejected_old": self._counts["rejected_old"],
            "resets": c[FilterStatus.RESET] + c[FilterStatus.DIVERGED],
            "out_of_order": self._counts["out_of_order"],
            "rejected_invalid": c[FilterStatus.INVALID],
            "rejected_uninitialized": self._counts["rejected_uninitialized"],
        }

    # -- batched steps (PoseFilterBank) -------------------------------------------------------
    @property
    def kernel_settings(self) -> KernelSettings:
        """The filter's constant kernel inputs (:class:`KernelSettings`)."""
        return self._settings

    @property
    def batchable(self) -> bool:
        """Whether :meth:`update_pose` of a plain pose measurement is one kernel step that a
        batch of filters may take for it (:meth:`step_time`, :meth:`commit_steps`): ``True``
        for a model of both position and orientation. A subclass whose ``update_pose`` does
        more returns ``False``."""
        return self._pose_model

    def step_time(self, t: float, x=None, p=None) -> float | None:
        """The time step [s] from the filter's newest state to a pose measurement at ``t``
        [s] when :meth:`update_pose` would integrate it in one plain kernel step (the filter
        is initialised, ``t`` is finite and not before its newest state, and no reset is
        due), else ``None``. With ``x`` and ``p``, also ``None`` unless the filter's state
        is held in these very arrays (:meth:`bind_state`)."""
        t0 = self._t
        if (
            t0 is None
            or not t0 <= t < math.inf
            or self._gated_run >= self._reset_after  # gating.reset_due, initialised
            or (x is not None and (self._x is not x or self._p is not p))
        ):
            return None
        return t - t0

    def holds_state(self, x: np.ndarray, p: np.ndarray) -> bool:
        """Whether the filter's newest state and covariance are held in the arrays ``x``
        (nx,) and ``p`` (nc, nc) (:meth:`bind_state`)."""
        return self._x is x and self._p is p

    def bind_state(self, x: np.ndarray, p: np.ndarray) -> None:
        """Hold the newest state in the caller's arrays ``x`` (nx,) and ``p`` (nc, nc) from
        now on (its values copied in unless they are held there already): a kernel stepping
        many filters at once writes the states in place (:class:`~.bank.PoseFilterBank`'s
        rows), and :meth:`commit_steps` records the step. The filter replaces them with
        arrays of its own when it re-initialises or re-filters out of order; bind them
        again then (:meth:`holds_state`)."""
        if self._x is not x:
            x[:] = self._x
            self._x = x
        if self._p is not p:
            p[:, :] = self._p
            self._p = p

    @staticmethod
    def commit_steps(filters, t, records, status, nis) -> None:
        """Record, for every ``k``, the pose measurement at ``t[k]`` [s] that a kernel
        integrated into the state arrays of ``filters[k]`` (:meth:`bind_state`) after its
        :meth:`step_time` said it may, as :meth:`update_pose` records its own step: the log
        entry (``records[k]``, a row of :func:`step_records`: the measurement and the state
        after it), the gate decision ``status[k]`` (:class:`FilterStatus`) and NIS
        ``nis[k]``, the filter's time and run of gated measurements; a diverged step
        re-initialises the filter from the measurement. Older entries than the history go.
        (One call for a batch: the bank's bookkeeping costs no call per filter more than
        the filter's own.)"""
        for f, tk, record, st, v in zip(filters, t, records, status, nis):
            e = _Entry(tk, 0, 0, record, f._nx, f._nc, 6)
            f._stepped(e, st, v)
            f._append(e)

    # -- replication -------------------------------------------------------------------------
    def snapshot(self) -> FilterSnapshot:
        """The newest state (after the newest logged measurement), for :meth:`adopt` by a copy
        of this filter elsewhere (read-only arrays; the filter never changes them)."""
        if not self._log:
            raise InputError("the filter has no measurement yet; nothing to snapshot")
        e = self._log[-1]
        return FilterSnapshot(e.t, e.x, e.p, e.status in _SEGMENT_START)

    def adopt(self, snap: FilterSnapshot) -> bool:
        """Take a state computed by another copy of this filter as the newest state, as if this
        filter had integrated the measurement behind it: predictions ahead of it, and past
        queries smoothed between adopted states, are then the other copy's answers.

        A state at the newest time replaces the newest one (the other copy re-filtered it);
        an older one is refused (``False``, counted in ``stats["rejected_old"]``). The
        snapshot's arrays are copied into the history's record.

        Raises
        ------
        ValueError
            If the state's shapes are not this model's.
        """
        t = float(snap.t)
        x = np.asarray(snap.x, dtype=float)  # copied into the entry's record
        p = np.asarray(snap.p, dtype=float)
        if x.shape != self._x0.shape or p.shape != self._p0.shape or not math.isfinite(t):
            raise InputError(
                f"state of shape {x.shape} / {p.shape} at t={t} does not fit this filter "
                f"({self._x0.shape} / {self._p0.shape})"
            )
        if self._t is not None and t < self._t:
            self._counts["rejected_old"] += 1
            return False
        e = _Entry(t, -1, -1, np.zeros(self._log_sizes[0]), self._nx, self._nc, 0)
        e.status = FilterStatus.INITIALIZED if snap.segment_start else FilterStatus.ACCEPTED
        e.store_state(x, p)
        self._smooth_cache = {}
        if self._log and t == self._t:
            self._log[-1] = e
        else:
            self._log.append(e)
            self._times.append(t)
        self._x, self._p, self._t = x.copy(), p.copy(), t
        self._prune()
        return True

    # -- measurements ------------------------------------------------------------------------
    def update_pose(self, t: float, measurement: UncertainPose) -> bool:
        """Integrate a full pose measurement ``T_a_b`` at time ``t`` (seconds).

        ``measurement.covariance`` (6x6) is over ``(dt, dtheta)`` with ``t_true = t + dt``,
        ``R_true = R Exp(dtheta)``. Parts the model does not estimate are ignored.

        Returns
        -------
        bool
            ``True`` if integrated; ``False`` if rejected by the gate or older than the history
            window (both counted in :attr:`stats`).
        """
        if not isinstance(measurement, UncertainPose) or measurement.shape != ():
            raise InputError("update_pose needs a single UncertainPose")
        pose = measurement.pose
        zp, zo, c = pose.position, pose.quaternion, measurement.covariance
        if self._pose_model:
            return self._measure(t, 0, 0, zp, zo, c)
        if self._params[0] >= 0:
            return self._measure(t, 0, -1, zp, zo, c[:3, :3].copy())
        return self._measure(t, -1, 0, zp, zo, c[3:, 3:].copy())

    def update_position(self, t: float, position, covariance) -> bool:
        """Position ``t_a_b`` (m, frame a) with 3x3 covariance (``t_true = t + dt``)."""
        return self._vector(t, 0, -1, position, covariance, "position")

    def update_orientation(self, t: float, quaternion, covariance) -> bool:
        """Orientation ``q_a_b`` with 3x3 covariance of ``dtheta`` (``R_true = R Exp(dtheta)``)."""
        if self._params[1] < 0:
            raise InputError("this motion model does not estimate orientation (n_do = -1)")
        q = check_quaternion(quaternion)
        if q.shape != (4,):
            raise InputError(f"quaternion must have shape (4,), got {q.shape}")
        return self._measure(t, -1, 0, np.zeros(3), q, check_covariance(covariance, size=3))

    def update_velocity(self, t: float, velocity, covariance) -> bool:
        """Linear velocity ``d t_a_b / dt`` (m/s, frame a) with 3x3 covariance (additive)."""
        return self._vector(t, 1, -1, velocity, covariance, "velocity")

    def update_acceleration(self, t: float, acceleration, covariance) -> bool:
        """Linear acceleration (m/s^2, frame a, gravity removed) with 3x3 covariance."""
        return self._vector(t, 2, -1, acceleration, covariance, "acceleration")

    def update_angular_velocity(self, t: float, angular_velocity, covariance) -> bool:
        """Angular velocity in the body frame b (rad/s, a gyroscope) with 3x3 covariance."""
        return self._vector(t, -1, 1, angular_velocity, covariance, "angular velocity")

    def _vector(self, t, lp, lo, value, covariance, name) -> bool:
        level, have = (lp, self._params[0]) if lp >= 0 else (lo, self._params[1])
        if have < level:
            part = "position" if lp >= 0 else "orientation"
            raise InputError(
                f"cannot integrate a {name} measurement: the motion model estimates "
                f"{max(have, -1)} {part} derivatives (needs >= {level})"
            )
        v = np.asarray(value, dtype=float)
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise InputError(f"{name} must be finite with shape (3,), got {v.shape}")
        c = check_covariance(covariance, name=f"{name} covariance", size=3)
        if lp >= 0:
            return self._measure(t, lp, -1, v, np.zeros(4), c)
        return self._measure(t, -1, lo, np.zeros(3), np.concatenate([v, [0.0]]), c)

    def update_measurement(self, t: float, measurement: MeasurementFunction) -> bool:
        """Integrate a user-defined measurement of the pose at time ``t`` (thesis 7.3.2).

        ``measurement`` meets :class:`~trackflow.filters.MeasurementFunction`: ``residual(T)``
        gives ``y = z - h(T)`` and ``J_h_pose`` (m, 6) over the pose error ``(dt, dtheta)``,
        ``covariance`` gives ``R`` (m, m). The update is the extended Kalman filter's with
        ``H = J_h_pose`` placed on the state's pose columns and the gate of the filter's policy
        at ``m`` degrees of freedom.

        Returns
        -------
        bool
            ``True`` if integrated; ``False`` for a counted rejection: gated, older than the
            history, before the first absolute measurement (``rejected_uninitialized``: a
            measurement function cannot initialise the pose) or a singular innovation
            covariance (``rejected_invalid``; the state stays the prediction).
        """
        if not isinstance(measurement, MeasurementFunction):
            raise InputError(
                "measurement must have residual(pose) -> (y, J_h_pose) and covariance, got "
                f"{type(measurement).__name__}"
            )
        if self._additive:
            raise InputError("measurement functions need the error_state formulation")
        if self._params[0] < 0 or self._params[1] < 0:
            raise InputError(
                "measurement functions need a model estimating position and orientation"
            )
        if self._t is None:
            self._counts["rejected_uninitialized"] += 1
            return False
        return self._measure(t, -1, -1, np.zeros(3), np.zeros(4), np.zeros((0, 0)), measurement)

    def _measure(self, t, lp, lo, zp, zo, r, fn=None) -> bool:
        t = float(t)
        if not math.isfinite(t):
            raise InputError(f"measurement time must be finite, got {t}")
        if self._smooth_cache:
            self._smooth_cache = {}
        if type(r) is np.ndarray and not r.flags.writeable and r.base is None:
            last = self._last_r  # a read-only noise (a sensor's nominal one): copied once
            if last[0] is not r:
                last = self._last_r = (r, np.array(r, dtype=float))
            r = last[1]
        z = (_kernel_array(zp), _kernel_array(zo), _kernel_array(r))
        m = z[2].shape[0]
        size = self._log_sizes.get(m)
        if size is None:
            size = _source.log_size(*self._params[:3], m)
        e = _Entry(t, lp, lo, np.empty(size), self._nx, self._nc, m, fn)
        if self._t is None or t >= self._t:
            self._apply(e, z)
            self._append(e)
            return e.status != gating.GATED
        oldest = self._base.t if self._base is not None else -math.inf
        if t < self._t - self._history or t < oldest:
            self._counts["rejected_old"] += 1
            return False
        # Out of order but inside the window: insert and re-filter from the stored state
        # just before it (same operations, in the same order, as in-order arrival).
        i = bisect.bisect_right(self._times, t)
        self._restore(i)
        self._log.insert(i, e)
        self._times.insert(i, t)
        self._apply(e, z)
        for entry in self._log[i + 1 :]:
            self._apply(entry)
        self._counts["out_of_order"] += 1
        return e.status != FilterStatus.GATED

    def _restore(self, i: int) -> None:
        src = self._log[i - 1] if i > 0 else self._base
        if src is None:
            self._x, self._p, self._t, self._gated_run = self._x0.copy(), self._p0.copy(), None, 0
        else:
            self._x, self._p = src.x.copy(), src.p.copy()
            self._t, self._gated_run = src.t, src.gated_run

    def _reinit(self, e: _Entry, why: str) -> None:
        n_dp, n_do, add = self._params[:3]
        k = kernels()
        self._x = self._x0.copy()
        self._p = self._p0.copy()
        q = e.zo if e.lo == 0 else self._x[3 * (n_dp + 1) :][:4] if n_do >= 0 else e.zo
        r = k.meas_cov(e.r, np.ascontiguousarray(q), e.lp, e.lo, add)
        k.initialize(self._x, self._p, n_dp, n_do, add, e.lp, e.lo, e.zp, e.zo, r)
        if why:
            log.warning("pose Kalman filter reset at t=%.6f s: %s", e.t, why)

    def _apply_function(self, e: _Entry) -> None:
        """Predict to ``e.t`` and integrate the measurement function ``e.fn``."""
        n_dp, n_do, add, kind, sp, so = self._params
        k = kernels()
        x, p = k.predict(self._x, self._p, e.t - self._t, n_dp, n_do, add, kind, sp, so)
        qo = 3 * (n_dp + 1)
        y, J = e.fn.residual(Pose(x[:3], x[qo : qo + 4]))
        y = np.ascontiguousarray(y, dtype=float).reshape(-1)
        m = y.size
        J = np.asarray(J, dtype=float)
        if J.shape != (m, 6) or not (np.all(np.isfinite(y)) and np.all(np.isfinite(J))):
            raise InputError(
                f"measurement residual must be finite y (m,) and J_h_pose (m, 6); got y "
                f"{y.shape}, J {J.shape}"
            )
        r = check_covariance(e.fn.covariance, name="measurement covariance", size=m)
        h = np.zeros((m, p.shape[0]))
        h[:, :3] = J[:, :3]
        h[:, qo : qo + 3] = J[:, 3:]
        xp, pp = x.copy(), p.copy()
        gate = self._policy.threshold(m)
        status, nis = k.update(
            x, p, y, h, np.ascontiguousarray(r), gate, n_dp, n_do, add, self._wmax
        )
        e.status, e.nis = int(status), float(nis)
        if status == FilterStatus.DIVERGED:  # cannot re-initialise from h: keep the prediction
            x, p = xp, pp
            e.status = int(FilterStatus.INVALID)
        self._x, self._p = x, p
        self._gated_run = gating.next_gated_run(e.status, self._gated_run)

    def _apply(self, e: _Entry, z=None) -> None:
        """Integrate entry ``e`` and record the state after it in ``e``. ``z`` = ``(zp, zo,
        r)`` on its first application (the kernel copies them into the record), ``None``
        when applied again (out-of-order re-filtering: the record holds them; it is
        replaced, not rewritten, so states handed out by :meth:`snapshot` never change)."""
        if z is None:
            e.replace_record()
        absolute = e.lp == 0 or e.lo == 0
        if (
            e.fn is None
            and self._t is not None
            and not (absolute and gating.reset_due(True, self._gated_run, self._policy.reset_after))
        ):
            zp, zo, r = z if z is not None else (e.zp, e.zo, e.r)
            gate = self._gates[3 if (e.lp < 0 or e.lo < 0) else 6]
            status, nis = kernels().step_packed(
                self._x, self._p, e.t - self._t, self._const, e.lp, e.lo, zp, zo, r, gate, e.buf
            )
            self._stepped(e, int(status), float(nis))
            return
        if z is not None:
            e.store_measurement(*z)
        if e.fn is not None and self._t is not None:
            self._apply_function(e)
        elif self._t is None:
            self._reinit(e, "")
            e.status, e.nis = FilterStatus.INITIALIZED, math.nan
            self._gated_run = 0
        else:
            self._reinit(e, f"{self._gated_run} consecutive measurements failed the gate")
            e.status, e.nis = FilterStatus.RESET, math.nan
            self._gated_run = 0
        self._t = e.t
        e.store_state(self._x, self._p)
        e.gated_run = self._gated_run

    def _stepped(self, e: _Entry, status: int, nis: float) -> None:
        """Bookkeeping after a kernel (``step_packed``, or ``step_bank`` through
        :meth:`commit_steps`) integrated entry ``e`` and wrote its state into ``e``'s record:
        a diverged step re-initialises the filter from ``e``'s measurement."""
        e.status, e.nis = status, nis
        if status == gating.DIVERGED:
            self._reinit(e, "singular innovation covariance or non-finite state")
            e.store_state(self._x, self._p)
        if self._smooth_cache:  # smoothed past states change with a newer measurement
            self._smooth_cache = {}
        self._gated_run = e.gated_run = gating.next_gated_run(status, self._gated_run)
        self._t = e.t

    def _append(self, e: _Entry) -> None:
        """Entry ``e``, the newest, into the log; entries older than the history go."""
        self._log.append(e)
        self._times.append(e.t)
        self._prune()

    def _prune(self) -> None:
        # entries 0 .. n-1 go when entry n (the new base's successor) is before the horizon
        times, horizon = self._times, self._t - self._history
        if len(times) < 2 or not times[1] < horizon:
            return  # nothing to cut
        if len(times) < 3 or not times[2] < horizon:  # one entry goes (a steady stream)
            e = self._base = self._log.pop(0)
            times.pop(0)
            self._pruned[e.status] += 1
            return
        n = bisect.bisect_left(times, horizon, 1) - 1
        if n > 0:
            for e in self._log[:n]:
                self._pruned[e.status] += 1
            self._base = self._log[n - 1]
            del self._log[:n]
            del self._times[:n]

    # -- queries -----------------------------------------------------------------------------
    def predict_state(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Nominal state and covariance at time ``t`` (see :meth:`predict`)."""
        if self._t is None:
            raise InputError("the filter has no measurement yet; cannot predict")
        t = float(t)
        if not math.isfinite(t):
            raise InputError(f"prediction time must be finite, got {t}")
        n_dp, n_do, add, kind, sp, so = self._params
        k = kernels()
        if t >= self._t:
            return k.predict(self._x, self._p, t - self._t, n_dp, n_do, add, kind, sp, so)
        # stored nodes: the base state (if any) then the logged ones, indexed without copying
        off = 1 if self._base is not None else 0
        oldest = self._node(0).t
        if t < oldest:
            raise InputError(
                f"t={t:.6f} s is older than the stored history (oldest state at "
                f"{oldest:.6f} s; history={self._history} s)"
            )
        i = bisect.bisect_right(self._times, t) - 1 + off
        a, b = self._node(i), self._node(i + 1)
        if b.status in _SEGMENT_START:
            return k.predict(a.x, a.p, t - a.t, n_dp, n_do, add, kind, sp, so)
        if t == a.t:  # at a stored node the smoothed state is the answer (the same RTS step)
            xs, ps = self._smoothed(i)
            return xs.copy(), ps.copy()
        xb, pb = self._smoothed(i + 1)
        return k.smooth(a.x, a.p, a.t, xb, pb, b.t, t, n_dp, n_do, add, kind, sp, so)

    def _node(self, j: int) -> _Entry:
        """Stored node ``j``: the base state first (if any), then the logged entries."""
        if self._base is not None:
            return self._base if j == 0 else self._log[j - 1]
        return self._log[j]

    def _smoothed(self, j: int) -> tuple[np.ndarray, np.ndarray]:
        """Rauch-Tung-Striebel smoothed state at stored node ``j`` (cached until new data)."""
        if j in self._smooth_cache:
            return self._smooth_cache[j]
        n_dp, n_do, add, kind, sp, so = self._params
        k = kernels()
        count = len(self._log) + (1 if self._base is not None else 0)
        top = j
        while top + 1 < count and self._node(top + 1).status not in _SEGMENT_START:
            if top + 1 in self._smooth_cache:
                break
            top += 1
        if top + 1 < count and top + 1 in self._smooth_cache:
            xs, ps = self._smooth_cache[top + 1]
        else:  # newest node of a segment: smoothed = filtered
            node = self._node(top)
            xs, ps = node.x, node.p
            self._smooth_cache[top] = (xs, ps)
            top -= 1
        for m in range(top, j - 1, -1):
            a, b = self._node(m), self._node(m + 1)
            xs, ps = k.smooth(a.x, a.p, a.t, xs, ps, b.t, a.t, n_dp, n_do, add, kind, sp, so)
            self._smooth_cache[m] = (xs, ps)
        return self._smooth_cache[j]

    def predict(self, t: float) -> UncertainPose:
        """Pose ``T_a_b`` at time ``t`` (seconds) with its 6x6 covariance.

        ``t`` after the newest measurement: motion-model prediction, the covariance growing
        with the process noise. ``t`` in the past (within ``history``): smoothed between the
        stored filter states around ``t`` (one Rauch-Tung-Striebel step; the motion model only
        runs forwards). The covariance is over ``(dt, dtheta)`` with ``t_true = t + dt``,
        ``R_true = R Exp(dtheta)``; a part the model does not estimate is reported as zero /
        identity with variance 1e12.
        """
        if self._t is not None and t >= self._t:  # fast path: only the pose rows
            out = np.empty(_source.POSE_OUT)
            kernels().predict_pose_packed(self._x, self._p, float(t) - self._t, self._const, out)
            return UncertainPose._trusted(out[:3], out[3:7], out[7:].reshape(6, 6))
        x, p = self.predict_state(t)
        pos, q, c = kernels().pose_of(x, p, *self._params[:3])
        return UncertainPose._trusted(pos, q, c)
