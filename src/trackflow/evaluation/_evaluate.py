"""Prediction-error evaluation (thesis section 9.2.1, tables 9.2-9.5)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ._baselines import predict_linear, predict_none
from ._kalman import run_predictor_orientation, run_predictor_position
from ._metrics import ErrorStats, error_stats, pose_errors
from ._model import PredictionModel
from ._targets import default_gap, interpolate_poses, scored_mask

__all__ = ["PREDICTORS", "PredictionReport", "predict_kalman", "evaluate_predictors"]

PREDICTORS = ("kalman", "linear", "none")


def _as_arrays(t, position, quaternion):
    t = np.ascontiguousarray(t, dtype=float).reshape(-1)
    p = np.ascontiguousarray(position, dtype=float)
    q = np.ascontiguousarray(quaternion, dtype=float)
    if p.shape != (t.shape[0], 3) or q.shape != (t.shape[0], 4):
        raise ValueError(
            f"need times (N,), positions (N, 3), quaternions (N, 4); got {t.shape}, {p.shape}, "
            f"{q.shape}"
        )
    if t.shape[0] < 4:
        raise ValueError(f"need at least 4 samples, got {t.shape[0]}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
        raise ValueError("times, positions and quaternions must be finite (clean the recording)")
    if np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise ValueError(f"times must increase strictly (sample {k}: {t[k]} after {t[k - 1]})")
    return t, p, q


def predict_kalman(
    t, position, quaternion, model: PredictionModel, horizons, gap_s: float | None = None
) -> tuple[np.ndarray, np.ndarray, int]:
    """Kalman-filter predictions ``horizons`` ahead of every sample.

    Parameters
    ----------
    t : array_like, shape (N,)
        Strictly increasing times [s].
    position, quaternion : array_like, shape (N, 3) and (N, 4)
        Measured ``T_a_b`` [m], ``(x, y, z, w)``.
    model : PredictionModel
    horizons : sequence of float, length H
        Horizons [s].
    gap_s : float, optional
        The filter restarts after a larger sample interval; default :func:`default_gap`.

    Returns
    -------
    position : ndarray, shape (H, N, 3)
    quaternion : ndarray, shape (H, N, 4)
    n_inflated : int
        Measurements down-weighted by the outlier gate (position plus orientation).
    """
    t, p, q = _as_arrays(t, position, quaternion)
    h = np.ascontiguousarray(horizons, dtype=float).reshape(-1)
    gap = default_gap(t) if gap_s is None else float(gap_s)
    pp, n1 = run_predictor_position(
        t, p, model.n_dp, model.position_levels(), model.pos_sigma, model.gate, gap, h
    )
    pq, n2 = run_predictor_orientation(
        t, q, model.n_do, model.orientation_levels(), model.ori_sigma, model.gate, gap, h
    )
    return pp, pq, int(n1 + n2)


@dataclass
class PredictionReport:
    """Prediction errors per predictor and horizon (thesis tables 9.2-9.5).

    ``stats[predictor][horizon_ms]`` is an :class:`ErrorStats`; predictors are ``kalman``,
    ``linear`` (extrapolation from the last two samples) and ``none`` (last measurement).
    """

    scored_from_s: float
    horizons_ms: tuple[int, ...]
    stats: dict
    model: PredictionModel
    n_samples: int
    n_gaps: int
    gap_s: float
    n_gated: int
    tuning: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready dictionary; horizon keys are strings in milliseconds."""
        return {
            "scored_from_s": self.scored_from_s,
            "predictors": {
                name: {str(h): s.as_dict() for h, s in per.items()}
                for name, per in self.stats.items()
            },
            "motion_model": self.model.as_dict(),
            "n_samples": self.n_samples,
            "n_gaps": self.n_gaps,
            "gap_s": self.gap_s,
            "n_gated": self.n_gated,
            "tuning": self.tuning,
        }

    def table(self) -> str:
        """Plain-text tables like the thesis's: position [mm] and orientation [deg]."""
        lines = []
        for title, avg, rms in (
            ("position error (mm)", "pos_avg_mm", "pos_rms_mm"),
            ("orientation error (deg)", "ori_avg_deg", "ori_rms_deg"),
        ):
            head = f"{title:<24}" + "".join(f"{str(h) + ' ms':>16}" for h in self.horizons_ms)
            lines.append(head)
            lines.append(f"{'':<24}" + "".join(f"{'avg':>8}{'rms':>8}" for _ in self.horizons_ms))
            for name, per in self.stats.items():
                row = f"{name:<24}"
                for h in self.horizons_ms:
                    s = per[h]
                    row += f"{getattr(s, avg):8.3g}{getattr(s, rms):8.3g}"
                lines.append(row)
            lines.append("")
        n = ", ".join(f"{h} ms: {self.stats['none'][h].n}" for h in self.horizons_ms)
        lines.append(f"scored from t = {self.scored_from_s:.3f} s; samples scored per horizon: {n}")
        lines.append(f"gaps > {self.gap_s * 1e3:.1f} ms skipped: {self.n_gaps}")
        return "\n".join(lines)


