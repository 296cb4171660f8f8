"""Orientation from the IMU alone on BROAD: trackflow against ``vqf`` and ``imufusion``.

The four undisturbed BROAD trials in ``../shared/data/broad`` (slow/fast rotation, slow/fast
translation; IMU and OptiTrack on one clock at 285.714 Hz) are run through

* trackflow's :func:`~trackflow.filters.run_imu_orientation` (error-state EKF with bounded
  velocity and position),
* ``vqf`` (Laidig and Seel's VQF, ``updateBatch``; ``quat6D``/``quat9D``),
* ``imufusion`` (x-io's Fusion AHRS with its gyro ``Bias`` module, ENU convention, the
  README's rejection settings),

each in 6D (gyro + accelerometer) and 9D (+ magnetometer). Errors follow BROAD's definition
(Laidig et al., Data 6(7), 2021; :func:`~trackflow.filters.heading_inclination_errors`): the
error rotation ``q_est q_ref^-1`` in the earth frame, its total angle, its heading part (about
the vertical) and its inclination part, RMSE in degrees over the trial's ``movement``
samples. 6D methods are scored by inclination (their heading is arbitrary), 9D ones by the
total error (BROAD's headline figure).

Tuning, the same for every method: leave one trial out. Each trial is scored with the
parameters (from a small grid per method, below) that have the lowest mean error on the three
other trials; no trial is scored with parameters tuned on it. The ratio is trackflow's mean
over the four trials against the best peer's. ``tagp`` is BROAD's own in-sample figure (one
common parameter chosen on all trials). Usage:
``python bench/imu_orientation.py [--json] [--plot PNG]``.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from trackflow.filters import ImuOrientationModel, heading_inclination_errors, run_imu_orientation
from trackflow.io import read_imu

ROOT = Path(__file__).resolve().parents[1]
TRIALS = (
    "01_undisturbed_slow_rotation_A",
    "06_undisturbed_fast_rotation_A",
    "10_undisturbed_slow_translation_A",
    "15_undisturbed_fast_translation_A",
)
METHODS = ("trackflow", "vqf", "imufusion")


def broad_dir() -> Path:
    """``$TRACKFLOW_DATA/broad``, else ``../shared/data/broad`` next to the repository."""
    env = os.environ.get("TRACKFLOW_DATA")
    for base in ([Path(env)] if env else []) + [ROOT.parent / "shared" / "data",
                                                 Path("/work/shared/data")]:  # fmt: skip
        if (base / "broad").is_dir():
            return base / "broad"
    raise SystemExit("BROAD trials not found (set TRACKFLOW_DATA to the shared data folder)")


def load_trial(name: str) -> dict:
    """IMU (trackflow's reader), reference ``R_w_s`` as ``(x, y, z, w)`` and movement mask."""
    from scipy.io import loadmat

    path = broad_dir() / f"{name}.mat"
    imu, _ = read_imu(path)
    m = loadmat(path)
    return {
        "t": (imu.t_ns - imu.t_ns[0]) * 1e-9,
        "rate": float(m["sampling_rate"].item()),
        "gyro": imu.gyro,
        "accel": imu.accel,
        "mag": imu.mag,
        "q_ref": m["opt_quat"][:, [1, 2, 3, 0]],
        "movement": m["movement"].ravel().astype(bool),
    }


def broad_rmse(q_est, q_ref, movement) -> dict:
    """BROAD's RMSEs [deg] over the movement samples (``nan`` reference rows skipped)."""
    ok = movement & np.isfinite(q_ref).all(axis=1)
    head, incl, total = heading_inclination_errors(q_est[ok], q_ref[ok])
    rms = lambda e: float(np.degrees(np.sqrt(np.mean(e**2))))  # noqa: E731
    return {"total": rms(total), "heading": rms(head), "inclination": rms(incl)}


# -- the three estimators: (trial, 9D?, parameters) -> R_w_s (M, 4) (x, y, z, w) -------------
def run_trackflow(d: dict, nine: bool, par: tuple) -> np.ndarray:
    gyro_noise, velocity_sigma, *rest = par
    kw = {"heading_sigma": rest[0]} if nine else {}
    model = ImuOrientationModel(gyro_noise=gyro_noise, velocity_sigma=velocity_sigma, **kw)
    mag = d["mag"] if nine else None
    return run_imu_orientation(d["t"], d["gyro"], d["accel"], mag, model).quaternions


def run_vqf(d: dict, nine: bool, par: tuple) -> np.ndarray:
    from vqf import VQF

    tau_acc, *rest = par
    v = VQF(1.0 / d["rate"], tauAcc=tau_acc, **({"tauMag": rest[0]} if nine else {}))
    out = v.updateBatch(d["gyro"], d["accel"], d["mag"])
    return out["quat9D" if nine else "quat6D"][:, [1, 2, 3, 0]]


def run_imufusion(d: dict, nine: bool, par: tuple) -> np.ndarray:
    import imufusion

    acc_rejection, gain = par
    s = imufusion.AhrsSettings()
    s.convention = imufusion.CONVENTION_ENU
    s.sample_rate = d["rate"]
    s.gain = gain
    s.gyroscope_range = 2000.0
    s.acceleration_rejection = acc_rejection
    s.magnetic_rejection = 10.0
    s.rejection_timeout = int(5 * d["rate"])
    ahrs = imufusion.Ahrs()
    ahrs.set_settings(s)
    bs = imufusion.BiasSettings()
    bs.sample_rate = d["rate"]
    bias = imufusion.Bias()
    bias.set_settings(bs)
    g_deg = np.degrees(d["gyro"])
    a_g = d["accel"] / 9.81
    mag = d["mag"]
    out = np.empty((g_deg.shape[0], 4))
    for i in range(g_deg.shape[0]):
        w = bias.update(g_deg[i])
        if nine:
            ahrs.update(w, a_g[i], mag[i])
        else:
            ahrs.update_no_magnetometer(w, a_g[i])
        out[i] = ahrs.get_quaternion()
    return out[:, [1, 2, 3, 0]]


RUNNERS = {"trackflow": run_trackflow, "vqf": run_vqf, "imufusion": run_imufusion}
# Grids: the 6D parameters, then the 9D grid built from a chosen 6D parameter tuple
# (magnetometer time constant or noise on top of it; imufusion re-tunes its one gain).
GRIDS_6D = {
    "trackflow": [(gn, vs) for gn in (4e-3, 6e-3, 1e-2) for vs in (0.1, 0.25, 0.5)],
    "vqf": [(ta,) for ta in (1.0, 2.0, 3.0, 4.5, 6.0, 10.0)],
    "imufusion": [(rej, g) for rej in (5.0, 10.0, 20.0) for g in (0.1, 0.25, 0.5, 1.0)],
}
GRIDS_9D = {
    "trackflow": lambda p6: [p6 + (hs,) for hs in (0.3, 0.5, 1.0, 2.0)],
    "vqf": lambda p6: [p6 + (tm,) for tm in (3.0, 9.0, 15.0, 30.0)],
    "imufusion": lambda p6: [(p6[0], g) for g in (0.1, 0.25, 0.5, 1.0)],
}
METRIC = {"6D": "inclination", "9D": "total"}


class _Table:
    """RMSE dicts per (method, 9D?, parameters, trial), computed once on first use."""

    def __init__(self, data: dict):
        self.data, self.cache, self.seconds = data, {}, {}

    def __call__(self, method: str, nine: bool, par: tuple, trial: str) -> dict:
        key = (method, nine, par, trial)
        if key not in self.cache:
            d = self.data[trial]
            t0 = time.perf_counter()
            q = RUNNERS[method](d, nine, par)
            self.seconds[key] = time.perf_counter() - t0
            self.cache[key] = broad_rmse(q, d["q_ref"], d["movement"])
        return self.cache[key]


def _choose(table, method, nine, grid, trials, metric) -> tuple:
    """The grid point with the lowest mean ``metric`` over ``trials`` (BROAD's TAGP rule)."""
    means = [np.mean([table(method, nine, p, n)[metric] for n in trials]) for p in grid]
    return grid[int(np.argmin(means))]


def compare(trials=TRIALS) -> dict:
    """Leave-one-trial-out comparison of the three methods, 6D and 9D.

    For every trial, each method's parameters are chosen on the *other* trials (the lowest
    mean error over them, BROAD's "trial-agnostic good parameter" rule) and the trial is
    scored with them; no trial is scored with parameters tuned on it. ``tagp`` also gives the
    in-sample figure of BROAD's paper (one common parameter chosen on all trials).

    Returns
    -------
    dict
        ``{"6D"|"9D": {method: {"trials": {trial: {"rmse", "parameter", "all": rmse dict}},
        "mean", "tagp": {"parameter", "mean"}, "seconds_per_trial"}}, "ratio_6D", "ratio_9D"}``
        with ``rmse`` the variant's metric [deg] (6D inclination, 9D total).
    """
    table = _Table({n: load_trial(n) for n in trials})
    out: dict = {}
    for variant, nine in (("6D", False), ("9D", True)):
        metric = METRIC[variant]
        res = {}
        for name in METHODS:

            def grid_for(train, name=name, nine=nine):
                if not nine:
                    return GRIDS_6D[name]
                p6 = _choose(table, name, False, GRIDS_6D[name], train, "inclination")
                return GRIDS_9D[name](p6)

            per = {}
            for n in trials:
                train = [m for m in trials if m != n]
                best = _choose(table, name, nine, grid_for(train), train, metric)
                rm = table(name, nine, best, n)
                per[n] = {"rmse": rm[metric], "parameter": list(best), "all": rm}
            tagp = _choose(table, name, nine, grid_for(list(trials)), trials, metric)
            secs = [v for k, v in table.seconds.items() if k[0] == name and k[1] == nine]
            res[name] = {
                "trials": per,
                "mean": float(np.mean([per[n]["rmse"] for n in trials])),
                "tagp": {
                    "parameter": list(tagp),
                    "mean": float(np.mean([table(name, nine, tagp, n)[metric] for n in trials])),
                },
                "seconds_per_trial": float(np.median(secs)),
            }
        out[variant] = res
        best_peer = min(res[n]["mean"] for n in METHODS if n != "trackflow")
        out[f"ratio_{variant}"] = res["trackflow"]["mean"] / best_peer
    return out


def error_over_time(trial: str, params: dict) -> dict:
    """Inclination error [deg] per sample of each method's 6D estimate on ``trial``."""
    d = load_trial(trial)
    out = {"t": d["t"], "movement": d["movement"]}
    for name in METHODS:
        q = RUNNERS[name](d, False, tuple(params[name]))
        ok = np.isfinite(d["q_ref"]).all(axis=1)
        e = np.full(d["t"].shape[0], np.nan)
        e[ok] = np.degrees(heading_inclination_errors(q[ok], d["q_ref"][ok])[1])
        out[name] = e
    return out


def plot(result: dict, path: Path, trial: str = TRIALS[3]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = error_over_time(trial, {n: result["6D"][n]["trials"][trial]["parameter"]
                                     for n in METHODS})  # fmt: skip
    fig, axes = plt.subplots(2, 1, figsize=(10, 6.5), gridspec_kw={"height_ratios": [3, 2]})
    ax = axes[0]
    t = series["t"]
    for name, colour, z in zip(METHODS, ("C0", "C2", "C1"), (3, 2, 1)):
        e = series[name]
        rms = np.sqrt(np.nanmean(e[series["movement"]] ** 2))
        ax.plot(t, e, colour, lw=0.6, zorder=z, label=f"{name} (RMSE {rms:.2f} deg)")
    ax.fill_between(t, 0, 1, where=~series["movement"], color="0.9",
                    transform=ax.get_xaxis_transform(), label="rest (not scored)")  # fmt: skip
    ax.set_ylabel("inclination error (deg)")
    ax.set_xlabel("time (s)")
    ax.set_title(f"BROAD {trial}, 6D (gyro + accelerometer), parameters tuned on the other trials")
    ax.set_ylim(0, max(3.0, float(np.nanpercentile(series["imufusion"], 99.5))))
    ax.legend(fontsize=8, loc="upper left")
    ax = axes[1]
    x = np.arange(len(TRIALS))
    width = 0.13
    labels = [n.split("_", 1)[1].replace("undisturbed_", "").replace("_A", "") for n in TRIALS]
    for i, (variant, name) in enumerate((v, n) for v in ("6D", "9D") for n in METHODS):
        vals = [result[variant][name]["trials"][n]["rmse"] for n in TRIALS]
        ax.bar(x + (i - 2.5) * width, vals, width, color=f"C{(0, 2, 1)[i % 3]}",
               alpha=1.0 if variant == "6D" else 0.5,
               label=f"{name} {variant} ({METRIC[variant]})")  # fmt: skip
    ax.set_xticks(x)
    ax.set_xticklabels(labels)
    ax.set_ylabel("RMSE (deg)")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", action="store_true", help="print the result as one JSON object")
    ap.add_argument("--plot", type=Path, help="write the figure (error over time, bars) here")
    args = ap.parse_args()
    res = compare()
    if args.plot:
        plot(res, args.plot)
    if args.json:
        print(json.dumps({
            "imu_only_6d_ratio": round(res["ratio_6D"], 4),
            "imu_only_9d_ratio": round(res["ratio_9D"], 4),
            **{f"{v}_{n}": {t: round(r["rmse"], 4) for t, r in res[v][n]["trials"].items()}
               for v in ("6D", "9D") for n in METHODS},
        }))  # fmt: skip
        return
    for v in ("6D", "9D"):
        print(f"{v}: {METRIC[v]} RMSE (deg), each trial with parameters tuned on the others")
        for n in METHODS:
            r = res[v][n]
            cells = " ".join(f"{r['trials'][t]['rmse']:6.3f}" for t in TRIALS)
            tagp = f"(TAGP {r['tagp']['mean']:.3f} at {r['tagp']['parameter']})"
            print(f"  {n:>10} {cells}  mean {r['mean']:.3f}  {tagp}  "
                  f"{r['seconds_per_trial']:.2f} s/trial")  # fmt: skip
        print(f"  ratio trackflow / best peer: {res[f'ratio_{v}']:.3f}")


if __name__ == "__main__":
    main()
