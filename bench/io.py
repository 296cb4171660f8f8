"""Recording I/O speed: the native .tfrec format vs NumPy's own .npy files, measured in one run.

The bar (issue 5): loading a 1e6-record recording into numpy takes well under a second. For
context the same run times the lower bound for any file format (``np.load`` of one ``.npy``
array holding the same bytes, no validation) and the text readers (TUM, CSV) per 1e6 rows.

* native read: ``read_native`` -> a validated ``PoseStream`` (record check values, finite
  values, unit quaternions, increasing timestamps, sign-flip scan), without and with 6x6
  covariances (80 / 368 bytes per record).
* native write: ``write_native`` (one ``os.write`` + ``fsync`` + atomic rename) and the
  streaming ``RecordingWriter.append_sample`` rate for the dataflow recorder.
* peer: ``np.save`` / ``np.load`` of a float64 array with the same content (10 or 31 columns).
* text: ``read_stream`` of TUM and CSV files with 1e5 rows, scaled to per-1e6 seconds.

Usage: ``python bench/io.py [--json] [--records N] [--repeat R]`` (best of R runs each).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from trackflow.io import (
    PoseStream,
    RecordingWriter,
    read_native,
    read_stream,
    write_native,
    write_stream,
)
from trackflow.math import quat_exp


def _stream(n: int, covariance: bool, rng: np.random.Generator) -> PoseStream:
    t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 1_000_000
    p = np.cumsum(rng.normal(scale=1e-3, size=(n, 3)), axis=0)
    q = quat_exp(np.cumsum(rng.normal(scale=1e-3, size=(n, 3)), axis=0))
    cov = None
    if covariance:
        d = np.array([1e-6] * 3 + [1e-4] * 3)
        cov = np.broadcast_to(np.diag(d), (n, 6, 6)).copy()
        cov[:, 0, 1] = cov[:, 1, 0] = 1e-7
    return PoseStream("world", "body", t, p, q, cov)


def _best(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--records", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(7)
    n = args.records
    out: dict[str, float | int] = {"records": n}
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        for cov in (False, True):
            tag = "cov" if cov else "nocov"
            s = _stream(n, cov, rng)
            path = d / f"{tag}.tfrec"
            out[f"native_write_{tag}_s"] = _best(lambda s=s, p=path: write_native(p, s), 1)
            out[f"native_bytes_{tag}"] = path.stat().st_size
            back, _ = read_native(path)
            assert back == s, "round trip failed"
            out[f"native_read_{tag}_s"] = _best(lambda p=path: read_native(p), args.repeat)
            cols = [s.t_ns[:, None].astype(float), s.position, s.quaternion]
            if cov:
                cols.append(s.covariance.reshape(n, 36))
            arr = np.hstack(cols + [s.confidence[:, None]])
            npy = d / f"{tag}.npy"
            np.save(npy, arr)
            out[f"npy_load_{tag}_s"] = _best(lambda p=npy: np.load(p), args.repeat)
            out[f"native_vs_npy_{tag}"] = out[f"native_read_{tag}_s"] / out[f"npy_load_{tag}_s"]
            del back, s
        # streaming writer: samples per second through append_sample
        m = 20_000
        s = _stream(m, False, rng)
        w = RecordingWriter(d / "rate.tfrec", "world", "body", covariance=False)
        t0 = time.perf_counter()
        for k in range(m):
            w.append_sample(s.t_ns[k], s.position[k], s.quaternion[k])
        out["writer_samples_per_s"] = m / (time.perf_counter() - t0)
        w.close()
        # text readers on 1e5 rows, scaled
        k = 100_000
        s = _stream(k, False, rng)
        for fmt, name in (("tum", "t.txt"), ("csv", "t.csv")):
            write_stream(d / name, s, format=fmt)
            sec = _best(lambda f=fmt, p=d / name: read_stream(p, format=f), 1)
            out[f"{fmt}_read_per_1e6_s"] = sec * 1e6 / k
    if args.json:
        print(json.dumps(out))
    else:
        for key, v in out.items():
            print(f"{key:28s} {v:.4g}" if isinstance(v, float) else f"{key:28s} {v}")
        ok = out["native_read_nocov_s"] < 1.0 and out["native_read_cov_s"] < 1.0
        print(f"bar: 1e6 records load in well under 1 s -> {'met' if ok else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
