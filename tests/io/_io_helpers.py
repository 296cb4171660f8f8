"""Random pose streams for the io tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trackflow.io import PoseStream
from trackflow.math import quat_exp


def random_stream(
    rng: np.random.Generator,
    n: int = 20,
    covariance: bool = False,
    t0_ns: int = 1_700_000_000_123_456_789,
    source: str = "world",
    target: str = "body",
    step_ns: int | None = None,
    extras: bool = False,
) -> PoseStream:
    """A stream with irregular integer-ns stamps, random poses and (optionally) covariances.

    With ``extras`` the confidence and flags are random too (for formats that store them).
    """
    if step_ns is None:
        dt = rng.integers(1_000_000, 20_000_000, size=n)
    else:
        dt = np.full(n, step_ns)
    t = t0_ns + np.cumsum(dt) - dt[0]
    p = rng.normal(scale=2.0, size=(n, 3))
    q = quat_exp(rng.normal(scale=1.5, size=(n, 3)))
    q[rng.random(n) < 0.3] *= -1.0  # sign flips are legal and must survive round trips
    cov = None
    if covariance:
        a = rng.normal(size=(n, 6, 6)) * np.array([1e-3] * 3 + [1e-2] * 3)[:, None]
        cov = a @ np.swapaxes(a, 1, 2)
    conf = rng.random(n) if extras else None
    flags = rng.integers(0, 16, size=n).astype(np.uint32) if extras else None
    return PoseStream(source, target, t, p, q, cov, conf, flags)


def write_big_tum(path: Path, n: int, seed: int = 5) -> None:
    """``n`` valid TUM rows like a real file's (75 bytes each): Unix times with 6 decimals,
    positions with 4 and unit quaternions with 6, a slow random walk."""
    rng = np.random.default_rng(seed)
    t_us = 1305031102175304 + np.cumsum(rng.integers(9000, 11000, n))
    p = np.cumsum(rng.normal(0, 1e-3, (n, 3)), axis=0)
    q = np.cumsum(rng.normal(0, 1e-2, (n, 4)), axis=0) + [0, 0, 0, 30.0]
    q /= np.linalg.norm(q, axis=1)[:, None]
    sec, frac = np.divmod(t_us, 1_000_000)
    with open(path, "w") as f:
        for k in range(0, n, 50_000):
            s = slice(k, k + 50_000)
            cols = [
                np.char.add(
                    np.char.add(sec[s].astype(str), "."), np.char.zfill(frac[s].astype(str), 6)
                )
            ]
            cols += [np.char.mod("%.4f", p[s, i]) for i in range(3)]
            cols += [np.char.mod("%.6f", q[s, i]) for i in range(4)]
            f.write("\n".join(" ".join(r) for r in zip(*cols)) + "\n")
