"""PNG plots of the PoseTool (thesis 9.2.1 figures): sequences over time and error vs horizon."""

from __future__ import annotations

import numpy as np

from .evaluation import KalmanPredictor, PredictionReport, predict_kalman, predict_linear
from .io import atomic_output
from .math import quat_log, quat_make_continuous

__all__ = ["plot_sequence", "plot_error_vs_horizon", "require_matplotlib", "save_figure"]


def require_matplotlib() -> None:
    """Raise ``ImportError`` naming the extra to install when matplotlib is missing."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise ImportError(
            "plots need matplotlib, which is not installed: pip install 'trackflow[plot]'"
        ) from None


def save_figure(fig, path, overwrite: bool = False, dpi: int = 110) -> None:
    """Save a matplotlib figure as PNG under the output policy (atomic, no silent overwrite)."""
    with atomic_output(path, overwrite=overwrite) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")


def _pyplot():
    require_matplotlib()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_sequence(
    path, t, position, quaternion, predictor: KalmanPredictor, horizon: float = 0.1,
    window: tuple[float, float] | None = None, title: str | None = None, overwrite: bool = False,
) -> None:  # fmt: skip
    """Position and orientation over time: measured points, Kalman-filtered and predicted
    curves, linear extrapolation, and the measurements shifted by the horizon.

    Parameters
    ----------
    path : str or Path
        Output PNG.
    t, position, quaternion : array_like, shapes (N,), (N, 3), (N, 4)
        Recording ``T_a_b`` [s, m, (x, y, z, w)].
    predictor : KalmanPredictor
        The Kalman filter (``trackflow.filters.run_filter`` settings) to draw.
    horizon : float
        Prediction horizon [s]; predictions are drawn at ``t + horizon``.
    window : (float, float), optional
        Time range [s] to draw; default the first 3 s. ``ValueError`` when it holds fewer
        than two samples.
    title : str, optional
        Figure title (e.g. the recording's name).
    overwrite : bool
        Replace an existing ``path`` (see :func:`save_figure`).

    Colours are the axes (x, y, z of the position or of the rotation vector); line styles are
    the series, explained in a second legend. Measurements are drawn as small dots under the
    curves so that the curves stay visible.
    """
    plt = _pyplot()
    t = np.asarray(t, float)
    p = np.asarray(position, float)
    q = quat_make_continuous(np.asarray(quaternion, float))
    kp, kq, _ = predict_kalman(t, p, q, predictor, (0.0, horizon))
    lp, lq = predict_linear(t, p, q, horizon)
    lo, hi = window if window is not None else (t[0], min(t[-1], t[0] + 3.0))
    m = (t >= lo) & (t <= hi)
    if np.count_nonzero(m) < 2:
        raise ValueError(
            f"the window {lo:g}..{hi:g} s holds {np.count_nonzero(m)} samples; the recording "
            f"spans {t[0]:g}..{t[-1]:g} s"
        )
    first = np.flatnonzero(m)[0]
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
            ax.plot(t[m], meas[m, a], ".", ms=2.5, color=c, alpha=0.5, zorder=1)
            ax.plot(t[m] + horizon, meas[m, a], "-", lw=0.6, alpha=0.35, color=c, zorder=2)
            ax.plot(t[m], filt[m, a], "-", lw=1.4, color=c, zorder=4)
            ax.plot(t[m] + horizon, pred[m, a], "--", lw=1.2, color=c, zorder=5)
            ax.plot(t[m] + horizon, lin[m, a], ":", lw=1.2, color=c, zorder=3)
        ax.set_ylabel(unit)
        ax.grid(alpha=0.3)
    from matplotlib.lines import Line2D

    ms = f"+{horizon * 1e3:.0f} ms"
    styles = [
        Line2D([], [], ls="", marker=".", color="k", label="measured"),
        Line2D([], [], ls="-", lw=1.4, color="k", label="Kalman filtered"),
        Line2D([], [], ls="--", lw=1.2, color="k", label=f"Kalman predicted {ms}"),
        Line2D([], [], ls=":", lw=1.2, color="k", label=f"linear extrapolation {ms}"),
        Line2D([], [], ls="-", lw=0.6, alpha=0.5, color="k", label=f"measured shifted {ms}"),
    ]
    colours = [Line2D([], [], color=c, lw=2, label=n) for c, n in zip(("C0", "C1", "C2"), "xyz")]
    leg = axes[0].legend(handles=styles, fontsize=7, ncol=3, loc="upper left", title="series")
    axes[0].add_artist(leg)
    axes[0].legend(handles=colours, fontsize=7, loc="upper right", title="axis")
    fig.suptitle(
        f"{title + ': ' if title else ''}measured, filtered and predicted ({ms}) poses, "
        f"{lo:.3g}..{hi:.3g} s"
    )
    axes[1].set_xlabel("time [s]")
    fig.tight_layout()
    try:
        save_figure(fig, path, overwrite)
    finally:
        plt.close(fig)


def plot_error_vs_horizon(
    path, report: PredictionReport, title: str | None = None, overwrite: bool = False
) -> None:
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
    fig.suptitle(f"{title + ': ' if title else ''}prediction error vs horizon")
    fig.tight_layout()
    try:
        save_figure(fig, path, overwrite)
    finally:
        plt.close(fig)
