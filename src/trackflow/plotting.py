"""PNG plots of the PoseTool (thesis 9.2.1 figures): sequences over time and error vs horizon."""

from __future__ import annotations

import numpy as np

from .errors import InputError
from .evaluation import PredictionReport, Predictor, Trajectory, predict_kalman, predict_linear
from .io import atomic_output
from .math import quat_make_continuous, quat_rminus
from .optional import pyplot, require

__all__ = ["plot_sequence", "plot_error_vs_horizon", "require_matplotlib", "save_figure"]


def require_matplotlib() -> None:
    """Raise :class:`~trackflow.errors.MissingExtraError` (an ``ImportError``) naming the
    extra to install when matplotlib is missing."""
    require("matplotlib", extra="plot", feature="plots")


def save_figure(fig, path, overwrite: bool = False, dpi: int = 110) -> None:
    """Save a matplotlib figure as PNG under the output policy (atomic, no silent overwrite)."""
    with atomic_output(path, overwrite=overwrite) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")


def _pyplot():
    return pyplot("plots")


def plot_sequence(
    path, recording: Trajectory, predictor: Predictor, horizon: float = 0.1,
    window: tuple[float, float] | None = None, title: str | None = None, overwrite: bool = False,
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
    t, p = recording.t, recording.position
    q = quat_make_continuous(recording.quaternion)
    kp, kq, _ = predict_kalman(Trajectory(t, p, q, np.inf), predictor, (0.0, horizon))
    lp, lq = predict_linear(t, p, q, horizon)
    lo, hi = window if window is not None else (t[0], min(t[-1], t[0] + 3.0))
    m = (t >= lo) & (t <= hi)
    if np.count_nonzero(m) < 2:
        raise InputError(
            f"the window {lo:g}..{hi:g} s holds {np.count_nonzero(m)} samples; the recording "
            f"spans {t[0]:g}..{t[-1]:g} s"
        )
    first = np.flatnonzero(m)[0]
    ref, p0 = q[first], p[first]

    def rv(qq):
        return np.degrees(quat_rminus(qq, ref))

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


def _series_axis(series) -> tuple[float, str]:
    """Scale and y label of an error series: metres drawn in millimetres."""
    what = {"ape": "APE", "rpe": "RPE", "axis": "APE"}[series.kind]
    rel = series.relation.replace("_", " ") + (" error" if series.kind == "axis" else "")
    if series.unit == "m":
        return 1e3, f"{what} {rel} [mm]"
    return 1.0, f"{what} {rel}" + (f" [{series.unit}]" if series.unit else "")


def plot_compare(folder, result, ref_name: str = "reference", est_name: str = "estimate",
                 overwrite: bool = False) -> list:  # fmt: skip
    """Two PNGs of a :class:`trackflow.evaluation.CompareResult` in ``folder``.

    ``<est>_vs_<ref>_errors.png``: every APE and RPE metric over time (one panel each; the APE
    translation with its per-axis errors), each with its RMSE. ``<est>_vs_<ref>_trajectories.png``:
    both associated trajectories from above (x-y) and from the side (x-z), the estimate after
    alignment. Returns the two paths.
    """
    from pathlib import Path

    plt = _pyplot()
    folder = Path(folder)
    stem = f"{est_name}_vs_{ref_name}"
    paths = [folder / f"{stem}_errors.png", folder / f"{stem}_trajectories.png"]
    r = result
    panels = [s for s in r.series.values() if s.kind in ("ape", "rpe")]
    fig, axes = plt.subplots(len(panels), 1, figsize=(11, 2.7 * len(panels)), sharex=True,
                             squeeze=False)  # fmt: skip
    axes = axes[:, 0]
    s = r.settings
    step = f"delta {s.get('delta', 1):g} {s.get('delta_unit', 'f')}"
    for ax, series in zip(axes, panels):
        k, label = _series_axis(series)
        e = series.error * k
        ax.plot(series.t, e, color="k" if series.kind == "ape" else "C3", lw=1.0, label="error")
        if series.name == "ape_trans_m":
            for a, axis in enumerate("xyz"):
                ax.plot(r.t, r.ape_axes[:, a] * 1e3, lw=0.8, color=f"C{a}", label=f"{axis} error")
        ax.set_ylabel(label + (f"\n{step}" if series.kind == "rpe" else ""), fontsize=8)
        rmse = float(np.sqrt(np.mean(e**2))) if len(e) else float("nan")
        ax.axhline(rmse, color="gray", ls="--", lw=0.8, label=f"RMSE {rmse:.3g}")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right", ncol=5)
    axes[-1].set_xlabel("time since the first reference sample [s]")
    fig.suptitle(f"{est_name} vs {ref_name}: pose errors (alignment {r.alignment['method']})")
    fig.tight_layout()
    try:
        save_figure(fig, paths[0], overwrite)
    finally:
        plt.close(fig)
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    for ax, (i, j), view in zip(axes, ((0, 1), (0, 2)), ("top (x-y)", "side (x-z)")):
        ax.plot(r.ref_xyz[:, i], r.ref_xyz[:, j], "-", color="k", lw=1.2, label=ref_name)
        ax.plot(r.est_xyz[:, i], r.est_xyz[:, j], "-", color="C1", lw=1.0, label=est_name)
        ax.set_xlabel(f"{'xyz'[i]} [m]")
        ax.set_ylabel(f"{'xyz'[j]} [m]")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(view)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"{est_name} (aligned: {r.alignment['method']}) and {ref_name}")
    fig.tight_layout()
    try:
        save_figure(fig, paths[1], overwrite)
    finally:
        plt.close(fig)
    return paths


