"""PNG plots of the PoseTool (thesis 9.2.1 figures): sequences over time and error vs horizon."""

from __future__ import annotations

import numpy as np

from .evaluation import PredictionReport, Predictor, Trajectory, predict_kalman, predict_linear
from .math import quat_log, quat_make_continuous

__all__ = ["plot_sequence", "plot_error_vs_horizon"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_sequence(
    path, recording: Trajectory, predictor: Predictor, horizon: float = 0.1,
    window: tuple[float, float] | None = None,
) -> None:  # fmt: skip
    """Position and orientation over time: measured points, Kalman-filtered and predicted
    curves, linear extrapolation, and the measurements shifted by the horizon.

    Parameters
    ----------
    path : str or Path
        Output PNG.
    recording : Trajectory
        Recording ``T_a_b`` [s, m, (x, y, z, w)].
    predictor : Predictor
        The filter to draw (e.g. the tuned one of a :class:`PredictionReport`); it runs
        through the recording's gaps without restarting.
    horizon : float
        Prediction horizon [s]; predictions are drawn at ``t + horizon``.
    window : (float, float), optional
        Time range [s] to draw; default the first 3 s.
    """
    plt = _pyplot()
    t, p = recording.t, recording.position
    q = quat_make_continuous(recording.quaternion)
    kp, kq, _ = predict_kalman(Trajectory(t, p, q, np.inf), predictor, (0.0, horizon))
    lp, lq = predict_linear(t, p, q, horizon)
    lo, hi = window if window is not None else (t[0], min(t[-1], t[0] + 3.0))
    m = (t >= lo) & (t <= hi)
    first = np.flatnonzero(m)[0] if np.any(m) else 0
    ref, p0 = q[first], p[first]
    from .math import quat_conjugate, quat_multiply

    def rv(qq):
        return np.degrees(quat_log(quat_multiply(quat_conjugate(ref), qq)))

    fig, axes = plt.subplots(2, 1, figsize=(11, 7), sharex=True)
    for ax, meas, filt, pred, lin, unit in (
        (
            axes[0],
            (p - p0) * 1e3,
            (kp[0] - p0) * 1e3,
            (kp[1] - p0) * 1e3,
            (lp - p0) * 1e3,
            "position from start [mm]",
        ),
        (axes[1], rv(q), rv(kq[0]), rv(kq[1]), rv(lq), "rotation from start [deg]"),
    ):
        for a, c in zip(range(3), ("C0", "C1", "C2")):
            ax.plot(t[m], meas[m, a], "x", ms=3, color=c, label="measured" if a == 0 else None)
            ax.plot(t[m], filt[m, a], "-", lw=1, color=c, label="filtered" if a == 0 else None)
            ax.plot(t[m] + horizon, pred[m, a], "--", lw=1, color=c,
                    label=f"Kalman +{horizon * 1e3:.0f} ms" if a == 0 else None)  # fmt: skip
            ax.plot(t[m] + horizon, lin[m, a], ":", lw=1, color=c,
                    label=f"linear +{horizon * 1e3:.0f} ms" if a == 0 else None)  # fmt: skip
            ax.plot(t[m] + horizon, meas[m, a], "-", lw=0.5, alpha=0.4, color=c,
                    label="measured shifted (no prediction)" if a == 0 else None)  # fmt: skip
        ax.set_ylabel(unit)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, ncol=3)
    axes[1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_error_vs_horizon(path, report: PredictionReport) -> None:
    """RMS (solid) and average (dashed) prediction error vs horizon for every predictor."""
    plt = _pyplot()
    h = np.array(report.horizons_ms)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, avg, rms, unit in (
        (axes[0], "pos_avg_mm", "pos_rms_mm", "position error [mm]"),
        (axes[1], "ori_avg_deg", "ori_rms_deg", "orientation error [deg]"),
    ):
        for i, (name, per) in enumerate(report.stats.items()):
            c = f"C{i}"
            ax.plot(h, [getattr(per[k], rms) for k in h], "o-", color=c, label=f"{name} RMS")
            ax.plot(h, [getattr(per[k], avg) for k in h], "s--", color=c, label=f"{name} avg")
        ax.set_xlabel("horizon [ms]")
        ax.set_ylabel(unit)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
