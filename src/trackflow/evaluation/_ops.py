"""PoseTool operations on whole recordings (thesis 8.1.1): info, shift, scale, invert, infer."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..errors import InputError
from ..filters import smooth_filter
from ..io import PoseStream
from ..math import Pose, UncertainPose, quat_rminus
from ._predictor import KalmanPredictor, default_predictor
from ._targets import default_gap

__all__ = ["stream_info", "shift_stream", "scale_covariance", "invert_stream", "infer_streams"]


def stream_info(stream: PoseStream) -> dict:
    """Rate, duration, gaps, timing jitter and speed statistics of a recording.

    Gaps are intervals longer than three times the median interval. Speeds are from
    consecutive samples: linear [m/s] and angular [deg/s] (median, 95th percentile, max).
    """
    n = len(stream)
    out = {"source": stream.source, "target": stream.target, "samples": n}
    out["has_covariance"] = stream.covariance is not None
    if n < 2:
        return out
    t_ns, t0 = stream.t_ns, stream.t_ns[0]
    p = np.asarray(stream.position)
    q = np.asarray(stream.quaternion)

    # one or two arrays of N - 1 at a time (long recordings: 1.7M samples)
    def intervals(i: int, j: int) -> np.ndarray:  # [s], from times relative to the first
        return np.diff((t_ns[i : j + 1] - t0).astype(float) * 1e-9)

    dt = _per_interval(n, intervals)
    med = float(np.median(dt))
    gap = 3.0 * med  # default_gap of the times
    out.update(
        duration_s=float(np.float64(t_ns[-1] - t0) * 1e-9),
        rate_hz=1.0 / med,
        interval_median_ms=med * 1e3,
        jitter_ms=None,  # below
        gaps=int(np.count_nonzero(dt > gap)),
        largest_gap_s=float(dt.max()),
        quaternion_sign_flips=int(
            sum(
                np.count_nonzero(np.einsum("ij,ij->i", q[i:j], q[i + 1 : j + 1]) < 0)
                for i, j in _blocks(n)
            )
        ),
    )
    regular = dt[dt <= gap]
    del dt  # recomputed below: std's temporaries and the intervals are never held at once
    out["jitter_ms"] = float(np.std(regular) * 1e3)
    del regular
    dt = _per_interval(n, intervals)
    v = _per_interval(n, lambda i, j: np.linalg.norm(p[i + 1 : j + 1] - p[i:j], axis=1))
    v /= dt
    out["speed_m_s"] = {k: float(f(v)) for k, f in _STATS.items()}
    del v

    def angle(i: int, j: int) -> np.ndarray:
        rel = quat_rminus(q[i + 1 : j + 1], q[i:j])
        return np.degrees(np.linalg.norm(rel, axis=1))

    w = _per_interval(n, angle)
    w /= dt
    out["angular_speed_deg_s"] = {k: float(f(w)) for k, f in _STATS.items()}
    return out


def _blocks(n: int):
    """``(i, j)`` ranges covering the ``n - 1`` intervals of ``n`` samples in blocks."""
    return ((i, min(i + _BLOCK, n - 1)) for i in range(0, n - 1, _BLOCK))


def _per_interval(n: int, f: Callable[[int, int], np.ndarray]) -> np.ndarray:
    """``f(i, j)`` (the values of intervals ``i..j-1``) for all ``n - 1`` intervals, (N - 1,),
    computed in blocks so that temporaries stay small for long recordings."""
    out = np.empty(n - 1)
    for i, j in _blocks(n):
        out[i:j] = f(i, j)
    return out


_BLOCK = 1 << 16
# statistics of scratch arrays: median and percentile may partition them in place (no copies)
_STATS = {
    "median": lambda x: np.median(x, overwrite_input=True),
    "p95": lambda x: np.percentile(x, 95, overwrite_input=True),
    "max": np.max,
}


def shift_stream(stream: PoseStream, offset_s: float) -> PoseStream:
    """Add ``offset_s`` seconds to every timestamp (a constant latency correction)."""
    if not np.isfinite(offset_s):
        raise InputError(f"offset must be finite, got {offset_s}")
    off = round(offset_s * 1e9)  # exact Python integer: no wrap-around
    if len(stream):
        lo, hi = int(stream.t_ns[0]) + off, int(stream.t_ns[-1]) + off
        if lo < -(2**63) or hi > 2**63 - 1:
            raise InputError(
                f"offset {offset_s:g} s moves the timestamps out of the int64 nanosecond range "
                f"(about +-292 years from 1970); first sample at {int(stream.t_ns[0]) * 1e-9:.9g} s"
            )
    return stream.with_(t_ns=stream.t_ns + np.int64(off))


def scale_covariance(stream: PoseStream, factor: float) -> PoseStream:
    """Multiply every covariance by ``factor`` (> 0); errors ``(dt, dtheta)`` scale by its root.

    Perturbation model unchanged: ``t_true = t + dt``, ``R_true = R Exp(dtheta)``.
    """
    if not np.isfinite(factor) or factor <= 0:
        raise InputError(f"covariance scale factor must be positive, got {factor}")
    if stream.covariance is None:
        raise InputError("the recording carries no covariance to scale")
    return stream.with_(covariance=stream.covariance * factor)


def invert_stream(stream: PoseStream) -> PoseStream:
    """``T_a_b`` -> ``T_b_a`` for every sample, covariances propagated to first order.

    ``C_inv = J C J^T`` with ``J = J_inv_pose`` of :meth:`UncertainPose.inverse`, in the
    convention ``t_true = t + dt``, ``R_true = R Exp(dtheta)``.
    """
    if stream.covariance is None:
        inv = Pose(stream.position, stream.quaternion).inverse()
        return PoseStream.from_poses(stream.target, stream.source, stream.t_ns, inv,
                                     stream.confidence, stream.flags)  # fmt: skip
    inv = stream.uncertain_poses.inverse()
    return PoseStream.from_poses(stream.target, stream.source, stream.t_ns, inv,
                                 stream.confidence, stream.flags)  # fmt: skip


def infer_streams(
    a: PoseStream,
    b: PoseStream,
    method: str = "filter",
    predictor_a: KalmanPredictor | None = None,
    predictor_b: KalmanPredictor | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> PoseStream:
    """Chain ``T_x_y`` (``a``) and ``T_y_z`` (``b``) into ``T_x_z``, time-aligned.

    ``progress(done, total)``, if given, is called as the filters advance (``total`` counts
    every measurement and query of both recordings).

    ``method="filter"`` (default): each recording runs through a pose Kalman filter and a
    Rauch-Tung-Striebel smoother over the whole recording (:func:`trackflow.filters.smooth_filter`;
    motion model and measurement noise from ``predictor_a`` / ``predictor_b``, default
    :func:`default_predictor` of that recording; a recording's own covariances are used when it
    has them). Both are queried at the union of the two recordings' timestamps inside their
    common time span (a query between two states is one smoothing step from the filtered state
    before it to the smoothed state after it), so each relation is estimated at the other's
    times from all its measurements.
    ``method="interpolate"``: ``b`` is interpolated to ``a``'s times (linear position, slerp,
    covariances interpolated) and ``a`` is taken as measured.

    Query times inside a gap (interval longer than :func:`default_gap`) of either recording
    are dropped. Covariances compose to first order, ``C = J_a C_a J_a^T + J_b C_b J_b^T`` (the
    two recordings independent; errors ``t_true = t + dt``, ``R_true = R Exp(dtheta)``); with
    ``"interpolate"`` a missing covariance counts as zero.

    Returns
    -------
    PoseStream
        ``T_x_z`` with covariances.
    """
    if a.target != b.source:
        raise InputError(
            f"cannot chain T_{a.source}_{a.target} with T_{b.source}_{b.target}: "
            f"{a.target!r} != {b.source!r}"
        )
    if len(a) < 4 or len(b) < 4:
        raise InputError("each recording needs at least four samples")
    if method == "interpolate":
        return _infer_interpolated(a, b)
    if method != "filter":
        raise InputError(f"unknown method {method!r}; use 'filter' or 'interpolate'")
    t0 = min(int(a.t_ns[0]), int(b.t_ns[0]))
    tq = np.union1d(a.t_ns, b.t_ns)
    keep = _inside(tq, a.t_ns) & _inside(tq, b.t_ns)
    if not np.any(keep):
        raise InputError("the recordings do not overlap in time")
    tq = tq[keep]
    ts = (tq - t0).astype(float) * 1e-9
    total = len(a) + len(b) + 2 * len(ts)
    ua = _filtered_at(a, predictor_a, t0, ts, progress, 0, total)
    ub = _filtered_at(b, predictor_b, t0, ts, progress, len(a) + len(ts), total)
    return PoseStream.from_poses(a.source, b.target, tq, ua.compose(ub))


def _inside(tq: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Query times (ns) within ``t``'s span and not inside one of its gaps."""
    ts = (t - t[0]).astype(float) * 1e-9
    gap = default_gap(ts)
    j = np.clip(np.searchsorted(t, tq, side="right") - 1, 0, len(t) - 2)
    return (tq >= t[0]) & (tq <= t[-1]) & ((t[j + 1] - t[j]).astype(float) * 1e-9 <= gap)