def plot_results(folder, comparison, overwrite: bool = False) -> list:
    """One PNG per metric of a :class:`trackflow.evaluation.ResultsComparison` in ``folder``,
    ``results_<metric>.png`` for each APE and RPE metric (not the per-axis ones): the errors of
    every result over time (left) and their distributions as box plots (right, whiskers at
    1.5 IQR, mean marked). Returns the paths.
    """
    from pathlib import Path

    plt = _pyplot()
    folder = Path(folder)
    paths = []
    for m in comparison.metrics:
        if comparison.results[0].series[m].kind == "axis":
            continue
        fig, (ax_t, ax_b) = plt.subplots(1, 2, figsize=(13, 4.5),
                                         gridspec_kw={"width_ratios": [2.2, 1]})  # fmt: skip
        k, label = _series_axis(comparison.results[0].series[m])
        data = []
        for c, (name, res) in enumerate(zip(comparison.names, comparison.results)):
            series = res.series[m]
            ax_t.plot(series.t, series.error * k, lw=0.9, color=f"C{c}", label=name)
            data.append(series.error * k)
        ax_t.set_xlabel("time since the first reference sample [s]")
        ax_t.set_ylabel(label)
        ax_t.grid(alpha=0.3)
        ax_t.legend(fontsize=8)
        ax_b.boxplot(data, showmeans=True)
        ax_b.set_xticks(range(1, len(data) + 1), comparison.names, rotation=20, fontsize=8)
        ax_b.set_ylabel(label)
        ax_b.grid(alpha=0.3, axis="y")
        fig.suptitle(f"{m}: {len(data)} results")
        fig.tight_layout()
        path = folder / f"results_{m}.png"
        try:
            save_figure(fig, path, overwrite)
        finally:
            plt.close(fig)
        paths.append(path)
    return paths


#: View name -> axes drawn (indices into x, y, z); ``"3d"`` draws all three.
TRAJECTORY_VIEWS = {"top": (0, 1), "side": (0, 2), "front": (1, 2), "3d": (0, 1, 2)}


def plot_trajectories(path, streams, names, views=("top", "side", "3d"),
                      overwrite: bool = False) -> None:  # fmt: skip
    """Positions of several recordings overlaid, one panel per view, start and end marked.

    Parameters
    ----------
    path : str or Path
        Output PNG.
    streams : sequence of PoseStream
        ``T_world_body`` recordings in one world frame [m].
    names : sequence of str
        Legend labels.
    views : sequence of {"top", "side", "front", "3d"}
    """
    unknown = [v for v in views if v not in TRAJECTORY_VIEWS]
    if unknown or not views:
        raise InputError(f"views must be some of {list(TRAJECTORY_VIEWS)}, got {list(views)}")
    plt = _pyplot()
    fig = plt.figure(figsize=(5.5 * len(views), 5))
    for k, view in enumerate(views):
        axes_idx = TRAJECTORY_VIEWS[view]
        ax = fig.add_subplot(1, len(views), k + 1, **({"projection": "3d"} if view == "3d" else {}))
        for c, (s, name) in enumerate(zip(streams, names)):
            p = np.asarray(s.position)
            cols = [p[:, i] for i in axes_idx]
            ax.plot(*cols, "-", lw=1.0, color=f"C{c}", label=name)
            ax.plot(*[[v[0]] for v in cols], "o", ms=4, color=f"C{c}")
            ax.plot(*[[v[-1]] for v in cols], "s", ms=4, color=f"C{c}")
        ax.set_xlabel(f"{'xyz'[axes_idx[0]]} [m]")
        ax.set_ylabel(f"{'xyz'[axes_idx[1]]} [m]")
        if view == "3d":
            ax.set_zlabel("z [m]")
        else:
            ax.set_aspect("equal", adjustable="datalim")
            ax.grid(alpha=0.3)
        ax.set_title(f"{view} view" + ("" if view == "3d" else f" ({'xyz'[axes_idx[0]]}-"
                                                             f"{'xyz'[axes_idx[1]]})"))  # fmt: skip
        if k == 0:
            ax.legend(fontsize=8, title="o start, \u25a1 end", title_fontsize=7)
    fig.suptitle("trajectories: " + ", ".join(names))
    fig.tight_layout()
    try:
        save_figure(fig, path, overwrite)
    finally:
        plt.close(fig)
