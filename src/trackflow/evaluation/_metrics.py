"""Prediction error statistics: average and RMS of position [mm] and orientation [deg] errors."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..math import quat_angle

__all__ = ["ErrorStats", "pose_errors", "error_stats"]


@dataclass(frozen=True)
class ErrorStats:
    """Average and root-mean-square prediction errors over ``n`` scored samples."""

    pos_avg_mm: float
    pos_rms_mm: float
    ori_avg_deg: float
    ori_rms_deg: float
    n: int

    def as_dict(self) -> dict:
        return asdict(self)


def pose_errors(p_pred, q_pred, p_true, q_true) -> tuple[np.ndarray, np.ndarray]:
    """Position error norms [m] and orientation error angles [rad], shape (N,) each."""
    e_p = np.linalg.norm(np.asarray(p_pred) - np.asarray(p_true), axis=-1)
    e_q = quat_angle(np.asarray(q_pred), np.asarray(q_true))
    return e_p, e_q


def error_stats(e_pos: np.ndarray, e_ori: np.ndarray) -> ErrorStats:
    """Summarise errors (metres, radians; shape (n,)) as :class:`ErrorStats` in mm and deg."""
    n = int(e_pos.shape[0])
    if n == 0:
        nan = float("nan")
        return ErrorStats(nan, nan, nan, nan, 0)
    return ErrorStats(
        pos_avg_mm=float(np.mean(e_pos) * 1e3),
        pos_rms_mm=float(np.sqrt(np.mean(e_pos**2)) * 1e3),
        ori_avg_deg=float(np.degrees(np.mean(e_ori))),
        ori_rms_deg=float(np.degrees(np.sqrt(np.mean(e_ori**2)))),
        n=n,
    )
