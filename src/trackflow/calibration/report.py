"""Calibration reports: ``report.json`` plus PNG residual plots in a directory."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..optional import pyplot

__all__ = ["plot_residuals", "write_clock_report", "write_hand_eye_report", "write_json"]


def _pyplot():
    return pyplot("calibration plots")


def plot_residuals(path, t, residuals, inliers, title: str, xlabel: str = "time [s]") -> None:
    """Position [mm] and rotation [deg] residual norms over time; outliers in grey.

    ``t`` (M,) seconds, ``residuals`` (M, 6) as ``(dp [m], dtheta [rad])``, ``inliers`` (M,).
    """
    plt = _pyplot()
    t = np.asarray(t, float) - float(np.min(t))
    dp = np.linalg.norm(residuals[:, :3], axis=1) * 1e3
    da = np.degrees(np.linalg.norm(residuals[:, 3:], axis=1))
    fig, ax = plt.subplots(2, 1, figsize=(8, 4.5), sharex=True)
    for a, y, lab in ((ax[0], dp, "position residual [mm]"), (ax[1], da, "rotation [deg]")):
        a.plot(t[inliers], y[inliers], ".", ms=2, label="inliers")
        if (~inliers).any():
            a.plot(t[~inliers], y[~inliers], ".", ms=2, color="0.6", label="rejected")
        a.set_ylabel(lab)
        hi = np.nanpercentile(y[inliers], 99.5) if inliers.any() else 1.0
        a.set_ylim(0, 1.5 * hi if hi > 0 else 1.0)
        a.grid(alpha=0.3)
    ax[0].legend(loc="upper right", fontsize=8)
    ax[1].set_xlabel(xlabel)
    ax[0].set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_json(directory, data: dict) -> Path:
    """``report.json`` in ``directory`` (created)."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    (d / "report.json").write_text(json.dumps(data, indent=2))
    return d


def write_clock_report(directory, result) -> Path:
    """``report.json`` and ``correlation.png`` for a :class:`StreamClockOffset`."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    (d / "report.json").write_text(json.dumps(result.as_dict(), indent=2))
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 3))
    ax.plot(result.lags_s, result.correlation)
    ax.axvline(result.offset_s, color="C3", ls="--", label=f"offset {result.offset_s:.4f} s")
    ax.set_xlabel("offset [s]")
    ax.set_ylabel(f"{result.signal} speed correlation")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(d / "correlation.png", dpi=110)
    plt.close(fig)
    return d


def write_hand_eye_report(directory, result) -> Path:
    """``report.json`` (the ``--json`` keys plus the form and counts) and ``residuals.png``."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    out = result.to_json()
    out.update(form=result.form, n_used=result.n_used, n_outliers=result.n_outliers,
               n_pairs=result.n_pairs, n_pair_outliers=result.n_pair_outliers,
               drift=result.drift, drift_sigma=result.drift_sigma)  # fmt: skip
    (d / "report.json").write_text(json.dumps(out, indent=2))
    plot_residuals(
        d / "residuals.png",
        result.times_s,
        result.residuals,
        result.inliers,
        f"{result.form}: {result.residual_pos_mm:.2f} mm, {result.residual_ori_deg:.3f} deg RMS",
    )
    return d
