"""Prediction error statistics: average and RMS of position [mm] and orientation [deg] errors."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..math import quat_angle, quat_conjugate, quat_multiply

__all__ = ["ErrorStats", "earth_frame_errors", "pose_errors", "error_stats"]


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


def earth_frame_errors(q_est, q_ref, mask=None) -> dict:
    """Orientation errors split like the BROAD benchmark (Laidig et al., 2021), in degrees.

    The error rotation in the earth frame is ``q_e = q_est q_ref^*`` (both ``R_earth_sensor``,
    z up). Its angle is the total error; the part about the vertical axis is the heading
    error, ``2 atan(|q_e,z| / |q_e,w|)``; the rest is the inclination error,
    ``2 acos(sqrt(q_e,w^2 + q_e,z^2))``. Estimators without a magnetometer (6D) cannot know
    heading, so their figure of merit is the inclination error.

    Parameters
    ----------
    q_est, q_ref : array_like (N, 4)
        ``(x, y, z, w)``; rows where either is not finite are skipped.
    mask : array_like of bool (N,), optional
        Samples to score (BROAD's ``movement``).

    Returns
    -------
    dict
        ``total_rmse_deg``, ``heading_rmse_deg``, ``inclination_rmse_deg``, ``n``.
    """
    a = np.asarray(q_est, dtype=float)
    b = np.asarray(q_ref, dtype=float)
    ok = np.all(np.isfinite(b), axis=1) & np.all(np.isfinite(a), axis=1)
    if mask is not None:
        ok &= np.asarray(mask, dtype=bool).reshape(-1)
    a = a[ok] / np.linalg.norm(a[ok], axis=1, keepdims=True)
    b = b[ok] / np.linalg.norm(b[ok], axis=1, keepdims=True)
    e = quat_multiply(a, quat_conjugate(b))
    w, z = np.abs(e[:, 3]), e[:, 2]
    total = 2.0 * np.arccos(np.clip(w, 0.0, 1.0))
    heading = 2.0 * np.arctan2(np.abs(z), w)
    incl = 2.0 * np.arccos(np.clip(np.sqrt(w**2 + z**2), 0.0, 1.0))

    def rms(v):
        return float(np.degrees(np.sqrt(np.mean(v**2)))) if v.size else float("nan")

    return {
        "total_rmse_deg": rms(total),
        "heading_rmse_deg": rms(heading),
        "inclination_rmse_deg": rms(incl),
        "n": int(ok.sum()),
    }
