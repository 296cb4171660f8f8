"""Tuning speed: trackflow's compiled search vs a filterpy-based equivalent of the same search.

The problem: the first 60 s of a 120 Hz recording (TUM-VI room 1, OptiTrack). trackflow runs its
whole default search (``trackflow.evaluation.tune_model``: position with 1-3 and orientation
with 1-2 derivatives, two log-parameterised white-noise densities each, Powell's method, robust
prediction cost at 50 and 100 ms; every cost evaluation is a ``trackflow.filters.run_filter``
run over the 60 s; then the learned increment models of ``trackflow.filters.twist_ar``, orders
3, 5, 10, forward-validated). The filterpy variant evaluates the same kind of cost with
``filterpy.kalman.KalmanFilter`` (position, constant acceleration: one 3-state filter per axis,
the same F, Q, R, no gating) under Powell with a capped evaluation budget; its time per
evaluation is extrapolated to trackflow's evaluation count. ``--json`` prints
``{"trackflow_s": .., "filterpy_s": ..}``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

# the bar is "on one core": no BLAS or numba worker threads (set before numpy is imported)
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "tumvi" / "dataset-room1_512_16.txt"


def load(seconds: float = 60.0):
    from trackflow.io import read_stream

    stream, _ = read_stream(DATA, format="tum", clean=True)
    t = (stream.t_ns - stream.t_ns[0]) * 1e-9
    keep = t <= seconds
    return t[keep], np.asarray(stream.position)[keep], np.asarray(stream.quaternion)[keep]


def run_trackflow(t, p, q) -> tuple[float, int]:
    from trackflow.evaluation import Trajectory, tune_model

    tune_model(Trajectory.check(t[:300], p[:300], q[:300]), max_evaluations=3)  # compile
    rec = Trajectory.check(t, p, q)
    t0 = time.perf_counter()
    res = tune_model(rec)
    return time.perf_counter() - t0, res.n_evaluations


def run_filterpy(t, p, q, budget: int) -> tuple[float, int]:
    from filterpy.kalman import KalmanFilter
    from scipy.optimize import minimize

    from trackflow.evaluation import Trajectory, estimate_noise

    h = (0.05, 0.1)
    rec = Trajectory.check(t, p, q)
    sig, _ = estimate_noise(t, p, q)
    targets = [(rec.scored(hs), rec.target(hs)[0]) for hs in h]
    n_eval = 0

    def cost(lx):
        nonlocal n_eval
        n_eval += 1
        s0, s2 = 10.0**lx
        pred = np.zeros((len(h), len(t), 3))
        for a in range(3):
            kf = KalmanFilter(dim_x=3, dim_z=1)
            kf.x = np.array([[p[0, a]], [0.0], [0.0]])
            kf.P = np.diag([sig**2, 1e6, 1e6])
            kf.H = np.array([[1.0, 0.0, 0.0]])
            kf.R = np.array([[sig**2]])
            for k in range(1, len(t)):
                dt = t[k] - t[k - 1]
                kf.F = np.array([[1, dt, dt * dt / 2], [0, 1, dt], [0, 0, 1]])
                kf.Q = s2**2 * np.array(
                    [[dt**5 / 20, dt**4 / 8, dt**3 / 6], [dt**4 / 8, dt**3 / 3, dt**2 / 2],
                     [dt**3 / 6, dt**2 / 2, dt]]
                ) + np.diag([s0**2 * dt, 0, 0])  # fmt: skip
                kf.predict()
                kf.update(np.array([[p[k, a]]]))
                for i, hs in enumerate(h):
                    pred[i, k, a] = kf.x[0, 0] + hs * kf.x[1, 0] + 0.5 * hs * hs * kf.x[2, 0]
        return sum(np.mean(np.linalg.norm(pred[i][m] - tp[m], axis=1) ** 2)
                   for i, (m, tp) in enumerate(targets))  # fmt: skip

    t0 = time.perf_counter()
    minimize(cost, np.log10([sig, 30.0]), method="Powell",
             bounds=[(-10, 5)] * 2, options={"maxfev": budget})  # fmt: skip
    return time.perf_counter() - t0, n_eval


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--filterpy-evals", type=int, default=3, help="capped evaluation budget")
    args = ap.parse_args(argv)
    if not DATA.is_file():
        print(f"recording not found: {DATA}", file=sys.stderr)
        return 1
    t, p, q = load()
    tf_s, tf_n = run_trackflow(t, p, q)
    fp_s, fp_n = run_filterpy(t, p, q, args.filterpy_evals)
    fp_total = fp_s / fp_n * tf_n  # same number of cost evaluations as trackflow's search
    res = {"trackflow_s": round(tf_s, 3), "filterpy_s": round(fp_total, 3)}
    if args.json:
        print(json.dumps(res))
    else:
        print(f"60 s, 120 Hz ({len(t)} samples), {tf_n} cost evaluations")
        print(f"trackflow: {tf_s:.2f} s")
        print(f"filterpy : {fp_total:.1f} s (measured {fp_n} evaluations, {fp_s:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
