"""Uncertain pose composition: trackflow vs GTSAM and pytransform3d, measured in one run.

Every contestant starts from the same inputs (position, quaternion x-y-z-w and a 6x6 covariance
for each of two poses) and ends with the composed pose, its covariance and both Jacobians:

* trackflow: ``a.compose(b, jacobians=True)`` on ``UncertainPose`` objects (trackflow's own
  representation *is* position + quaternion, so there is nothing to convert). Also reported:
  the same including building and validating both objects from raw arrays each call.
* GTSAM: ``Pose3(Rot3.Quaternion(w, x, y, z), t)`` for both inputs, ``compose(b, H1, H2)`` and
  ``H1 C1 H1^T + H2 C2 H2^T`` in NumPy, results read back to position + quaternion.
* pytransform3d: ``transform_from_pq`` for both inputs, then
  ``concat_locally_uncertain_transforms`` (which returns no Jacobians), results read back.

Batched: trackflow composes a batch of 100 000 pose pairs in one call (covariances and
Jacobians included); reported as compositions per second on one core.

Usage: ``python bench/compose.py [--json] [--repeat N]``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import timeit

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

from trackflow import Pose, UncertainPose
from trackflow.math import quat_exp, use_backend


def _inputs(rng: np.random.Generator):
    t = rng.normal(size=(2, 3))
    q = quat_exp(rng.normal(size=(2, 3)))
    a = rng.normal(size=(2, 6, 6)) * 1e-3
    cov = a @ np.swapaxes(a, -1, -2) + np.eye(6) * 1e-6
    return t, q, cov


def _best_per_call_us(fn, number: int, repeat: int) -> float:
    fn()  # warm-up (numba compilation, caches)
    return min(timeit.repeat(fn, number=number, repeat=repeat)) / number * 1e6


def bench_trackflow(t, q, cov, number, repeat):
    a = UncertainPose(Pose(t[0], q[0]), cov[0])
    b = UncertainPose(Pose(t[1], q[1]), cov[1])

    def objects():
        return a.compose(b, jacobians=True)

    def from_arrays():
        x = UncertainPose(Pose(t[0], q[0]), cov[0])
        y = UncertainPose(Pose(t[1], q[1]), cov[1])
        return x.compose(y, jacobians=True)

    return (
        _best_per_call_us(objects, number, repeat),
        _best_per_call_us(from_arrays, number, repeat),
    )


def bench_gtsam(t, q, cov, number, repeat):
    try:
        import gtsam
    except ImportError:
        return None
    c0, c1 = cov[0], cov[1]

    def run():
        x = gtsam.Pose3(gtsam.Rot3.Quaternion(q[0, 3], q[0, 0], q[0, 1], q[0, 2]), t[0])
        y = gtsam.Pose3(gtsam.Rot3.Quaternion(q[1, 3], q[1, 0], q[1, 1], q[1, 2]), t[1])
        h1 = np.zeros((6, 6), order="F")
        h2 = np.zeros((6, 6), order="F")
        z = x.compose(y, h1, h2)
        c = h1 @ c0 @ h1.T + h2 @ c1 @ h2.T
        return z.translation(), z.rotation().toQuaternion().coeffs(), c, h1, h2

    return _best_per_call_us(run, number, repeat)


def bench_pytransform3d(t, q, cov, number, repeat):
    try:
        import pytransform3d.transformations as pt
        import pytransform3d.uncertainty as pu
    except ImportError:
        return None
    pq0 = np.concatenate([t[0], q[0, [3, 0, 1, 2]]])  # pytransform3d wants (x, y, z, w, qx...)
    pq1 = np.concatenate([t[1], q[1, [3, 0, 1, 2]]])

    def run():
        a2b = pt.transform_from_pq(pq0)
        b2c = pt.transform_from_pq(pq1)
        m, c = pu.concat_locally_uncertain_transforms(a2b, b2c, cov[0], cov[1])
        return pt.pq_from_transform(m), c

    return _best_per_call_us(run, max(number // 10, 100), repeat)


def bench_batched(rng: np.random.Generator, n: int, repeat: int) -> float:
    ta = rng.normal(size=(n, 3))
    tb = rng.normal(size=(n, 3))
    qa = quat_exp(rng.normal(size=(n, 3)))
    qb = quat_exp(rng.normal(size=(n, 3)))
    m = rng.normal(size=(6, 6)) * 1e-3
    cov = np.broadcast_to(m @ m.T + 1e-6 * np.eye(6), (n, 6, 6)).copy()
    a = UncertainPose(Pose(ta, qa), cov)
    b = UncertainPose(Pose(tb, qb), cov)
    a[:10].compose(b[:10], jacobians=True)  # warm-up / compile
    best = min(timeit.repeat(lambda: a.compose(b, jacobians=True), number=1, repeat=repeat))
    return n / best


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--number", type=int, default=5000, help="calls per timing")
    parser.add_argument("--repeat", type=int, default=5, help="timings (best is kept)")
    parser.add_argument("--batch", type=int, default=100_000, help="batch size")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(1)
    t, q, cov = _inputs(rng)
    tf_obj, tf_arrays = bench_trackflow(t, q, cov, args.number, args.repeat)
    with use_backend("numpy"):
        tf_numpy, _ = bench_trackflow(t, q, cov, args.number // 5, args.repeat)
        batched_numpy = bench_batched(np.random.default_rng(2), args.batch, args.repeat)
    gt = bench_gtsam(t, q, cov, args.number, args.repeat)
    p3 = bench_pytransform3d(t, q, cov, args.number, args.repeat)
    batched = bench_batched(np.random.default_rng(2), args.batch, args.repeat)
    result = {
        "per_call_us": {"trackflow": tf_obj, "gtsam": gt, "pytransform3d": p3},
        "batched_per_s": batched,
        "details": {
            "trackflow_including_validated_construction_us": tf_arrays,
            "trackflow_numpy_backend_us": tf_numpy,
            "batched_numpy_backend_per_s": batched_numpy,
            "speedup_vs_gtsam": gt / tf_obj if gt else None,
            "speedup_vs_pytransform3d": p3 / tf_obj if p3 else None,
            "batch": args.batch,
        },
    }
    if args.json:
        print(json.dumps(result))
    else:
        pc = result["per_call_us"]
        print("uncertain composition, per call (us, lower is better)")
        for k, v in pc.items():
            print(f"  {k:15s} {v:9.2f}" if v is not None else f"  {k:15s}   (not installed)")
        print(f"  trackflow incl. validated construction of both inputs: {tf_arrays:.2f}")
        print(f"  trackflow, numpy backend: {tf_numpy:.2f}")
        if gt:
            print(f"  speed-up vs GTSAM: {gt / tf_obj:.2f}x (goal >= 2x)")
        print(f"batched: {batched:,.0f} compositions/s (goal >= 1e6); numpy {batched_numpy:,.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