def _filtered_at(
    s: PoseStream, predictor, t0: int, ts: np.ndarray, progress=None, done: int = 0, total: int = 0
) -> UncertainPose:
    """Filter and smooth ``s`` and query it at ``ts`` [s from t0]."""
    t = (s.t_ns - t0).astype(float) * 1e-9
    p, q = np.asarray(s.position, float), np.asarray(s.quaternion, float)
    pred = predictor if predictor is not None else default_predictor(t, p, q)
    meas = s.uncertain_poses if s.covariance is not None else pred.measurements(p, q)
    if progress is not None:
        progress(done, total)
    out = smooth_filter(t, meas, pred.model, ts, gate_probability=pred.gate_probability)
    if progress is not None:
        progress(done + len(t) + len(ts), total)
    return out


def _infer_interpolated(a: PoseStream, b: PoseStream) -> PoseStream:
    tb = b.t_ns
    ta = a.t_ns
    keep = _inside(ta, tb)
    if not np.any(keep):
        raise InputError("the recordings do not overlap in time")
    j = np.clip(np.searchsorted(tb, ta, side="right") - 1, 0, len(b) - 2)
    j, tak = j[keep], ta[keep]
    s = (tak - tb[j]).astype(float) / (tb[j + 1] - tb[j]).astype(float)
    ub = _uncertain(b)
    bi = ub[j].interpolate(ub[j + 1], s)
    ua = _uncertain(a)[keep]
    return PoseStream.from_poses(a.source, b.target, tak, ua.compose(bi))


def _uncertain(s: PoseStream) -> UncertainPose:
    if s.covariance is not None:
        return s.uncertain_poses
    return UncertainPose(Pose(s.position, s.quaternion), np.zeros((len(s), 6, 6)))
