"""IMU-aided tracking: speed of the inertial filter and its accuracy against peers.

Prints, with ``--json``, exactly the keys of issue 16::

    {"broad_ori50_ratio": .., "euroc_pos50_ratio": .., "euroc_ori50_ratio": ..,
     "imu_updates_per_s": ..}

* ``imu_updates_per_s``: IMU samples per second of wall time that :func:`run_inertial` (strapdown,
  numba, one thread) processes on a synthetic 1 kHz IMU with a 240 Hz tracker (60 s of data;
  best of three runs). 1 kHz with a 240 Hz tracker in 10 % of a core needs >= 10 000.
* ``broad_ori50_ratio``: orientation RMS 50 ms ahead, ``kalman_imu`` / the best pose-only
  predictor (the tuned ``kalman``, learned models included, ``linear`` or ``none``), the worse
  of BROAD fast rotation and fast translation with the poses thinned to 60 Hz
  (``trackflow evaluate --imu --pose-rate 60 --origins anytime``).
* ``euroc_pos50_ratio``, ``euroc_ori50_ratio``: the same on EuRoC V1_01, poses at 20 Hz.

The keys use prediction origins at every full-rate sample time (``--origins anytime``: an
application asking at any moment, with the data it has then; ``docs/inertial.md``); the
``--out`` file also holds the figures with origins at the tracker's poses (``poses``).

``--peers`` also runs the IMU-only orientation comparison of ``bench/imu_orientation.py`` (the
four BROAD trials against ``imufusion`` and ``vqf``, bench extra) and adds its ratios.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

from trackflow.evaluation import ImuSamples, Trajectory, evaluate_with_imu
from trackflow.filters import run_inertial
from trackflow.io import read_imu, read_stream

ROOT = Path(__file__).resolve().parents[1]
DATA = next(
    (d for d in (Path(os.environ.get("TRACKFLOW_DATA", ROOT.parent / "shared" / "data")),
                 ROOT.parent / "shared" / "data", Path("/work/shared/data"))
     if (d / "README.md").is_file()),
    ROOT.parent / "shared" / "data",
)  # fmt: skip
BROAD = ["01_undisturbed_slow_rotation_A", "06_undisturbed_fast_rotation_A",
         "10_undisturbed_slow_translation_A", "15_undisturbed_fast_translation_A"]  # fmt: skip


def imu_updates_per_s(seconds: float = 60.0, repeats: int = 3) -> float:
    """IMU samples per wall-clock second of the strapdown filter, 1 kHz IMU + 240 Hz poses."""
    rng = np.random.default_rng(0)
    ti = np.arange(0.0, seconds, 1e-3)
    gyro = rng.normal(scale=0.5, size=(ti.shape[0], 3))
    accel = np.array([0.0, 0.0, 9.81]) + rng.normal(scale=0.5, size=(ti.shape[0], 3))
    tp = np.arange(0.0, seconds, 1 / 240)
    p = rng.normal(scale=1e-3, size=(tp.shape[0], 3))
    q = np.tile([0.0, 0.0, 0.0, 1.0], (tp.shape[0], 1))
    C = np.diag([1e-6] * 3 + [1e-4] * 3)
    run_inertial(ti[:100], gyro[:100], accel[:100], tp[:20], p[:20], q[:20], C)  # compile
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        run_inertial(ti, gyro, accel, tp, p, q, C, horizons=(0.05,))
        best = min(best, time.perf_counter() - t0)
    return ti.shape[0] / best


ORIGINS = ("anytime", "poses")
POSE_ONLY = ("kalman", "linear", "none")


def imu_vs_pose_ratios(pose_path, imu_path, rate_hz) -> dict:
    """Per origin definition: ``kalman_imu`` / best pose-only RMS at 50 ms and the report."""
    stream, _ = read_stream(pose_path, clean=True)
    imu, _ = read_imu(imu_path)
    rec = Trajectory.from_stream(stream)
    samples = ImuSamples.check((imu.t_ns - int(stream.t_ns[0])) * 1e-9, imu.gyro, imu.accel)
    out = {}
    for origins in ORIGINS:
        rep = evaluate_with_imu(rec, samples, pose_rate_hz=rate_hz, origins=origins)
        s = rep.stats
        best = {k: min(getattr(s[n][50], k) for n in POSE_ONLY)
                for k in ("pos_rms_mm", "ori_rms_deg")}  # fmt: skip
        out[origins] = {
            "pos": s["kalman_imu"][50].pos_rms_mm / best["pos_rms_mm"],
            "ori": s["kalman_imu"][50].ori_rms_deg / best["ori_rms_deg"],
            "report": rep.as_dict(),
        }
    return out


def plot_prediction(full: dict, path: Path) -> None:
    """Orientation and position RMS vs horizon, with and without the IMU, per recording."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = [("BROAD fast rotation, poses 60 Hz", full["broad_fast_rotation"]),
            ("BROAD fast translation, poses 60 Hz", full["broad_fast_translation"]),
            ("EuRoC V1_01, poses 20 Hz", full["euroc"])]  # fmt: skip
    fig, axes = plt.subplots(2, 3, figsize=(12, 6))
    colors = {"none": "tab:gray", "linear": "tab:orange", "kalman": "tab:blue",
              "kalman_imu": "tab:red"}  # fmt: skip
    for col, (title, run) in enumerate(runs):
        for row, (key, unit) in enumerate((("ori_rms_deg", "deg"), ("pos_rms_mm", "mm"))):
            ax = axes[row, col]
            for origins, style in (("anytime", "o-"), ("poses", "x--")):
                preds = run[origins]["report"]["predictors"]
                for name in ("none", "linear", "kalman", "kalman_imu"):
                    hs = sorted(preds[name], key=float)
                    ax.plot([float(h) for h in hs], [preds[name][h][key] for h in hs], style,
                            color=colors[name], alpha=1.0 if origins == "anytime" else 0.5,
                            label=f"{name} ({origins})")  # fmt: skip
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel("horizon (ms)")
            ax.set_ylabel(f"{key.split('_')[0]} RMS ({unit})")
            if row == 0:
                ax.set_title(title, fontsize=10)
            ax.grid(True, which="both", alpha=0.3)
    axes[0, 0].legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", action="store_true", help="print the issue's keys as JSON")
    ap.add_argument("--peers", action="store_true", help="IMU-only comparison with peers")
    ap.add_argument("--plot", action="store_true", help="write docs/inertial_prediction.png")
    ap.add_argument("--out", default=None, help="write the full results to this JSON file")
    args = ap.parse_args(argv)
    if not (DATA / "broad").is_dir():
        print(f"no data at {DATA}", file=sys.stderr)
        return 1
    speed = imu_updates_per_s()
    rot = imu_vs_pose_ratios(*(2 * [DATA / "broad" / f"{BROAD[1]}.mat"]), 60.0)
    tra = imu_vs_pose_ratios(*(2 * [DATA / "broad" / f"{BROAD[3]}.mat"]), 60.0)
    eu = imu_vs_pose_ratios(
        DATA / "euroc" / "V1_01_easy_groundtruth_200hz.txt",
        DATA / "euroc" / "V1_01_easy_imu0.csv",
        20.0,
    )
    keys = {
        "broad_ori50_ratio": max(rot["anytime"]["ori"], tra["anytime"]["ori"]),
        "euroc_pos50_ratio": eu["anytime"]["pos"],
        "euroc_ori50_ratio": eu["anytime"]["ori"],
        "imu_updates_per_s": speed,
    }
    full = {"keys": keys, "broad_fast_rotation": rot, "broad_fast_translation": tra, "euroc": eu}
    if args.plot or args.peers:
        plot_prediction(full, ROOT / "docs" / "inertial_prediction.png")
    if args.peers:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from imu_orientation import compare  # the IMU-only comparison lives there

        cmp = compare()
        full["imu_only"] = {"ratio_6D": cmp["ratio_6D"], "ratio_9D": cmp["ratio_9D"]}
    if args.out:
        Path(args.out).write_text(json.dumps(full, indent=2, default=float))
    if args.json:
        print(json.dumps(keys))
    else:
        for k, v in keys.items():
            print(f"{k:>20}: {v:.4g}")
        for name in ("broad_fast_rotation", "broad_fast_translation", "euroc"):
            for o in ORIGINS:
                r = full[name][o]
                print(f"{name:>22} origins {o:>7}: kalman_imu / best pose-only at 50 ms: "
                      f"position {r['pos']:.3f}, orientation {r['ori']:.3f}")  # fmt: skip
        if args.peers:
            r = full["imu_only"]
            print(
                f"IMU-only orientation / best peer: 6D {r['ratio_6D']:.3f}, 9D {r['ratio_9D']:.3f}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
