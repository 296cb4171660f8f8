"""The pose filter's inner kernels compute exactly (to the bit) what their definitions say.

The speed-ups of ``sandwich_into`` (nonzero lists) and of the process noise kept between the
rows of a bank must not change a single bit, and a one-column ``chol_solve_rows`` must equal
its many-column form: each is checked against its definition written out in plain loops,
with non-finite values and signed zeros in the inputs, on both backends.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from trackflow.filters import gating
from trackflow.filters.derivative import kernels as source
from trackflow.filters.derivative import motion_kernels, update_kernels
from trackflow.math import _scalar, frozen, kernels_for, numba_available, use_backend

BACKENDS = ["numpy"] + (["numba"] if numba_available() else [])


def _same_bits(a, b) -> bool:
    """Equal values, NaN where NaN, and the same sign of every zero."""
    a, b = np.asarray(a), np.asarray(b)
    return bool(
        np.array_equal(a, b, equal_nan=True) and np.array_equal(np.signbit(a), np.signbit(b))
    )


def _sandwich_definition(a, p, q):
    """``A P A^T + Q`` as specified: each sum over the nonzero ``A`` terms in ascending
    order from zero, the symmetric part of ``Q`` added, tiny entries flushed to zero."""
    n = p.shape[0]
    tmp = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                if a[i, k] != 0.0:
                    s += float(a[i, k]) * float(p[k, j])
            tmp[i, j] = s
    out = np.empty((n, n))
    for j in range(n):
        for i in range(j + 1):
            s = 0.0
            for k in range(n):
                if a[j, k] != 0.0:
                    s += float(tmp[i, k]) * float(a[j, k])
            w = s + 0.5 * (float(q[i, j]) + float(q[j, i]))
            w = 0.0 if abs(w) < _scalar.TINY else w
            out[i, j] = out[j, i] = w
    return out


@pytest.mark.parametrize("backend", BACKENDS)
def test_sandwich_is_its_definition(rng, backend):
    n = 9
    with use_backend(backend):
        sc = kernels_for(_scalar)
        for trial in range(12):
            a = rng.normal(size=(n, n)) * (rng.random((n, n)) < 0.35)
            a[rng.integers(n), rng.integers(n)] = -0.0
            p = rng.normal(size=(n, n))
            q = rng.normal(size=(n, n)) * 1e-3
            if trial % 3 == 1:
                p[rng.integers(n), rng.integers(n)] = math.inf
            if trial % 3 == 2:
                a[rng.integers(n), rng.integers(n)] = math.nan
                p[2, :] = 1e-160  # products below the flush threshold
            got = p.copy()
            with np.errstate(all="ignore"):
                want = _sandwich_definition(a, p, q)
                sc.sandwich_into(
                    a, got, q, np.empty((n, n)), np.empty((n, n)), np.empty((n, n + 1), np.int64)
                )
            assert _same_bits(got, want), trial


@pytest.mark.parametrize("backend", BACKENDS)
def test_one_column_solve_is_a_column_of_the_many_column_solve(rng, backend):
    with use_backend(backend):
        sc = kernels_for(_scalar)
        for n in (1, 3, 6, 7):
            m = rng.normal(size=(n, n))
            lo, ok = sc.chol(m @ m.T + n * np.eye(n))
            assert ok
            b = rng.normal(size=(n, 3))
            b[0, 2] = math.inf
            many = b.copy()
            with np.errstate(all="ignore"):
                sc.chol_solve_rows(lo, many)
                for c in range(3):
                    one = b[:, c : c + 1].copy()
                    sc.chol_solve_rows(lo, one)
                    assert _same_bits(one[:, 0], many[:, c]), (n, c)


def _joseph_definition(p, kt, kr, hp, idx):
    """``MP = P - K (H P)`` summed term by term from ``P``, then each upper entry
    ``MP[i, j] + sum_a (KR[i, a] - MP[i, idx[a]]) K^T[a, j]`` in order, flushed, mirrored."""
    nc, m = p.shape[0], kt.shape[0]
    mp = np.empty((nc, nc))
    for i in range(nc):
        for j in range(nc):
            w = float(p[i, j])
            for a in range(m):
                w -= float(kt[a, i]) * float(hp[a, j])
            mp[i, j] = w
    out = np.empty((nc, nc))
    for i in range(nc):
        g = [float(kr[i, a]) - float(mp[i, idx[a]]) for a in range(m)]
        for j in range(i, nc):
            w = float(mp[i, j])
            for a in range(m):
                w += g[a] * float(kt[a, j])
            w = 0.0 if abs(w) < _scalar.TINY else w
            out[i, j] = out[j, i] = w
    return out


@pytest.mark.parametrize("backend", BACKENDS)
def test_joseph_selection_is_its_definition(rng, backend):
    nc, m = 12, 6
    with use_backend(backend):
        sc = kernels_for(_scalar)
        for trial in range(12):
            p = rng.normal(size=(nc, nc))  # not symmetric: the definition holds for any P
            kt, kr, hp = (
                rng.normal(size=(m, nc)),
                rng.normal(size=(nc, m)),
                rng.normal(size=(m, nc)),
            )
            idx = rng.permutation(nc)[:m] if trial % 2 else np.array([0, 1, 2, 6, 7, 8])
            kt[1, 4] = -0.0
            if trial % 3 == 1:
                p[rng.integers(nc), rng.integers(nc)] = math.inf
                hp[2, 5] = math.nan
            if trial % 3 == 2:
                kr[3] = 1e-160  # below the flush threshold
            got = p.copy()
            with np.errstate(all="ignore"):
                want = _joseph_definition(p, kt, kr, hp, idx)
                sc.joseph_selection(
                    got, kt, kr, hp, idx, np.empty((nc, nc)), np.empty(m), np.empty(nc)
                )
            assert _same_bits(got, want), trial


@pytest.mark.parametrize("backend", BACKENDS)
def test_gain_is_its_definition(rng, backend):
    """``K^T = S^-1 H P`` by the row solve, ``K y`` and ``K R`` each summed from zero in
    order of the measurement rows."""
    nc, m = 12, 6
    with use_backend(backend):
        k = kernels_for(update_kernels)
        sc = kernels_for(_scalar)
        for trial in range(8):
            a = rng.normal(size=(m, m))
            s, r = a @ a.T + m * np.eye(m), rng.normal(size=(m, m))
            r[2, 3] = -0.0
            hp, y = rng.normal(size=(m, nc)), rng.normal(size=m) * 0.1
            hp[:, 5] = 0.0  # products of signed zeros
            if trial % 2:
                r[4, 4] = math.inf
            lo, kt, kr, delta = np.empty((m, m)), np.empty((m, nc)), np.empty((nc, m)), np.empty(nc)
            with np.errstate(all="ignore"):
                st, nis = k.gain_into(hp, s, y, r, 1e9, lo, np.empty((m, 1)), kt, kr, delta,
                                      np.empty((m, nc)))  # fmt: skip
                low, ok = sc.chol(s)
                want_kt = sc.chol_solve(low, hp)
                want_kr, want_delta = np.empty((nc, m)), np.empty(nc)
                for i in range(nc):
                    w = 0.0
                    for b in range(m):
                        w += float(want_kt[b, i]) * float(y[b])
                    want_delta[i] = w
                    for c in range(m):
                        w = 0.0
                        for b in range(m):
                            w += float(want_kt[b, i]) * float(r[b, c])
                        want_kr[i, c] = w
            assert ok and st == gating.ACCEPTED, trial
            assert _same_bits(kt, want_kt) and _same_bits(delta, want_delta), trial
            assert _same_bits(kr, want_kr), trial


@pytest.mark.parametrize("backend", BACKENDS)
def test_selection_of_is_the_selection_of_the_jacobian(rng, backend):
    """``selection_of`` (the levels alone) says what ``selection_rows`` finds in the
    ``H`` of ``jacobian_into``, and ``residual_into`` writes ``innovation_into``'s ``y``."""
    quats = [rng.normal(size=4) for _ in range(3)]
    quats += [np.array([0.0, 0.0, 0.0, 1.0]), np.array([1e-200, 1e-200, 0.0, 1.0])]
    quats += [np.array([0.0, 0.0, 0.0, 0.0]), np.array([math.inf, 0.0, 0.0, 0.0])]
    with use_backend(backend):
        k = kernels_for(source)
        for n_dp in range(-1, 3):
            for n_do in range(-1, 3):
                for additive in (0, 1):
                    npl, nol, nx, nc = source.dims(n_dp, n_do, additive)
                    for lp in range(-1, n_dp + 1):
                        for lo in range(-1, n_do + 1):
                            if lp < 0 and lo < 0:
                                continue
                            m = k.residual_size(additive, lp, lo)
                            for q in quats:
                                x = rng.normal(size=nx)
                                if nol:
                                    x[3 * npl : 3 * npl + 4] = q
                                zp, zo = rng.normal(size=3), rng.normal(size=4)
                                y, h = np.empty(m), np.empty((m, nc))
                                y2 = np.empty(m)
                                idx, idx2 = np.empty(m, np.int64), np.empty(m, np.int64)
                                qa, qb = np.empty(4), np.empty(4)
                                case = (n_dp, n_do, additive, lp, lo, q)
                                with np.errstate(all="ignore"):
                                    k.residual_into(x, n_dp, n_do, additive, lp, lo, zp, zo,
                                                    y, h, qa, qb)  # fmt: skip
                                    k.innovation_into(x, n_dp, n_do, additive, lp, lo, zp, zo,
                                                      y2, qa, qb)  # fmt: skip
                                    found = k.selection_rows(h, idx)
                                known = k.selection_of(n_dp, n_do, additive, lp, lo, idx2)
                                assert found == known, case
                                assert _same_bits(y, y2), case
                                if known:
                                    assert list(idx) == list(idx2), case


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("additive", [0, 1])
def test_kept_process_noise_is_the_fresh_one(backend, additive):
    n_dp, n_do, kind = 2, 1, 0
    sp, so = np.array([0.0, 0.0, 3.0]), np.array([0.0, 2.0])
    npl, nol, nx, nc = source.dims(n_dp, n_do, additive)
    x = np.zeros(nx)
    x[3 * npl + 3] = 1.0
    with use_backend(backend):
        k = kernels_for(source)
        memo = np.zeros(2)
        qm, lv = np.full((nc, nc), 7.0), np.empty((3, 3))
        for dt in (0.004, 0.004, 0.0, -0.0, -0.0, math.nan, math.nan, 0.01, 0.004):
            fresh = np.full((nc, nc), 5.0)
            with np.errstate(all="ignore"):
                kernels_for(motion_kernels).process_noise_into(
                    x, dt, n_dp, n_do, additive, kind, sp, so, fresh, lv
                )
                k.process_noise_memo(x, dt, n_dp, n_do, additive, kind, sp, so, qm, lv, memo)
            assert qm.tobytes() == fresh.tobytes(), dt