def evaluate_predictors(
    t,
    position,
    quaternion,
    model: PredictionModel,
    horizons=(0.01, 0.02, 0.05, 0.1, 0.2),
    scored_from: float | None = None,
    gap_s: float | None = None,
) -> PredictionReport:
    """Score the Kalman, linear and no-prediction predictors on one recording.

    For every sample ``k`` (with ``t[k] >= scored_from``) each predictor predicts the pose at
    ``t[k] + h`` from samples ``0..k``; the target is the recording interpolated there (linear
    position, slerp orientation). Samples whose window ``[t[k-1], t[k] + h]`` contains a gap
    longer than ``gap_s`` are skipped (``n`` in the result says how many were scored). The
    Kalman filter runs over the whole recording so it is warmed up when scoring starts.

    Parameters
    ----------
    t, position, quaternion : array_like, shapes (N,), (N, 3), (N, 4)
        The recording ``T_a_b``: times [s], positions [m], quaternions ``(x, y, z, w)``.
    model : PredictionModel
    horizons : sequence of float
        Horizons [s]; reported in whole milliseconds.
    scored_from : float, optional
        First scored time [s]; default the first sample.
    gap_s : float, optional
        Default :func:`default_gap`.

    Returns
    -------
    PredictionReport
    """
    t, p, q = _as_arrays(t, position, quaternion)
    h = np.asarray(horizons, dtype=float).reshape(-1)
    if h.size == 0 or np.any(~np.isfinite(h)) or np.any(h <= 0):
        raise ValueError(f"horizons must be positive seconds, got {h.tolist()}")
    gap = default_gap(t) if gap_s is None else float(gap_s)
    start = float(t[0]) if scored_from is None else float(scored_from)
    kp, kq, n_gated = predict_kalman(t, p, q, model, h, gap)
    h_ms = tuple(int(round(v * 1e3)) for v in h)
    stats: dict[str, dict[int, ErrorStats]] = {name: {} for name in PREDICTORS}
    for i, (hs, hm) in enumerate(zip(h, h_ms)):
        mask = scored_mask(t, hs, gap) & (t >= start)
        tp, tq = interpolate_poses(t, p, q, t + hs)
        preds = {
            "kalman": (kp[i], kq[i]),
            "linear": predict_linear(t, p, q, hs),
            "none": predict_none(t, p, q, hs),
        }
        for name, (pp, pq) in preds.items():
            e_p, e_q = pose_errors(pp[mask], pq[mask], tp[mask], tq[mask])
            stats[name][hm] = error_stats(e_p, e_q)
    return PredictionReport(
        scored_from_s=start,
        horizons_ms=h_ms,
        stats=stats,
        model=model,
        n_samples=int(t.shape[0]),
        n_gaps=int(np.count_nonzero(np.diff(t) > gap)),
        gap_s=gap,
        n_gated=n_gated,
    )
