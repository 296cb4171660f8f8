"""Sensor noise (thesis 6.1.5, 10.3.7): a per-axis 6x6 covariance from a recording.

Two estimators, both in the conventions (translation error in the source frame [m], rotation
error on the right [rad]):

* ``static``: samples in segments where the body rests (smoothed speed below a threshold for
  at least ``min_segment_s``); the deviations from each segment's mean pose are pooled.
* ``innovation``: moving data, thesis-style: a pose Kalman filter (``trackflow.evaluation``'s
  tuning chooses its motion model on the recording; ``tune=False`` keeps the untuned default)
  runs over the recording; the one-step innovations ``nu`` (measurement against the prediction
  from the previous sample, in the error convention) satisfy ``E[nu nu^T] = P^- + R``, so
  ``R = mean(nu nu^T) - mean(P^-)`` with the filter's own predicted covariance ``P^-``. The
  filter is re-run with the new ``R`` until it settles (3 rounds). Samples after irregular
  intervals (gaps, jitter above 5 %) are left out.
* ``dynamic``: moving data; a local quadratic in time is fitted around every sample (a
  Savitzky-Golay window of ``2 k + 1`` samples) and the residual of the centre sample, divided
  by ``1 - h`` (the centre's leverage), estimates the white measurement noise. Motion must be
  smooth at the scale of the window (a few tens of milliseconds for 100 Hz trackers).

``trackflow.evaluation.estimate_noise`` is a different, scalar tool (one isotropic sigma per
part from second differences, the starting point of filter tuning); this module gives the full
per-axis covariance for a setup. The result can be written into a setup as the sensor's
``covariance`` (:func:`trackflow.calibration.fragment.sensor_update`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..io import PoseStream
from ..math import quat_make_continuous, quat_rminus
from ._geometry import mean_rotation

__all__ = ["NoiseResult", "sensor_noise"]


@dataclass(frozen=True)
class NoiseResult:
    """``covariance`` (6, 6), the number of samples and segments used, and the method."""

    covariance: np.ndarray
    n_samples: int
    n_segments: int
    method: str
    errors: np.ndarray | None = None  # (M, 6) the error samples pooled, for plots

    @property
    def sigma_pos_mm(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance)[:3]) * 1e3

    @property
    def sigma_ori_deg(self) -> np.ndarray:
        return np.degrees(np.sqrt(np.diag(self.covariance)[3:]))

    def as_dict(self) -> dict:
        return {
            "method": self.method,
            "sigma_pos_mm": [float(v) for v in self.sigma_pos_mm],
            "sigma_ori_deg": [float(v) for v in self.sigma_ori_deg],
            "covariance": [[float(v) for v in row] for row in self.covariance],
            "n_samples": self.n_samples,
            "n_segments": self.n_segments,
        }


def _segments(mask: np.ndarray) -> list[tuple[int, int]]:
    d = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def _static(t, p, q, max_speed, max_rate, min_segment_s):
    # speeds over +-0.25 s: long enough that the noise itself does not look like motion
    i0 = np.searchsorted(t, t - 0.25)
    i1 = np.clip(np.searchsorted(t, t + 0.25, side="right") - 1, 0, len(t) - 1)
    dt = np.maximum(t[i1] - t[i0], 1e-9)
    v = np.linalg.norm(p[i1] - p[i0], axis=1) / dt
    w = np.linalg.norm(quat_rminus(q[i1], q[i0]), axis=1) / dt
    still = (v < max_speed) & (w < max_rate)
    errs = []
    n_seg = 0
    for a, b in _segments(still):
        if t[b - 1] - t[a] < min_segment_s or b - a < 10:
            continue
        qm = mean_rotation(q[a:b])
        e = np.concatenate([p[a:b] - p[a:b].mean(axis=0), quat_rminus(q[a:b], qm)], axis=1)
        errs.append(e * np.sqrt((b - a) / (b - a - 1)))  # unbiased per segment
        n_seg += 1
    if not errs:
        raise InputError(
            f"no static segment of at least {min_segment_s} s (speed < {max_speed * 1e3:.0f} "
            f"mm/s and < {np.degrees(max_rate):.1f} deg/s): use method='dynamic'"
        )
    e = np.concatenate(errs)
    return e.T @ e / len(e), len(e), n_seg, e


def _dynamic(t, p, q, k):
    n = len(t)
    if n < 2 * k + 1 + 3:
        raise InputError(f"dynamic noise estimation needs more than {2 * k + 4} samples")
    # Local quadratic on a uniform window: leverage of the centre sample.
    u = np.arange(-k, k + 1, dtype=float)
    V = np.stack([np.ones_like(u), u, u * u], axis=1)
    H = V @ np.linalg.solve(V.T @ V, V.T)
    w_centre = H[k]  # smoothing weights for the centre
    lev = H[k, k]
    centre = np.arange(k, n - k)
    # reject windows with gaps (irregular sampling breaks the uniform-window assumption)
    dt = np.diff(t)
    med = np.median(dt)
    span = t[centre + k] - t[centre - k]
    ok = np.abs(span - 2 * k * med) < 0.5 * med
    win = centre[:, None] + np.arange(-k, k + 1)[None, :]
    rp = p[centre] - np.einsum("j,njk->nk", w_centre, p[win])
    # rotations as rotation vectors relative to the centre sample (locally linear)
    qc = q[centre]
    rel = quat_rminus(q[win], qc[:, None, :])
    rr = -np.einsum("j,njk->nk", w_centre, rel)  # centre's own rel is 0
    e = np.concatenate([rp, rr], axis=1)[ok] / np.sqrt(1.0 - lev)
    # robust: drop the largest 1 % (jumps) before the covariance
    m = np.sum((e / e.std(axis=0)) ** 2, axis=1)
    e = e[m <= np.quantile(m, 0.99)]
    return e.T @ e / len(e), len(e), 1, e


def _innovation(t, p, q, tune: bool, rounds: int = 3):
    from ..evaluation import KalmanPredictor, Trajectory, default_predictor, tune_model
    from ..math import Pose, UncertainPose

    dt = np.diff(t)
    h = float(np.median(dt))
    regular = np.abs(dt - h) <= 0.05 * h
    if regular.sum() < 50:
        raise InputError(
            f"innovation noise needs at least 50 regular sample intervals, got {regular.sum()}"
        )
    pred = default_predictor(t, p, q)
    if tune:
        recording = Trajectory.check(t, p, q)
        tuned = tune_model(recording, horizons=(h, 2 * h), ar_orders=()).predictor
        if isinstance(tuned, KalmanPredictor):
            pred = tuned
    R = pred.measurement_covariance()
    for _ in range(rounds):
        meas = UncertainPose(Pose(p, q), np.broadcast_to(R, (len(t), 6, 6)).copy())
        res = pred.run(t, meas, (h,), max_gap=3 * h, covariance=True)
        pr = res.predictions[h]
        ok = regular & (res.status[1:] == 0) & (res.status[:-1] == 0)
        e = np.concatenate(
            [p[1:] - pr.position[:-1], quat_rminus(q[1:], pr.quaternion[:-1])], axis=1
        )[ok]
        P = pr.covariance[:-1][ok]
        C = e.T @ e / len(e) - P.mean(axis=0)
        if np.any(np.diag(C) <= 0):
            raise InputError(
                "the filter's predicted covariance exceeds the spread of its innovations: its "
                "motion model does not fit this recording (use tune=True or method='dynamic')"
            )
        w, V = np.linalg.eigh(0.5 * (C + C.T))
        R = (V * np.maximum(w, 1e-14)) @ V.T  # keep it positive definite
    return R, len(e), 1, e


def sensor_noise(
    stream: PoseStream,
    method: str = "static",
    *,
    max_speed: float = 0.005,
    max_rate_deg: float = 1.0,
    min_segment_s: float = 1.0,
    half_window: int = 3,
    tune: bool = True,
) -> NoiseResult:
    """6x6 measurement-noise covariance of ``stream`` (see the module docstring).

    Parameters
    ----------
    method : {"static", "dynamic", "innovation"}
    max_speed, max_rate_deg : float
        Static segments: smoothed speed [m/s] and angular speed [deg/s] limits.
    min_segment_s : float
        Shortest static segment used [s].
    half_window : int
        Dynamic: the local quadratic spans ``2 half_window + 1`` samples.
    tune : bool
        Innovation: tune the filter's motion model on the recording first.
    """
    t = (np.asarray(stream.t_ns, np.int64) - int(stream.t_ns[0])) * 1e-9
    p = np.asarray(stream.position, float)
    q = quat_make_continuous(np.asarray(stream.quaternion, float))
    if method == "static":
        C, n, seg, e = _static(t, p, q, max_speed, np.radians(max_rate_deg), min_segment_s)
    elif method == "dynamic":
        C, n, seg, e = _dynamic(t, p, q, int(half_window))
    elif method == "innovation":
        C, n, seg, e = _innovation(t, p, q, tune)
    else:
        raise InputError(f"method must be 'static', 'dynamic' or 'innovation', got {method!r}")
    return NoiseResult(0.5 * (C + C.T), n, seg, method, e)