@pytest.mark.parametrize("additive", [0, 1])
def test_bank_of_one_packet_equals_each_filter_alone(rng, additive):
    """``step_bank`` and ``predict_pose_bank`` with one time step for every row (a live
    packet: the process noise is computed once) give each filter's own bits."""
    n_dp, n_do = 1, 1
    k = kernels_for(source)
    c = k.constants(n_dp, n_do, additive, 0, np.array([0.0, 30.0]), np.array([0.0, 100.0]), 50.0)
    npl, nol, nx, nc = source.dims(n_dp, n_do, additive)
    nf, r = 5, np.diag([1e-6] * 3 + [1e-5] * 3)
    xs, ps = np.zeros((nf, nx)), np.zeros((nf, nc, nc))
    for i in range(nf):
        xs[i, 6] = 1.0
        xs[i, 3:6] = rng.normal(size=3)
        xs[i, 10:] = rng.normal(size=3)
        m = rng.normal(size=(nc, nc)) * 0.05
        ps[i] = m @ m.T + 1e-4 * np.eye(nc)
    size = k.log_size(n_dp, n_do, additive, 6)
    for dt in (1 / 240, 1 / 240, 0.0, 0.01):
        zp = xs[:, :3] + rng.normal(size=(nf, 3)) * 1e-3
        zo = xs[:, 6:10] / np.linalg.norm(xs[:, 6:10], axis=1)[:, None]
        alone_x, alone_p, alone_log = xs.copy(), ps.copy(), np.empty((nf, size))
        for i in range(nf):
            k.step_packed(alone_x[i], alone_p[i], dt, c, 0, 0, zp[i], zo[i], r, 30.0, alone_log[i])
        logs, status, nis = np.empty((nf, size)), np.empty(nf, np.int64), np.empty(nf)
        rows = frozen(np.arange(nf), np.int64)
        k.step_bank(xs, ps, rows, frozen(np.full(nf, dt)), frozen(c), frozen(zp), frozen(zo),
                    frozen(np.broadcast_to(r, (nf, 6, 6))), 30.0, logs, status, nis)  # fmt: skip
        assert xs.tobytes() == alone_x.tobytes() and ps.tobytes() == alone_p.tobytes()
        assert logs.tobytes() == alone_log.tobytes()
        out = np.empty((nf, source.POSE_OUT))
        k.predict_pose_bank(xs, ps, rows, frozen(np.full(nf, 0.02)), frozen(c), out)
        for i in range(nf):
            one = np.empty(source.POSE_OUT)
            k.predict_pose_packed(xs[i], ps[i], 0.02, c, one)
            assert one.tobytes() == out[i].tobytes()
