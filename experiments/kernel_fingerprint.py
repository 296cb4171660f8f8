"""Bit fingerprint of the pose Kalman filter kernels, to prove a speed-up changed no result.

Runs the kernels of :mod:`trackflow.filters.derivative.kernels` on seeded random states,
time steps and measurements, edge cases included (angles below the series threshold,
rotations near pi, a measurement on the other quaternion sign, gated and diverged steps,
huge, zero, negative and NaN time steps, NaN and infinite measurements, clipped angular
velocity), for both formulations (error state and additive), both process-noise kinds and
every motion model with ``n_dp, n_do`` in ``-1..2``:

* ``step_packed`` sequences with every measurement level the model allows (the records too);
* ``step_bank``, ``predict_pose_bank`` and ``step_predict_bank`` (a packet's steps and
  answers in one call) on a bank of filters, rows in random order, with one time step for all
  rows (as in a live packet; signed zeros too) or one per row;
* ``predict_pose_packed`` of single filters;
* ``run`` (with and without covariances, with the states for smoothing) and ``smooth_run``
  through :func:`~trackflow.filters.run_filter` and :func:`~trackflow.filters.smooth_filter`;
* the model's ``transition``, ``process_noise``, ``retract`` and ``local``.

Every output (arrays, statuses, NIS) goes into one SHA-256 per case, raw bytes (NaN payloads
and signed zeros included). The fingerprints depend on the machine's maths library and CPU,
so they are compared with a file written on the same machine before a change.

Usage::

    PYTHONPATH=src python experiments/kernel_fingerprint.py --save before.json
    PYTHONPATH=src python experiments/kernel_fingerprint.py --check before.json
    TRACKFLOW_BACKEND=numpy PYTHONPATH=src python experiments/kernel_fingerprint.py ...

Prints one JSON object: the backend, the combined digest and each case's digest; ``--check``
exits with status 1 and names the cases that differ.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import sys

import numpy as np

from trackflow import UncertainPose
from trackflow.filters import MotionModel, run_filter, smooth_filter
from trackflow.filters.derivative import kernels as source
from trackflow.math import frozen, get_backend, kernels_for, quat_exp, quat_multiply

MODELS = [(a, b) for a in range(-1, 3) for b in range(-1, 3) if (a, b) != (-1, -1)]
EDGE_DTS = (0.0, 1e-12, 1e-6, 2.5, 1e6, -0.01, math.nan, math.inf)


class Digest:
    """SHA-256 of everything fed to it, in order."""

    def __init__(self):
        self.h = hashlib.sha256()

    def add(self, *values) -> None:
        for v in values:
            self.h.update(np.ascontiguousarray(np.asarray(v)).tobytes())

    def hex(self) -> str:
        return self.h.hexdigest()

    def call(self, fn, *args):
        """``fn(*args)``; an exception of the plain-Python kernels (``math.sin(inf)``, a
        division by zero) is recorded by its type instead, and ``None`` returned."""
        try:
            return fn(*args)
        except (ArithmeticError, ValueError) as e:
            self.h.update(type(e).__name__.encode())
            return None


def _unit(v):
    return v / np.linalg.norm(v)


def _spd(rng, n, scale):
    a = rng.normal(size=(n, n)) * scale
    return a @ a.T + np.eye(n) * scale * scale * 0.1


def _state(rng, n_dp, n_do, additive, kind_of_rotation="random"):
    """A random nominal state and covariance of a model."""
    npl, nol, nx, nc = source.dims(n_dp, n_do, additive)
    x = np.empty(nx)
    x[: 3 * npl] = rng.normal(size=3 * npl)
    if n_do >= 0:
        qo = 3 * npl
        if kind_of_rotation == "tiny":
            q = quat_exp(rng.normal(size=3) * 1e-6)
        else:
            q = _unit(rng.normal(size=4))
        x[qo : qo + 4] = q
        w = rng.normal(size=3 * n_do) * 2.0
        if kind_of_rotation == "tiny":
            w *= 1e-7
        elif kind_of_rotation == "fast":
            w *= 40.0
        x[qo + 4 :] = w
    p = _spd(rng, nc, 0.05)
    return x, p


def _noise(rng, n_dp, n_do):
    npl, nol = n_dp + 1, n_do + 1
    sp = np.abs(rng.normal(size=max(npl, 1))) * 3.0
    so = np.abs(rng.normal(size=max(nol, 1))) * 2.0
    if npl > 1:
        sp[0] = 0.0  # the models of the library: noise on the top level only, often
    if nol > 1 and rng.random() < 0.5:
        so[0] = 0.0
    return sp, so


def _measurement(rng, x, n_dp, n_do, additive, lp, lo, case):
    """``(zp (3), zo (4), r)`` near the state, or an edge case."""
    npl = n_dp + 1 if n_dp >= 0 else 0
    qo = 3 * npl
    zp = rng.normal(size=3) * 0.01
    if lp >= 0:
        zp += x[3 * lp : 3 * lp + 3]
    if lo == 0:
        q = x[qo : qo + 4] / np.linalg.norm(x[qo : qo + 4])
        if case == "tiny":
            zo = quat_multiply(q, quat_exp(rng.normal(size=3) * 1e-7))
        elif case == "pi":
            zo = quat_multiply(q, quat_exp(_unit(rng.normal(size=3)) * (math.pi - 1e-9)))
        elif case == "flip":
            zo = -quat_multiply(q, quat_exp(rng.normal(size=3) * 0.01))
        else:
            zo = quat_multiply(q, quat_exp(rng.normal(size=3) * 0.02))
    else:
        zo = np.zeros(4)
        if lo >= 1:
            zo[:3] = x[qo + 4 + 3 * (lo - 1) : qo + 7 + 3 * (lo - 1)] + rng.normal(size=3) * 0.1
    m = (3 if lp >= 0 else 0) + (3 if lo >= 0 else 0)
    r = _spd(rng, m, 0.01)
    if case == "nan":
        zp[1] = math.nan
    elif case == "inf":
        zo[0] = math.inf
    elif case == "huge":
        zp *= 1e200
    elif case == "badr":
        r = -r
    elif case == "zero_r":
        r = np.zeros((m, m))
    return zp, zo, r


CASES = ("plain",) * 8 + ("tiny", "pi", "flip", "nan", "inf", "huge", "badr", "zero_r")


def _dt(rng):
    if rng.random() < 0.12:
        return float(EDGE_DTS[rng.integers(len(EDGE_DTS))])
    return float(rng.uniform(1e-4, 0.05))


def _gate(rng):
    return float((math.inf, 30.0, 5.0, 0.5)[rng.integers(4)])


def step_packed_sequences(k, rng, d: Digest, steps: int) -> None:
    """One filter per model, formulation and noise kind, stepped with every measurement level."""
    for n_dp, n_do in MODELS:
        for additive in (0, 1):
            for kind in (0, 1):
                sp, so = _noise(rng, n_dp, n_do)
                wmax = float((50.0, 0.0, 0.3)[rng.integers(3)])
                c = k.constants(n_dp, n_do, additive, kind, sp, so, wmax)
                x, p = _state(rng, n_dp, n_do, additive)
                levels = [
                    (lp, lo)
                    for lp in range(-1, n_dp + 1)
                    for lo in range(-1, n_do + 1)
                    if (lp, lo) != (-1, -1)
                ]
                for _ in range(steps):
                    lp, lo = levels[rng.integers(len(levels))]
                    case = CASES[rng.integers(len(CASES))]
                    zp, zo, r = _measurement(rng, x, n_dp, n_do, additive, lp, lo, case)
                    log = np.full(k.log_size(n_dp, n_do, additive, r.shape[0]), 7.0)
                    if rng.random() < 0.2:
                        log = np.empty(0)
                    res = d.call(
                        k.step_packed, x, p, _dt(rng), c, lp, lo, zp, zo, r, _gate(rng), log
                    )
                    if res is not None:
                        d.add(np.int64(res[0]), np.float64(res[1]))
                    d.add(x, p, log)
                    if (
                        not (np.all(np.isfinite(x)) and np.all(np.isfinite(p)))
                        or rng.random() < 0.05
                    ):
                        x, p = _state(rng, n_dp, n_do, additive, ("tiny", "fast")[rng.integers(2)])


def banks(k, rng, d: Digest, rounds: int) -> None:
    """``step_bank``, ``step_predict_bank`` and ``predict_pose_bank`` (and
    ``predict_pose_packed`` per filter)."""
    for n_dp, n_do in MODELS:
        if n_dp < 0 or n_do < 0:
            continue
        for additive in (0, 1):
            for kind in (0, 1):
                sp, so = _noise(rng, n_dp, n_do)
                c = frozen(k.constants(n_dp, n_do, additive, kind, sp, so, 50.0))
                npl, nol, nx, nc = source.dims(n_dp, n_do, additive)
                nf = 7
                xs, ps = np.empty((nf, nx)), np.empty((nf, nc, nc))
                for i in range(nf):
                    xs[i], ps[i] = _state(rng, n_dp, n_do, additive, ("random", "tiny")[i % 2])
                size = k.log_size(n_dp, n_do, additive, 6)
                for _ in range(rounds):
                    rows = rng.permutation(nf)[: rng.integers(1, nf + 1)]
                    m = rows.size
                    dts = np.array([_dt(rng) for _ in range(m)])
                    if rng.random() < 0.5:  # one packet: the same step for every row
                        dts[:] = (-0.0, 0.0, dts[0], dts[0])[rng.integers(4)]
                        dts[m // 2 :] = (dts[0], -dts[0])[rng.integers(2)]
                    zs = [
                        _measurement(rng, xs[i], n_dp, n_do, additive, 0, 0,
                                     CASES[rng.integers(len(CASES))])
                        for i in rows
                    ]  # fmt: skip
                    zp = np.array([z[0] for z in zs])
                    zo = np.array([z[1] for z in zs])
                    r = np.array([z[2] for z in zs])
                    logs, status, nis = (
                        np.full((m, size), 7.0),
                        np.full(m, 9, np.int64),
                        np.full(m, 7.0),
                    )
                    gate = _gate(rng)
                    xs2, ps2 = xs.copy(), ps.copy()  # the same step, with its answers
                    d.call(
                        k.step_bank, xs, ps, frozen(rows, np.int64), frozen(dts), c, frozen(zp),
                        frozen(zo), frozen(r), gate, logs, status, nis,
                    )  # fmt: skip
                    d.add(xs, ps, logs, status, nis)
                    ts = np.cumsum(np.abs(dts))  # step times; answers at or after the last
                    at = float(ts.max() + abs(_dt(rng)))
                    ahead = np.full((m, source.POSE_OUT), 7.0)
                    status2, nis2 = np.full(m, 9, np.int64), np.full(m, 7.0)
                    d.call(
                        k.step_predict_bank, xs2, ps2, frozen(rows, np.int64), frozen(dts), c,
                        frozen(zp), frozen(zo), frozen(r), gate, np.empty((m, 0)), status2, nis2,
                        at, frozen(ts), ahead,
                    )  # fmt: skip
                    d.add(xs2, ps2, status2, nis2, ahead)
                    out = np.full((m, source.POSE_OUT), 7.0)
                    pdts = np.array([_dt(rng) for _ in range(m)])
                    if rng.random() < 0.5:
                        pdts[:] = (0.0, -0.0, pdts[0])[rng.integers(3)]
                    d.call(
                        k.predict_pose_bank, xs, ps, frozen(rows, np.int64), frozen(pdts), c, out
                    )
                    d.add(out)
                    one = np.full(source.POSE_OUT, 7.0)
                    d.call(k.predict_pose_packed, xs[rows[0]], ps[rows[0]], float(pdts[0]), c, one)
                    d.add(one)
                    for i in range(nf):
                        if not (np.all(np.isfinite(xs[i])) and np.all(np.isfinite(ps[i]))):
                            xs[i], ps[i] = _state(rng, n_dp, n_do, additive)


def model_functions(rng, d: Digest, n: int) -> None:
    """The model's transition, process noise, retraction and local coordinates."""
    for n_dp, n_do in MODELS:
        for form in ("error_state", "additive"):
            additive = int(form == "additive")
            for kind in ("white_noise", "thesis"):
                sp, so = _noise(rng, n_dp, n_do)
                noise = list(sp[: n_dp + 1]) + list(so[: n_do + 1])
                model = MotionModel(n_dp, n_do, noise=noise, kind=kind)
                for j in range(n):
                    x, _ = _state(rng, n_dp, n_do, additive, ("random", "tiny", "fast")[j % 3])
                    dt = float(rng.uniform(1e-4, 0.1))
                    xn, a = model.transition(x, dt, form)
                    qm = model.process_noise(dt, x, form)
                    delta = rng.normal(size=a.shape[0]) * (1e-7, 0.1, 3.0)[j % 3]
                    y = model.retract(x, delta, form)
                    d.add(xn, a, qm, y, model.local(y, x, form))


