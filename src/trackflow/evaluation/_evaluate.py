"""Prediction-error evaluation (thesis section 9.2.1, tables 9.2-9.5)."""

from __future__ import annotations

from dataclasses import dataclass, field

from ._baselines import LinearPredictor, NoPredictor
from ._metrics import ErrorStats, error_stats, pose_errors
from ._prediction import Predictor, positive_horizons, predict_kalman
from ._trajectory import Trajectory

__all__ = ["PREDICTORS", "PredictionReport", "evaluate_predictors"]

PREDICTORS = ("kalman", "linear", "none")


@dataclass
class PredictionReport:
    """Prediction errors per predictor and horizon (thesis tables 9.2-9.5).

    ``stats[predictor][horizon_ms]`` is an :class:`ErrorStats`; predictors are ``kalman``,
    ``linear`` (extrapolation from the last two samples) and ``none`` (last measurement).
    """

    scored_from_s: float
    horizons_ms: tuple[int, ...]
    stats: dict
    predictor: object
    n_samples: int
    n_gaps: int
    gap_s: float
    n_gated: int
    tuning: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        """JSON-ready dictionary; horizon keys are strings in milliseconds."""
        return {
            "scored_from_s": self.scored_from_s,
            "predictors": {
                name: {str(h): s.as_dict() for h, s in per.items()}
                for name, per in self.stats.items()
            },
            "motion_model": self.predictor.as_dict(),
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
    recording: Trajectory,
    predictor: Predictor,
    horizons=(0.01, 0.02, 0.05, 0.1, 0.2),
    scored_from: float | None = None,
) -> PredictionReport:
    """Score the Kalman, linear and no-prediction predictors on one recording.

    For every sample ``k`` (with ``t[k] >= scored_from``) each predictor predicts the pose at
    ``t[k] + h`` from samples ``0..k``; the target is the recording interpolated there (linear
    position, slerp orientation). Samples whose window ``[t[k-1], t[k] + h]`` contains a gap
    (an interval longer than ``recording.gap_s``) are skipped (``n`` in the result says how
    many were scored). The Kalman filter (``predictor``) runs over the whole recording, so it
    is warmed up when scoring starts, and restarts after gaps.

    Parameters
    ----------
    recording : Trajectory
        The checked recording ``T_a_b``.
    predictor : Predictor
        The filter scored as ``kalman`` (e.g. a :class:`KalmanPredictor`).
    horizons : sequence of float
        Horizons [s]; reported in whole milliseconds.
    scored_from : float, optional
        First scored time [s]; default the first sample.

    Returns
    -------
    PredictionReport
    """
    r = recording
    h = positive_horizons(horizons)
    start = float(r.t[0]) if scored_from is None else float(scored_from)
    runs = {"kalman": predict_kalman(r, predictor, h), "linear": LinearPredictor().predict(r, h),
            "none": NoPredictor().predict(r, h)}  # fmt: skip
    h_ms = tuple(int(round(v * 1e3)) for v in h)
    stats: dict[str, dict[int, ErrorStats]] = {name: {} for name in PREDICTORS}
    for i, (hs, hm) in enumerate(zip(h, h_ms)):
        mask = r.scored(hs) & (r.t >= start)
        tp, tq = r.target(hs)
        for name, run in runs.items():
            pp, pq = run.position[i], run.quaternion[i]
            e_p, e_q = pose_errors(pp[mask], pq[mask], tp[mask], tq[mask])
            stats[name][hm] = error_stats(e_p, e_q)
    return PredictionReport(
        scored_from_s=start,
        horizons_ms=h_ms,
        stats=stats,
        predictor=predictor,
        n_samples=len(r),
        n_gaps=r.n_gaps,
        gap_s=r.gap_s,
        n_gated=runs["kalman"].n_gated,
    )
