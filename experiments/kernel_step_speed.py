"""Time of the compiled pose Kalman filter kernels per filter, piece by piece.

The live path of ``trackflow run`` calls ``step_bank`` (predict and update of every filter
with a new pose) and ``predict_pose_bank`` (the filtered answers) once per packet. This script
times them from Python for a bank of 20 filters (the 20 bodies of ``bench/trackers_cpu.py``:
motion model ``n_dp = n_do = 1``, error-state formulation, a 6x6 pose measurement), and the
pieces of one step per filter inside compiled loops: ``step_with``, ``predict_into``,
``update_with`` (after a prediction), ``gain_into``, ``joseph_selection`` and
``predict_pose_with``. Loops that must start from the same state each time copy it back
first; the time of that copy alone (``restore``) is subtracted.

Usage: ``PYTHONPATH=src python experiments/kernel_step_speed.py [--repeat N]``; prints one
JSON object (microseconds, the best of ``--repeat`` runs, and the load average).
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numba
import numpy as np

from trackflow.filters.derivative import kernels as source
from trackflow.filters.derivative import update_kernels
from trackflow.math import _scalar, frozen, kernels_for, quat_exp, quat_multiply

BODIES = 20
N_DP, N_DO, ADD, KIND = 1, 1, 0, 0
SIG_P, SIG_O = np.array([0.0, 30.0]), np.array([0.0, 100.0])
GATE, WMAX = 22.458, 50.0
R = np.diag([1e-6] * 3 + [1e-5] * 3)
DT = 1.0 / 240.0


def _states(k):
    """20 filters after 300 packets of a moving body each (realistic x and P)."""
    c = k.constants(N_DP, N_DO, ADD, KIND, SIG_P, SIG_O, WMAX)
    npl, nol, nx, nc = k.dims(N_DP, N_DO, ADD)
    xs, ps = np.zeros((BODIES, nx)), np.zeros((BODIES, nc, nc))
    rng = np.random.default_rng(3)
    for b in range(BODIES):
        x, p = np.zeros(nx), np.eye(nc) * 100.0
        x[6] = 1.0
        q0 = quat_exp(rng.normal(size=3))
        k.initialize(x, p, N_DP, N_DO, ADD, 0, 0, np.zeros(3), q0, R)
        for i in range(300):
            t = i * DT
            zp = np.array([np.sin(t), 0.1 * b, 0.5]) + rng.normal(0, 1e-3, 3)
            zo = quat_multiply(q0, quat_exp(np.array([0.1, 0.2 + 0.5 * t, 0.3])))
            k.step_packed(x, p, DT, c, 0, 0, zp, zo, R, GATE, np.empty(0))
        xs[b], ps[b] = x, p
    return c, xs, ps


def _loops(k):
    """Compiled timing loops over the kernels of ``k`` (numba dispatchers)."""
    u = kernels_for(update_kernels)
    step_with, predict_into, update_with = k.step_with, k.predict_into, u.update_with
    gain_into, joseph, ppw = u.gain_into, kernels_for(_scalar).joseph_selection, k.predict_pose_with
    residual_into = k.residual_into
    jit = numba.njit(cache=False)

    @jit
    def restore(n, x0, p0, x, p):
        for _ in range(n):
            x[:] = x0
            p[:, :] = p0

    @jit
    def t_step(n, x0, p0, x, p, zp, zo, r, log, pws, y, h, uws, idx):
        for _ in range(n):
            x[:] = x0
            p[:, :] = p0
            step_with(x, p, DT, N_DP, N_DO, ADD, KIND, SIG_P, SIG_O, 0, 0, zp, zo, r, GATE,
                      WMAX, log, pws, y, h, uws, idx)  # fmt: skip

    @jit
    def t_predict(n, x0, p0, x, p, pws):
        for _ in range(n):
            x[:] = x0
            p[:, :] = p0
            predict_into(x, p, DT, N_DP, N_DO, ADD, KIND, SIG_P, SIG_O, pws)

    @jit
    def t_update(n, x0, p0, x, p, zp, zo, r, y, h, uws, idx):
        for _ in range(n):
            x[:] = x0
            p[:, :] = p0
            residual_into(x, N_DP, N_DO, ADD, 0, 0, zp, zo, y, h, uws[10], uws[11])
            update_with(x, p, y, h, r, GATE, N_DP, N_DO, ADD, WMAX, uws, idx)

    @jit
    def t_gain(n, hp, s, y, r, lo, sy, kt, kr, delta, mp):
        for _ in range(n):
            gain_into(hp, s, y, r, GATE, lo, sy, kt, kr, delta, mp)

    @jit
    def t_joseph(n, p0, p, kt, kr, hp, idx, mp, g, acc):
        for _ in range(n):
            p[:, :] = p0
            joseph(p, kt, kr, hp, idx, mp, g, acc)

    @jit
    def t_ppw(n, x, p, out, pws, t, sel):
        for _ in range(n):
            ppw(x, p, DT, N_DP, N_DO, ADD, KIND, SIG_P, SIG_O, out, pws, t, sel)

    return restore, t_step, t_predict, t_update, t_gain, t_joseph, t_ppw


def _best(fn, n, repeat):
    fn(1)
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter_ns()
        fn(n)
        best = min(best, (time.perf_counter_ns() - t0) / n / 1000.0)
    return best


def measure(repeat: int = 7, n: int = 20000) -> dict:
    k = kernels_for(source)
    c, xs, ps = _states(k)
    npl, nol, nx, nc = k.dims(N_DP, N_DO, ADD)
    x0, p0 = xs[0].copy(), ps[0].copy()
    x, p = x0.copy(), p0.copy()
    zp = frozen(x0[:3] + 1e-3)
    zo = frozen(quat_multiply(x0[6:10], quat_exp(np.array([1e-3, 0.0, 2e-3]))))
    r = frozen(R)
    log = np.empty(k.log_size(N_DP, N_DO, ADD, 6))
    pws = k.predict_scratch(N_DP, N_DO, ADD)
    uws = k.update_scratch(6, nc)
    y, h, idx = np.empty(6), np.empty((6, nc)), np.empty(6, np.int64)
    restore, t_step, t_predict, t_update, t_gain, t_joseph, t_ppw = _loops(k)
    res = {}
    base = _best(lambda m: restore(m, x0, p0, x, p), n, repeat)
    res["restore"] = base
    res["step_with"] = (
        _best(lambda m: t_step(m, x0, p0, x, p, zp, zo, r, log, pws, y, h, uws, idx), n, repeat)
        - base
    )
    res["predict_into"] = _best(lambda m: t_predict(m, x0, p0, x, p, pws), n, repeat) - base
    # the update pieces start from the predicted state
    xp, pp = x0.copy(), p0.copy()
    k.predict_into(xp, pp, DT, N_DP, N_DO, ADD, KIND, SIG_P, SIG_O, pws)
    res["update_with"] = (
        _best(lambda m: t_update(m, xp, pp, x, p, zp, zo, r, y, h, uws, idx), n, repeat) - base
    )
    hp, s, lo, sy, kt, kr, delta, g, acc, mp, d4, q4 = uws
    xx, pq = xp.copy(), pp.copy()
    k.residual_into(xx, N_DP, N_DO, ADD, 0, 0, zp, zo, y, h, d4, q4)
    k.selection_rows(h, idx)
    for a in range(6):
        hp[a] = pq[idx[a]]
        for b in range(6):
            s[a, b] = 0.5 * (hp[a, idx[b]] + hp[b, idx[a]]) + 0.5 * (R[a, b] + R[b, a])
    res["gain_into"] = _best(lambda m: t_gain(m, hp, s, y, r, lo, sy, kt, kr, delta, mp), n, repeat)
    kernels_for(update_kernels).gain_into(hp, s, y, r, GATE, lo, sy, kt, kr, delta, mp)
    res["joseph_selection"] = _best(
        lambda m: t_joseph(m, pp, pq, kt, kr, hp, idx, mp, g, acc), n, repeat
    ) - (base * 0.9)  # p only (x is 1/13 of the restore)
    out = np.empty(source.POSE_OUT)
    t6, sel = np.empty((6, nc)), np.empty(6, np.int64)
    res["predict_pose_with"] = _best(lambda m: t_ppw(m, x0, p0, out, pws, t6, sel), n, repeat)
    # the bank calls from Python, as the live path makes them (20 rows each)
    rows = frozen(np.arange(BODIES), np.int64)
    dts = frozen(np.full(BODIES, DT))
    zps = frozen(xs[:, :3] + 1e-3)
    zos = frozen(xs[:, 6:10])
    rs = frozen(np.broadcast_to(R, (BODIES, 6, 6)))
    size = k.log_size(N_DP, N_DO, ADD, 6)
    cst = frozen(c)
    bx, bp = xs.copy(), ps.copy()

    def bank_step(m):
        for _ in range(m):
            bx[:] = xs
            bp[:] = ps
            logs = np.empty((BODIES, size))
            st, nis = np.empty(BODIES, np.int64), np.empty(BODIES)
            k.step_bank(bx, bp, rows, dts, cst, zps, zos, rs, GATE, logs, st, nis)

    def bank_restore(m):
        for _ in range(m):
            bx[:] = xs
            bp[:] = ps
            np.empty((BODIES, size))
            np.empty(BODIES, np.int64), np.empty(BODIES)

    def bank_predict(m):
        for _ in range(m):
            out = np.empty((BODIES, source.POSE_OUT))
            k.predict_pose_bank(xs, ps, rows, dts, cst, out)

    nb = max(n // 40, 200)
    res["step_bank_20"] = _best(bank_step, nb, repeat) - _best(bank_restore, nb, repeat)
    res["predict_pose_bank_20"] = _best(bank_predict, nb, repeat)
    res = {key: round(v, 3) for key, v in res.items()}
    res["loadavg"] = [round(v, 2) for v in os.getloadavg()]
    return res


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("-n", type=int, default=20000, help="iterations per timed run")
    args = ap.parse_args(argv)
    print(json.dumps(measure(args.repeat, args.n)))


if __name__ == "__main__":
    main()