def _recording(rng, n, jump=True):
    t = np.cumsum(rng.uniform(0.004, 0.014, n))
    rv = np.outer(np.sin(t), [0.3, 1.0, 0.2]) + np.outer(t, [0.0, 0.0, 2.5])
    q = quat_exp(rv)
    p = np.stack([np.sin(t), np.cos(2 * t), 0.3 * t], axis=1) + rng.normal(0, 1e-3, (n, 3))
    if jump:
        p[n // 2 :] += [0.5, 0.0, 0.0]
    c = np.broadcast_to(np.diag([1e-6] * 3 + [1e-5] * 3), (n, 6, 6)).copy()
    p[n // 3] = np.nan  # a dropout row
    q[n // 4] = -q[n // 4]
    return t, UncertainPose._trusted(p, q, c)


def offline(rng, d: Digest, n: int) -> None:
    """``run`` (both outputs) and ``smooth_run`` through the offline drivers."""
    t, poses = _recording(rng, n)
    queries = np.concatenate([t[::5], rng.uniform(t[0] - 0.01, t[-1] + 0.05, 60)])
    for n_dp, n_do in MODELS:
        sp, so = _noise(rng, n_dp, n_do)
        noise = list(sp[: n_dp + 1]) + list(so[: n_do + 1])
        model = MotionModel(n_dp, n_do, noise=noise)
        for form in ("error_state", "additive"):
            for cov in (True, False):
                res = run_filter(t, poses, model, horizons=(0.0, 0.03), formulation=form,
                                 covariance=cov, reset_after=5)  # fmt: skip
                d.add(res.nis, res.status, res.filtered.position, res.filtered.quaternion)
                if cov:
                    d.add(res.filtered.covariance)
                for h in res.horizons:
                    pr = res.predictions[h]
                    d.add(pr.position, pr.quaternion)
                    if cov:
                        d.add(pr.covariance)
            sm = smooth_filter(t, poses, model, queries, formulation=form, reset_after=5)
            d.add(sm.position, sm.quaternion, sm.covariance)


def fingerprint(scale: float = 1.0) -> dict:
    """``{case: sha256 hex}`` of every case, run with the active backend."""
    k = kernels_for(source)
    out = {}
    parts = (
        ("step_packed", lambda r, d: step_packed_sequences(k, r, d, int(60 * scale))),
        ("bank", lambda r, d: banks(k, r, d, int(40 * scale))),
        ("model", lambda r, d: model_functions(r, d, int(6 * scale))),
        ("offline", lambda r, d: offline(r, d, int(200 * scale))),
    )
    for seed, (name, fn) in enumerate(parts):
        d = Digest()
        with np.errstate(all="ignore"):
            fn(np.random.default_rng(1000 + seed), d)
        out[name] = d.hex()
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--save", help="write the fingerprints to this JSON file")
    ap.add_argument("--check", help="compare with the fingerprints in this JSON file")
    ap.add_argument("--scale", type=float, default=1.0, help="size of the random sets")
    args = ap.parse_args(argv)
    cases = fingerprint(args.scale)
    total = hashlib.sha256(json.dumps(cases, sort_keys=True).encode()).hexdigest()
    result = {"backend": get_backend(), "scale": args.scale, "digest": total, "cases": cases}
    print(json.dumps(result, indent=1))
    if args.save:
        with open(args.save, "w") as f:
            json.dump(result, f, indent=1)
    if args.check:
        with open(args.check) as f:
            ref = json.load(f)
        bad = [c for c in cases if ref["cases"].get(c) != cases[c]]
        if bad:
            print(f"DIFFERENT: {bad}", file=sys.stderr)
            return 1
        print("identical", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
