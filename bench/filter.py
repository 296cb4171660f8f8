"""Pose Kalman filter speed: streaming vs filterpy, offline throughput, thesis table 9.6.

Usage: ``.venv/bin/python bench/filter.py [--json] [--quick]``

* ``streaming_us``: one pose measurement update plus one prediction (20 ms ahead) for the
  typical 6-DoF model (2 position, 1 orientation derivatives), trackflow's streaming
  ``PoseKalmanFilter`` and filterpy's ``ExtendedKalmanFilter`` doing the same model (the
  thesis's additive-quaternion state of 16 entries with the same transition, Jacobians,
  diagonal process noise and normalisation measurement), measured side by side in this run.
* ``offline_updates_per_s``: ``run_filter`` over a 1 kHz recording, filtering only (the
  rate with one prediction horizon per step is printed in the text output).
* ``table_9_6``: predictions/s and measurements/s of the streaming filter for the thesis's four
  state layouts (thesis table 9.6: 20k/5.5k, 58k/15k, 35k/12k, 28k/11k on a 2 GHz Pentium 4).
* the long-run stability check: 1e7 steps at 1 kHz (1e5 with ``--quick``) keep the covariance
  symmetric positive definite and the quaternion unit (reported on stderr, not in the JSON).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

from trackflow import Pose, UncertainPose
from trackflow.filters import FilterStatus, MotionModel, PoseKalmanFilter, run_filter
from trackflow.filters.derivative.streaming import kernels

DT = 0.01
NOISE = (0.0, 0.0, 5.0, 0.0, 3.0)
C6 = np.diag([1e-6] * 3 + [1e-5] * 3)


def measurements(n: int, rng: np.random.Generator, dt: float = DT):
    t = np.arange(n) * dt
    ang = np.stack([0.3 * np.sin(t), 1.5 * t, 0.2 * np.cos(0.5 * t)], axis=1)
    half = 0.5 * np.linalg.norm(ang, axis=1, keepdims=True)
    axis = ang / np.maximum(2 * half, 1e-12)
    q = np.concatenate([np.sin(half) * axis, np.cos(half)], axis=1)
    p = np.stack([np.cos(t), np.sin(t), 0.1 * t], axis=1) + rng.normal(0, 1e-3, (n, 3))
    return t, p, q


# -- filterpy doing the same model ------------------------------------------------------------


def filterpy_step_fn():
    from filterpy.kalman import ExtendedKalmanFilter

    model = MotionModel(2, 1, noise=NOISE, kind="thesis")
    n = 16
    ekf = ExtendedKalmanFilter(dim_x=n, dim_z=7)
    q_diag = model.process_noise(DT, formulation="additive")
    taylor = np.kron(np.array([[1, DT, DT * DT / 2], [0, 1, DT], [0, 0, 1]]), np.eye(3))

    def qmul(a, b):
        return np.array(
            [
                a[3] * b[0] + a[0] * b[3] + a[1] * b[2] - a[2] * b[1],
                a[3] * b[1] - a[0] * b[2] + a[1] * b[3] + a[2] * b[0],
                a[3] * b[2] + a[0] * b[1] - a[1] * b[0] + a[2] * b[3],
                a[3] * b[3] - a[0] * b[0] - a[1] * b[1] - a[2] * b[2],
            ]
        )

    def transition(x, dt):
        f = np.eye(n)
        tay = np.kron(np.array([[1, dt, dt * dt / 2], [0, 1, dt], [0, 0, 1]]), np.eye(3))
        f[:9, :9] = tay if dt != DT else taylor
        q = x[9:13]
        b = x[13:16] * dt
        phi = math.sqrt(b @ b)
        s = math.sin(phi / 2) / phi if phi > 1e-8 else 0.5
        d = np.array([*(s * b), math.cos(phi / 2)])
        xn = x.copy()
        xn[:9] = f[:9, :9] @ x[:9]
        xn[9:13] = qmul(q, d)
        dx, dy, dz, dw = d
        f[9:13, 9:13] = [
            [dw, dz, -dy, dx],
            [-dz, dw, dx, dy],
            [dy, -dx, dw, dz],
            [-dx, -dy, -dz, dw],
        ]
        ds = (0.5 * math.cos(phi / 2) * phi - math.sin(phi / 2)) / phi**3 if phi > 1e-8 else 0
        jac = np.zeros((4, 3))
        jac[:3] = s * np.eye(3) + ds * np.outer(b, b)
        jac[3] = -0.5 * s * b
        x_, y_, z_, w_ = q
        left = np.array(
            [[w_, -z_, y_, x_], [z_, w_, -x_, y_], [-y_, x_, w_, z_], [-x_, -y_, -z_, w_]]
        )
        f[9:13, 13:16] = left @ jac * dt
        return xn, f

    def hx(x):
        q = x[9:13]
        return np.concatenate([x[:3], q / np.linalg.norm(q)])

    def hjac(x):
        h = np.zeros((7, n))
        h[:3, :3] = np.eye(3)
        q = x[9:13]
        dd = q @ q
        ll = math.sqrt(dd)
        h[3:, 9:13] = (dd * np.eye(4) - np.outer(q, q)) / (ll * dd)
        return h

    r7 = np.zeros((7, 7))
    r7[:6, :6] = C6

    def init(z_p, z_q):
        ekf.x = np.zeros(n)
        ekf.x[:3] = z_p
        ekf.x[9:13] = z_q
        ekf.P = np.eye(n) * 1.0
        ekf.Q = q_diag

    def step(z_p, z_q):
        # measurement covariance in quaternion space, eqs. 6.24-6.25
        x_, y_, z_, w_ = z_q
        v = np.eye(7)
        v[3:7, 3:6] = 0.5 * np.array([[w_, -z_, y_], [z_, w_, -x_], [-y_, x_, w_], [-x_, -y_, -z_]])
        v[3:7, 6] = z_q
        r7[6, 6] = 1.0
        rr = v @ r7 @ v.T
        ekf.x, ekf.F = transition(ekf.x, DT)
        ekf.predict()
        z_q = z_q if z_q @ ekf.x[9:13] >= 0 else -z_q
        ekf.update(np.concatenate([z_p, z_q]), hjac, hx, R=rr)
        ekf.x[9:13] /= np.linalg.norm(ekf.x[9:13])
        # prediction 20 ms ahead
        xp, fp = transition(ekf.x, 0.02)
        pp = fp @ ekf.P @ fp.T + q_diag
        return xp, pp

    return init, step


def bench_streaming(n: int, rng, repeats: int = 7) -> dict:
    """Best (least disturbed) block of ``n`` steps for each filter, blocks interleaved."""
    t, p, q = measurements(repeats * n + 2, rng)
    zs = [UncertainPose(Pose(p[i], q[i]), C6) for i in range(len(t))]
    model = MotionModel(2, 1, noise=NOISE, kind="thesis")
    kf = PoseKalmanFilter(model, history=0.1)
    kf.update_pose(t[0], zs[0])
    kf.update_pose(t[1], zs[1])  # compile / warm up
    kf.predict(t[1] + 0.02)
    init, step = filterpy_step_fn()
    init(p[0], q[0])
    step(p[1], q[1])
    ours, theirs = math.inf, math.inf
    for r in range(repeats):
        lo, hi = 2 + r * n, 2 + (r + 1) * n
        t0 = time.perf_counter()
        for i in range(lo, hi):
            kf.update_pose(t[i], zs[i])
            kf.predict(t[i] + 0.02)
        ours = min(ours, (time.perf_counter() - t0) / n * 1e6)
        m = max(n // 4, 100)
        t0 = time.perf_counter()
        for i in range(lo, lo + m):
            step(p[i], q[i])
        theirs = min(theirs, (time.perf_counter() - t0) / m * 1e6)
    return {"trackflow": round(ours, 2), "filterpy": round(theirs, 2)}


def bench_offline(n: int, rng, horizons=(), repeats: int = 5) -> float:
    """Best of ``repeats`` whole-sequence runs over ``n`` rows at 1 kHz: updates per second."""
    t, p, q = measurements(n, rng, dt=1e-3)
    poses = UncertainPose._trusted(p, q, np.broadcast_to(C6, (n, 6, 6)))
    model = MotionModel(2, 1, noise=NOISE)
    run_filter(t[:100], poses[:100], model, horizons=(0.05,))  # compile
    best = 0.0
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = run_filter(t, poses, model, horizons=horizons)
        best = max(best, res.stats["updates"] / (time.perf_counter() - t0))
    return best


def bench_table_9_6(n: int, rng) -> list:
    t, p, q = measurements(n + 2, rng)
    zs = [UncertainPose(Pose(p[i], q[i]), C6) for i in range(n + 2)]
    rows = []
    for n_dp, n_do in ((2, 2), (2, -1), (-1, 2), (0, 0)):
        npl, nol = n_dp + 1, n_do + 1
        model = MotionModel(n_dp, n_do, noise=[1.0] * (npl + nol), kind="thesis")
        kf = PoseKalmanFilter(model, history=0.1)
        kf.update_pose(t[0], zs[0])
        kf.update_pose(t[1], zs[1])
        kf.predict(t[1] + 0.01)
        meas, pred = 0.0, 0.0
        blk = max(n // 5, 100)
        for r in range(5):  # best of 5 blocks
            t0 = time.perf_counter()
            for i in range(2 + r * blk, 2 + (r + 1) * blk):
                kf.update_pose(t[i], zs[i])
            meas = max(meas, blk / (time.perf_counter() - t0))
            t_last = t[1 + (r + 1) * blk]
            t0 = time.perf_counter()
            for i in range(blk):
                kf.predict(t_last + 0.001 * i)
            pred = max(pred, blk / (time.perf_counter() - t0))
        rows.append(
            {
                "n_dp": n_dp,
                "n_do": n_do,
                "predictions_per_s": round(pred),
                "measurements_per_s": round(meas),
            }
        )
    return rows


def stability(steps: int) -> dict:
    """Run ``steps`` pose updates at 1 kHz in chunks, checking P and q after each chunk."""
    k = kernels()
    model = MotionModel(2, 1, noise=NOISE)
    settings = PoseKalmanFilter(model).kernel_settings
    n_dp, n_do, add, kind, sp, so = settings.params
    x, p = settings.x0.copy(), settings.p0.copy()
    rng = np.random.default_rng(3)
    chunk = min(steps, 100_000)
    done = 0
    worst_sym, min_eig, worst_unit, gated = 0.0, math.inf, 0.0, 0
    t0 = time.perf_counter()
    initialized = False
    while done < steps:
        m = min(chunk, steps - done)
        t, pos, quat = measurements(m, rng, dt=1e-3)
        t = t + done * 1e-3
        if not initialized:
            k.initialize(x, p, n_dp, n_do, add, 0, 0, pos[0], quat[0], C6)
            initialized = True
        for i in range(m):
            st, _ = k.step(
                x, p, 1e-3, n_dp, n_do, add, kind, sp, so, 0, 0, pos[i], quat[i], C6, 1e9, 50.0
            )
            gated += st != FilterStatus.ACCEPTED
        done += m
        worst_sym = max(worst_sym, float(np.max(np.abs(p - p.T))))
        min_eig = min(min_eig, float(np.linalg.eigvalsh(p).min()))
        worst_unit = max(worst_unit, abs(float(np.linalg.norm(x[9:13])) - 1.0))
    return {
        "steps": steps,
        "seconds": round(time.perf_counter() - t0, 1),
        "max_asymmetry": worst_sym,
        "min_eigenvalue": min_eig,
        "max_quaternion_norm_error": worst_unit,
        "not_accepted": int(gated),
    }


# -- error-state vs additive on real recordings ---------------------------------------------

RECORDINGS = [
    "tumvi/dataset-room1_512_16.txt",
    "tumvi/dataset-room2_512_16.txt",
    "tumvi/dataset-room3_512_16.txt",
    "ar_table/table_01.txt",
    "ar_table/table_02.txt",
    "ar_table/table_03.txt",
    "ar_table/table_04.txt",
    "euroc/V1_01_easy_groundtruth_200hz.txt",
]
HORIZONS = (0.0, 0.02, 0.05, 0.1)
COMPARE_MODEL = MotionModel(2, 1, noise=(0.0, 0.0, 30.0, 0.0, 20.0))
COMPARE_COV = np.diag([0.5e-3**2] * 3 + [np.radians(0.2) ** 2] * 3)


def _reference(t, p, q, tq):
    """Recorded pose at times ``tq`` (linear / slerp between neighbours; NaN across gaps)."""
    from trackflow.math import quat_slerp

    i = np.searchsorted(t, tq) - 1
    ok = (i >= 0) & (i < len(t) - 1)
    i = np.clip(i, 0, len(t) - 2)
    gap = t[i + 1] - t[i]
    ok &= gap < 2.5 * np.median(np.diff(t))
    s = np.clip((tq - t[i]) / np.where(gap > 0, gap, 1.0), 0.0, 1.0)
    pr = p[i] + s[:, None] * (p[i + 1] - p[i])
    qr = quat_slerp(q[i], q[i + 1], s)
    pr[~ok] = np.nan
    return pr, qr, ok


def compare_formulations(data_dir) -> list[dict]:
    """Run both formulations over the real recordings; prediction errors vs the recording."""
    from pathlib import Path

    from trackflow.math import quat_angle

    rows = []
    for name in RECORDINGS:
        path = Path(data_dir) / name
        if not path.is_file():
            continue
        d = np.loadtxt(path, comments="#")
        t, p, q = d[:, 0] - d[0, 0], d[:, 1:4], d[:, 4:8]
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
        n = len(t)
        poses = UncertainPose._trusted(p, q, np.broadcast_to(COMPARE_COV, (n, 6, 6)))
        for form in ("error_state", "additive"):
            run_filter(t[:50], poses[:50], COMPARE_MODEL, HORIZONS, formulation=form)
            t0 = time.perf_counter()
            res = run_filter(t, poses, COMPARE_MODEL, HORIZONS, formulation=form)
            sec = time.perf_counter() - t0
            row = {
                "recording": name,
                "formulation": form,
                "rows": n,
                "seconds": round(sec, 3),
                "mean_nis": round(float(np.nanmean(res.nis)), 2),
                "rejected_gate": res.stats["rejected_gate"],
                "resets": res.stats["resets"],
            }
            skip = t > t[0] + 1.0  # after convergence
            for h in HORIZONS:
                pr, qr, ok = _reference(t, p, q, t + h)
                pred = res.predictions[h]
                ok &= skip
                ep = np.linalg.norm(pred.position[ok] - pr[ok], axis=1) * 1e3
                eo = np.degrees(quat_angle(pred.quaternion[ok], qr[ok]))
                row[f"pos_rms_mm_{int(h * 1e3)}ms"] = round(float(np.sqrt(np.mean(ep**2))), 3)
                row[f"rot_rms_deg_{int(h * 1e3)}ms"] = round(float(np.sqrt(np.mean(eo**2))), 3)
            rows.append(row)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--quick", action="store_true", help="short runs (1e5 stability steps)")
    ap.add_argument(
        "--compare",
        metavar="DATA_DIR",
        help="only compare the error-state and additive filters on the recordings in DATA_DIR",
    )
    args = ap.parse_args(argv)
    if args.compare:
        rows = compare_formulations(args.compare)
        print(json.dumps(rows, indent=1))
        return 0
    rng = np.random.default_rng(2026)
    n = 1000 if args.quick else 4000
    out = {
        "streaming_us": bench_streaming(n, rng),
        "offline_updates_per_s": round(bench_offline(100_000 if args.quick else 300_000, rng)),
        "table_9_6": bench_table_9_6(n, rng),
    }
    offline_h = bench_offline(100_000, rng, horizons=(0.05,))
    stab = stability(100_000 if args.quick else 10_000_000)
    print(f"stability: {json.dumps(stab)}", file=sys.stderr)
    if args.json:
        print(json.dumps(out))
    else:
        s = out["streaming_us"]
        print(
            f"streaming update+predict: trackflow {s['trackflow']:.1f} us, filterpy "
            f"{s['filterpy']:.1f} us ({s['filterpy'] / s['trackflow']:.1f}x)"
        )
        print(
            f"offline: {out['offline_updates_per_s']:.3g} updates/s "
            f"({offline_h:.3g}/s with one 50 ms prediction per step)"
        )
        for r in out["table_9_6"]:
            print(
                f"n_dp={r['n_dp']:2d} n_do={r['n_do']:2d}: {r['predictions_per_s']:8d} "
                f"predictions/s {r['measurements_per_s']:8d} measurements/s"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
