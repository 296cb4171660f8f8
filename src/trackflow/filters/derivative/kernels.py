"""Kernels of the thesis's pose Kalman filter on derivative motion models, written once.

A kernel source for :mod:`trackflow.math._backend` (plain Python on NumPy arrays, compiled by
numba when that backend is active; keep it numba-compatible: explicit loops, contiguous float64
arrays, no Python objects). SO(3) comes from :mod:`trackflow.math._lie`, small linear
algebra from :mod:`trackflow.math._scalar`, the gate and reset decisions from
:mod:`trackflow.filters.gating`.
Every allocating kernel is a thin wrapper of its in-place ``*_into`` twin, and one offline loop
(:func:`run`) serves both formulations with or without covariance output.

The filter's kernels live in three sources: the motion model (state sizes, transition, process
noise, prediction) in :mod:`.motion_kernels`, measurements and the Kalman update in
:mod:`.update_kernels`, and here what composes them: initialisation, the pose of a state, the
step and prediction of one filter and of a bank, smoothing and the offline loops.

State layout (``n_dp`` position and ``n_do`` orientation derivatives, ``-1`` = not estimated):

* nominal vector ``x``: ``t, t', ..., t^(n_dp)`` (3 each, frame a), then ``q`` (4, ``(x, y, z, w)``)
  and ``w, w', ..., w^(n_do - 1)`` (3 each, body frame b, rad/s^k); length
  ``3 (n_dp + 1) + 4 + 3 n_do`` = the thesis's ``7 + 3 (n_dp + n_do)``.
* error-state covariance (``additive = 0``): over ``dt^(i)`` (additive) and ``dtheta`` with
  ``R_true = R Exp(dtheta)`` (right perturbation, ``docs/conventions.md``) then the additive
  angular-derivative errors; size ``3 (n_dp + 1) + 3 (n_do + 1)``.
* additive formulation (``additive = 1``, thesis 6.2): covariance over the nominal vector itself,
  ``q_true = q + dq``.
"""

from __future__ import annotations

import math

import numpy as np

from trackflow.filters.derivative.motion_kernels import (
    dims,
    mean_transition_into,
    predict,
    predict_into,
    predict_scratch,
    process_noise,
    process_noise_memo,
    transition,
    transition_matrix_into,
)
from trackflow.filters.derivative.update_kernels import (
    inject,
    innovation_into,
    meas_cov,
    residual_into,
    residual_size,
    selection_of,
    selection_rows,
    update,  # noqa: F401 (no longer called here; kernels().update serves the streaming filter)
    update_dense,
    update_into,
    update_scratch,
)
from trackflow.filters.gating import (
    DIVERGED,
    INITIALIZED,
    INVALID,
    RESET,
    next_gated_run,
    reset_due,
)
from trackflow.math._lie import (
    left_mult,
    qrminus_into,
)
from trackflow.math._scalar import (
    chol,
    chol_solve,
    sym,
)

KERNELS = (
    "local",
    "initialize",
    "pose_of",
    "pose_mean_into",
    "predict_pose_into",
    "predict_pose_with",
    "predict_pose",
    "smooth",
    "step",
    "log_size",
    "step_into",
    "step_with",
    "constants",
    "step_packed",
    "predict_pose_packed",
    "step_bank",
    "predict_pose_bank",
    "step_predict_bank",
    "measurement_cov",
    "row_is_finite",
    "run",
    "smooth_run",
)
KERNEL_SOURCES = (
    "trackflow.math._scalar",
    "trackflow.math._lie",
    "trackflow.filters.gating",
    "trackflow.filters.derivative.motion_kernels",
    "trackflow.filters.derivative.update_kernels",
)
# Glue of one filter's step and prediction, inlined into their compiled callers
# (``trackflow.math._backend``): each passes 15 to 35 arrays on, and every array argument
# of a call costs two atomic reference-count operations, more than the glue's own work.
KERNELS_INLINE = ("step_with", "predict_pose_with")

UNKNOWN_VARIANCE = 1e12  # reported for a pose part the model does not estimate


def local(x1, x0, n_dp, n_do, additive):
    """``x1 [-] x0`` in the covariance coordinates (inverse of :func:`inject` for small steps)."""
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    qo = 3 * npl
    d = np.zeros(nc)
    for i in range(qo):
        d[i] = x1[i] - x0[i]
    if n_do < 0:
        return d
    if additive:
        s = 1.0
        if (
            x1[qo] * x0[qo]
            + x1[qo + 1] * x0[qo + 1]
            + x1[qo + 2] * x0[qo + 2]
            + x1[qo + 3] * x0[qo + 3]
            < 0.0
        ):
            s = -1.0
        for i in range(4):
            d[qo + i] = s * x1[qo + i] - x0[qo + i]
        for i in range(qo + 4, nx):
            d[i] = x1[i] - x0[i]
        return d
    qrminus_into(x1[qo : qo + 4], x0[qo : qo + 4], d[qo : qo + 3])
    for i in range(qo + 4, nx):
        d[i - 1] = x1[i] - x0[i]
    return d


def initialize(x, p, n_dp, n_do, additive, lp, lo, zp, zo, r):
    """First measurement: copy the measured part into the state, its noise into ``P``."""
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    qo = 3 * npl
    idx = np.zeros(8, np.int64)
    m = 0
    if lp >= 0:
        for k in range(3):
            x[3 * lp + k] = zp[k]
            idx[m] = 3 * lp + k
            m += 1
    if lo == 0:
        s = 1.0 if zo[3] >= 0.0 else -1.0
        for k in range(4):
            x[qo + k] = s * zo[k]
        for k in range(4 if additive else 3):
            idx[m] = qo + k
            m += 1
    elif lo >= 1:
        xo = qo + 4 + 3 * (lo - 1)
        co = xo if additive else qo + 3 * lo
        for k in range(3):
            x[xo + k] = zo[k]
            idx[m] = co + k
            m += 1
    for i in range(m):
        for j in range(nc):
            p[idx[i], j] = 0.0
            p[j, idx[i]] = 0.0
    for i in range(m):
        for j in range(m):
            p[idx[i], idx[j]] = r[i, j]


def pose_of(x, p, n_dp, n_do, additive):
    """Pose part of a state: ``(t (3), q (4), C (6x6))`` in trackflow's convention."""
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    qo = 3 * npl
    t = np.zeros(3)
    q = np.zeros(4)
    q[3] = 1.0
    c = np.zeros((6, 6))
    j = np.zeros((6, nc))  # d (dt, dtheta) / d covariance coordinates
    if npl > 0:
        for k in range(3):
            t[k] = x[k]
            j[k, k] = 1.0
    if nol > 0:
        q[:] = x[qo : qo + 4]
        if additive:
            n = math.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
            q /= n
            lt = left_mult(q).T  # L(q^*)
            for a in range(3):
                for b in range(4):
                    j[3 + a, qo + b] = 2.0 * lt[a, b] / n
        else:
            for k in range(3):
                j[3 + k, qo + k] = 1.0
    if additive:
        c[:, :] = j @ p @ j.T
    else:
        sel = np.empty(6, np.int64)
        for k in range(3):
            sel[k] = k if npl > 0 else -1
            sel[3 + k] = qo + k if nol > 0 else -1
        for a in range(6):
            for b in range(6):
                if sel[a] >= 0 and sel[b] >= 0:
                    c[a, b] = p[sel[a], sel[b]]
    if npl == 0:
        for k in range(3):
            c[k, k] = UNKNOWN_VARIANCE
    if nol == 0:
        for k in range(3, 6):
            c[k, k] = UNKNOWN_VARIANCE
    return t, q, sym(c)


def pose_mean_into(x, n_dp, n_do, additive, pos, quat):
    """Pose part of a nominal state into ``pos`` (3) and ``quat`` (4), as :func:`pose_of`."""
    npl = n_dp + 1 if n_dp >= 0 else 0
    for k in range(3):
        pos[k] = x[k] if npl > 0 else 0.0
    if n_do >= 0:
        qo = 3 * npl
        for k in range(4):
            quat[k] = x[qo + k]
        if additive:
            n = math.sqrt(quat[0] ** 2 + quat[1] ** 2 + quat[2] ** 2 + quat[3] ** 2)
            for k in range(4):
                quat[k] /= n
    else:
        quat[0], quat[1], quat[2], quat[3] = 0.0, 0.0, 0.0, 1.0


#: Length of :func:`predict_pose_into`'s output: position (3), quaternion (4), covariance (36).
POSE_OUT = 43


def predict_pose_into(x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o, out):
    """:func:`predict_pose` written into ``out`` (:data:`POSE_OUT`,): position, quaternion
    ``(x, y, z, w)`` and the 6x6 covariance row by row (one array to return to Python
    instead of three)."""
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    pos = out[:3]
    q = out[3:7]
    c = out[7:POSE_OUT].reshape((6, 6))
    if additive:
        xn, pn = predict(x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o)
        t3, q4, c6 = pose_of(xn, pn, n_dp, n_do, additive)
        pos[:] = t3
        q[:] = q4
        c[:, :] = c6
        return
    predict_pose_with(
        x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o, out,
        predict_scratch(n_dp, n_do, additive), np.empty((6, nc)), np.empty(6, np.int64),
    )  # fmt: skip


def predict_pose_with(x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o, out, pws, t, sel):
    """:func:`predict_pose_into` of the error-state formulation with its scratch arrays
    given: ``pws`` (:func:`predict_scratch`), ``t`` (6, nc) and ``sel`` (6,) int, so that a
    loop over many filters allocates them once."""
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    cf, b, d, xn, a, qm, lv = pws[0], pws[1], pws[2], pws[3], pws[4], pws[5], pws[6]
    mean_transition_into(x, dt, n_dp, n_do, xn, cf, b, d)
    transition_matrix_into(x, n_dp, n_do, additive, cf, b, d, a, pws[9])
    process_noise_memo(x, dt, n_dp, n_do, additive, kind, sig_p, sig_o, qm, lv, pws[11])
    qo = 3 * npl
    for k in range(3):
        sel[k] = k if npl > 0 else 0
        sel[3 + k] = qo + k if nol > 0 else 0
    for r in range(6):
        for k in range(nc):
            t[r, k] = 0.0
    for r in range(6):
        for k in range(nc):
            v = a[sel[r], k]
            if v != 0.0:
                for j in range(nc):
                    t[r, j] += v * p[k, j]
    co = 7  # the covariance in out, row by row: c[r, col] = out[co + 6 r + col]
    for r in range(6):
        for col in range(r, 6):
            w = qm[sel[r], sel[col]]
            for k in range(nc):
                w += t[r, k] * a[sel[col], k]
            out[co + 6 * r + col] = w
            out[co + 6 * col + r] = w
    for k in range(3):
        out[k] = xn[k] if npl > 0 else 0.0
        out[3 + k] = xn[qo + k] if nol > 0 else 0.0
    out[6] = xn[qo + 3] if nol > 0 else 1.0
    for lo, hi, known in ((0, 3, npl > 0), (3, 6, nol > 0)):
        if not known:
            for k in range(lo, hi):
                for j in range(6):
                    out[co + 6 * k + j] = 0.0
                    out[co + 6 * j + k] = 0.0
                out[co + 7 * k] = UNKNOWN_VARIANCE


def predict_pose(x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o):
    """Pose part of the prediction over ``dt``: ``(t, q, C)`` as :func:`pose_of` of
    :func:`predict`, computing only the pose rows of ``A P A^T + Q``."""
    out = np.empty(POSE_OUT)
    predict_pose_into(x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o, out)
    return out[:3], out[3:7], out[7:POSE_OUT].reshape((6, 6))


def smooth(x0, p0, t0, x1, p1, t1, t, n_dp, n_do, additive, kind, sig_p, sig_o):
    """State at ``t0 <= t <= t1`` from the filtered states at ``t0`` and ``t1``.

    One Rauch-Tung-Striebel step: predict forward ``t0 -> t`` (``x_f, P_f``) and ``t -> t1``
    (``x_m, P_m``, Jacobian ``A``), then ``x = x_f [+] G (x1 [-] x_m)``,
    ``P = P_f + G (P1 - P_m) G^T`` with ``G = P_f A^T P_m^-1``. The motion model only runs
    forwards in time.
    """
    xf, pf = predict(x0, p0, t - t0, n_dp, n_do, additive, kind, sig_p, sig_o)
    xm, a = transition(xf, t1 - t, n_dp, n_do, additive)
    pm = a @ pf @ a.T + process_noise(xf, t1 - t, n_dp, n_do, additive, kind, sig_p, sig_o)
    pm = sym(pm)
    lo, ok = chol(pm)
    if not ok:
        return xf, pf
    g = chol_solve(lo, (pf @ a.T).T).T
    d = local(x1, xm, n_dp, n_do, additive)
    xs = xf.copy()
    inject(xs, g @ d, n_dp, n_do, additive, 0.0, np.empty(4), np.empty(4))
    ps = pf + g @ (p1 - pm) @ g.T
    return xs, sym(ps)


def step(x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o, lp, lo, zp, zo, r, gate, wmax):
    """Streaming predict + update in place; returns ``(status, nis)``.

    On GATED ``x, p`` hold the prediction to the measurement time; on DIVERGED they are
    undefined (the caller resets the filter). :func:`step_into` without a record.
    """
    return step_into(
        x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o, lp, lo, zp, zo, r, gate, wmax,
        np.empty(0),
    )  # fmt: skip


def log_size(n_dp, n_do, additive, rows):
    """Length of a record of :func:`step_into` for a ``rows x rows`` measurement noise: the
    state ``x`` (nx), ``P`` (nc x nc, row by row), ``zp`` (3), ``zo`` (4) and ``r``."""
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    return nx + nc * nc + 7 + rows * rows


def step_into(
    x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o, lp, lo, zp, zo, r, gate, wmax, log
):
    """:func:`step`, also writing the measurement and the resulting state into the record
    ``log`` (:func:`log_size`; length 0 = no record): ``x``, ``P`` row by row, ``zp``,
    ``zo``, ``r`` row by row. ``zp``, ``zo`` and ``r`` may be views of ``log`` itself (a
    record applied again): they are read before the state is written.

    One compiled call per update instead of a call and five copies made from Python.
    """
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    m = residual_size(additive, lp, lo)
    return step_with(
        x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o, lp, lo, zp, zo, r, gate, wmax, log,
        predict_scratch(n_dp, n_do, additive), np.empty(m), np.empty((m, nc)),
        update_scratch(m, nc), np.empty(m, np.int64),
    )  # fmt: skip


def step_with(
    x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o, lp, lo, zp, zo, r, gate, wmax, log,
    pws, y, h, uws, idx,
):  # fmt: skip
    """:func:`step_into` with its scratch arrays given: ``pws`` (:func:`predict_scratch`),
    the innovation ``y`` (m,) and Jacobian ``h`` (m, nc) (:func:`residual_size`), ``uws``
    (:func:`update_scratch`) and ``idx`` (m,) int; a loop over many filters allocates them
    once. Every scratch array is written before it is read."""
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    if log.shape[0] > 0:
        o = nx + nc * nc
        for k in range(3):
            log[o + k] = zp[k]
        for k in range(4):
            log[o + 3 + k] = zo[k]
        rows = r.shape[0]
        for i in range(rows):
            for j in range(rows):
                log[o + 7 + i * rows + j] = r[i, j]
    predict_into(x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o, pws)
    # update_with, without writing H and searching it for a selection (known from the levels)
    if selection_of(n_dp, n_do, additive, lp, lo, idx):
        innovation_into(x, n_dp, n_do, additive, lp, lo, zp, zo, y, uws[10], uws[11])
        status, nis = update_into(
            x, p, y, measurement_cov(r, x, n_dp, lp, lo, additive), idx, gate, n_dp, n_do,
            additive, wmax, uws,
        )  # fmt: skip
    else:
        residual_into(x, n_dp, n_do, additive, lp, lo, zp, zo, y, h, uws[10], uws[11])
        status, nis = update_dense(
            x, p, y, h, measurement_cov(r, x, n_dp, lp, lo, additive), gate, n_dp, n_do,
            additive, wmax, uws,
        )  # fmt: skip
    if log.shape[0] > 0:
        for i in range(nx):
            log[i] = x[i]
        for i in range(nc):
            for j in range(nc):
                log[nx + i * nc + j] = p[i, j]
    return status, nis


def constants(n_dp, n_do, additive, kind, sig_p, sig_o, wmax):
    """A filter's constant parameters packed in one float array, made once: ``n_dp``,
    ``n_do``, ``additive``, ``kind``, ``wmax``, the lengths of ``sig_p`` and ``sig_o``, then
    their values. One array argument instead of seven makes a call from Python cheaper."""
    c = np.empty(7 + sig_p.shape[0] + sig_o.shape[0])
    c[0], c[1], c[2], c[3], c[4] = n_dp, n_do, additive, kind, wmax
    c[5], c[6] = sig_p.shape[0], sig_o.shape[0]
    for i in range(sig_p.shape[0]):
        c[7 + i] = sig_p[i]
    for i in range(sig_o.shape[0]):
        c[7 + sig_p.shape[0] + i] = sig_o[i]
    return c


def step_packed(x, p, dt, c, lp, lo, zp, zo, r, gate, log):
    """:func:`step_into` with the parameters of :func:`constants`."""
    n_sp = int(c[5])
    sp = c[7 : 7 + n_sp]
    so = c[7 + n_sp : 7 + n_sp + int(c[6])]
    return step_into(
        x, p, dt, int(c[0]), int(c[1]), int(c[2]), int(c[3]), sp, so, lp, lo, zp, zo, r, gate,
        c[4], log,
    )  # fmt: skip


def predict_pose_packed(x, p, dt, c, out):
    """:func:`predict_pose_into` with the parameters of :func:`constants`."""
    n_sp = int(c[5])
    sp = c[7 : 7 + n_sp]
    so = c[7 + n_sp : 7 + n_sp + int(c[6])]
    predict_pose_into(x, p, dt, int(c[0]), int(c[1]), int(c[2]), int(c[3]), sp, so, out)


def step_bank(xs, ps, rows, dts, c, zp, zo, r, gate, logs, status, nis):
    """:func:`step_packed` of pose measurements (``lp = lo = 0``) for several filters of
    one kind in one call: row ``k`` updates the state ``xs[rows[k]], ps[rows[k]]`` over
    ``dts[k]`` with ``zp[k], zo[k], r[k]`` and writes the record ``logs[k]``, its status
    and NIS into ``status[k], nis[k]``. The same operations, in the same order, as one
    :func:`step_packed` per filter."""
    n_dp, n_do, additive, kind, wmax = int(c[0]), int(c[1]), int(c[2]), int(c[3]), c[4]
    n_sp = int(c[5])
    sp = c[7 : 7 + n_sp]
    so = c[7 + n_sp : 7 + n_sp + int(c[6])]
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    m = residual_size(additive, 0, 0)
    pws = predict_scratch(n_dp, n_do, additive)  # scratch shared by the rows
    uws = update_scratch(m, nc)
    y = np.empty(m)
    h = np.empty((m, nc))
    idx = np.empty(m, np.int64)
    for k in range(rows.shape[0]):
        i = rows[k]
        s, v = step_with(
            xs[i], ps[i], dts[k], n_dp, n_do, additive, kind, sp, so, 0, 0, zp[k], zo[k], r[k],
            gate, wmax, logs[k], pws, y, h, uws, idx,
        )  # fmt: skip
        status[k] = s
        nis[k] = v


def predict_pose_bank(xs, ps, rows, dts, c, out):
    """:func:`predict_pose_packed` for several filters of one kind: row ``k`` predicts the
    state ``xs[rows[k]], ps[rows[k]]`` over ``dts[k]`` into ``out[k]`` (:data:`POSE_OUT`),
    the error-state formulation with scratch arrays shared by the rows."""
    n_dp, n_do, additive, kind = int(c[0]), int(c[1]), int(c[2]), int(c[3])
    if additive:
        for k in range(rows.shape[0]):
            i = rows[k]
            predict_pose_packed(xs[i], ps[i], dts[k], c, out[k])
        return
    n_sp = int(c[5])
    sp = c[7 : 7 + n_sp]
    so = c[7 + n_sp : 7 + n_sp + int(c[6])]
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    pws = predict_scratch(n_dp, n_do, additive)
    t = np.empty((6, nc))
    sel = np.empty(6, np.int64)
    for k in range(rows.shape[0]):
        i = rows[k]
        predict_pose_with(xs[i], ps[i], dts[k], n_dp, n_do, 0, kind, sp, so, out[k], pws, t, sel)


def step_predict_bank(xs, ps, rows, dts, c, zp, zo, r, gate, logs, status, nis, at, ts, out):
    """:func:`step_bank`, then :func:`predict_pose_bank` of the same rows at the time
    ``at`` [s] from their step times ``ts`` (row ``k`` ahead by ``at - ts[k]``) into
    ``out``: a packet's updates and its answers in one call from Python. A row whose step
    diverged is predicted too; the caller does not use its answer."""
    step_bank(xs, ps, rows, dts, c, zp, zo, r, gate, logs, status, nis)
    ahead = np.empty(rows.shape[0])
    for k in range(rows.shape[0]):
        ahead[k] = at - ts[k]
    predict_pose_bank(xs, ps, rows, ahead, c, out)


def measurement_cov(r, x, n_dp, lp, lo, additive):
    """Noise of a measurement in residual coordinates at the state ``x`` (:func:`meas_cov`)."""
    if not (additive and lo == 0):
        return r
    q = x[3 * (n_dp + 1 if n_dp >= 0 else 0) :][:4]
    n = math.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    return meas_cov(r, q / n, lp, lo, additive)


def row_is_finite(pos, quat, cov, i):
    """Whether measurement row ``i`` (position, quaternion and covariance) is all finite."""
    for k in range(3):
        if not np.isfinite(pos[i, k]):
            return False
    for k in range(4):
        if not np.isfinite(quat[i, k]):
            return False
    for a in range(6):
        for b in range(6):
            if not np.isfinite(cov[i, a, b]):
                return False
    return True


def run(
    times, pos, quat, cov, horizons, x, p, n_dp, n_do, additive, kind, sig_p, sig_o,
    gate, wmax, reset_after, covariance, out_t, out_q, out_c, pred_t, pred_q, pred_c, nis, status,
    out_x, out_p,
):  # fmt: skip
    """Offline run over time-sorted pose measurements; fills the output arrays.

    ``out_x, out_p`` (N, nx) and (N, nc, nc), or empty: the whole filter state after each
    measurement (the prediction where a row was skipped), for :func:`smooth_run`.

    ``x, p`` hold the initial (uninitialised) state. Rows with non-finite values are skipped
    (status INVALID) and get the prediction; gating and resets follow
    :mod:`trackflow.filters.gating`. With ``covariance = False`` the pose covariances are not
    computed (``out_c`` and ``pred_c`` are not touched and may be empty) and the loop allocates
    nothing per measurement, which makes parameter searches over whole recordings cheap.
    """
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    lp = 0 if n_dp >= 0 else -1
    lo = 0 if n_do >= 0 else -1
    m = residual_size(additive, lp, lo)
    mr = (3 if lp >= 0 else 0) + (3 if lo >= 0 else 0)  # rows of the measured block of cov[i]
    roff = 0 if lp >= 0 else 3
    x0 = x.copy()
    p0 = p.copy()
    pws = predict_scratch(n_dp, n_do, additive)
    uws = update_scratch(m, nc)
    y = np.empty(m)
    h = np.empty((m, nc))
    idx = np.empty(m, np.int64)
    r = np.empty((mr, mr))
    xs = np.empty(nx)
    ps = np.empty((nc, nc))
    zq = np.empty(4)  # the measured quaternion, writeable (meas_cov's one argument type)
    pout = np.empty(POSE_OUT)  # predict_pose_with's output and scratch (error state)
    tsc = np.empty((6, nc))
    sel = np.empty(6, np.int64)
    initialized = False
    t_state = 0.0
    gated_run = 0
    for i in range(times.shape[0]):
        zp = pos[i]
        zo = quat[i]
        for k in range(mr):
            for j in range(mr):
                r[k, j] = cov[i, roff + k, roff + j]
        xs[:] = x
        ps[:, :] = p
        if not row_is_finite(pos, quat, cov, i):
            status[i] = INVALID
            if initialized and covariance:
                predict_into(
                    xs, ps, times[i] - t_state, n_dp, n_do, additive, kind, sig_p, sig_o, pws
                )
            elif initialized:
                mean_transition_into(x, times[i] - t_state, n_dp, n_do, xs, pws[0], pws[1], pws[2])
        elif reset_due(initialized, gated_run, reset_after):
            status[i] = RESET if initialized else INITIALIZED
            x[:] = x0
            p[:, :] = p0
            for k in range(4):
                zq[k] = zo[k]
            initialize(
                x, p, n_dp, n_do, additive, lp, lo, zp, zo, meas_cov(r, zq, lp, lo, additive)
            )
            t_state = times[i]
            initialized = True
            gated_run = 0
            nis[i] = np.nan
        else:
            predict_into(x, p, times[i] - t_state, n_dp, n_do, additive, kind, sig_p, sig_o, pws)
            residual_into(x, n_dp, n_do, additive, lp, lo, zp, zo, y, h, uws[10], uws[11])
            rr = measurement_cov(r, x, n_dp, lp, lo, additive)
            if selection_rows(h, idx):
                st, v = update_into(x, p, y, rr, idx, gate, n_dp, n_do, additive, wmax, uws)
            else:
                st, v = update_dense(x, p, y, h, rr, gate, n_dp, n_do, additive, wmax, uws)
            t_state = times[i]
            status[i] = st
            nis[i] = v
            if st == DIVERGED:
                x[:] = x0
                p[:, :] = p0
                for k in range(4):
                    zq[k] = zo[k]
                initialize(
                    x, p, n_dp, n_do, additive, lp, lo, zp, zo, meas_cov(r, zq, lp, lo, additive)
                )
            gated_run = next_gated_run(st, gated_run)
        if status[i] != INVALID:
            xs[:] = x
            ps[:, :] = p
        if out_x.shape[0] > 0:
            out_x[i] = xs
            out_p[i] = ps
        if covariance:
            t, q, c = pose_of(xs, ps, n_dp, n_do, additive)
            out_t[i] = t
            out_q[i] = q
            out_c[i] = c
        else:
            pose_mean_into(xs, n_dp, n_do, additive, out_t[i], out_q[i])
        for hz in range(horizons.shape[0]):
            if not initialized:
                pred_t[hz, i] = out_t[i]
                pred_q[hz, i] = out_q[i]
                if covariance:
                    pred_c[hz, i] = out_c[i]
                continue
            dt = times[i] - t_state + horizons[hz]
            if covariance and additive:  # predict_pose_into, with run's scratch arrays
                xs[:] = x
                ps[:, :] = p
                predict_into(xs, ps, dt, n_dp, n_do, additive, kind, sig_p, sig_o, pws)
                t, q, c = pose_of(xs, ps, n_dp, n_do, additive)
                pred_t[hz, i] = t
                pred_q[hz, i] = q
                pred_c[hz, i] = c
            elif covariance:
                predict_pose_with(
                    x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o, pout, pws, tsc, sel
                )
                for k in range(3):
                    pred_t[hz, i, k] = pout[k]
                for k in range(4):
                    pred_q[hz, i, k] = pout[3 + k]
                for a in range(6):
                    for b in range(6):
                        pred_c[hz, i, a, b] = pout[7 + 6 * a + b]
            else:
                mean_transition_into(x, dt, n_dp, n_do, xs, pws[0], pws[1], pws[2])
                pose_mean_into(xs, n_dp, n_do, additive, pred_t[hz, i], pred_q[hz, i])


def smooth_run(
    times, xs, ps, status, queries, n_dp, n_do, additive, kind, sig_p, sig_o, out_t, out_q, out_c
):  # fmt: skip
    """Rauch-Tung-Striebel smoothing of a whole run, answered at sorted query times.

    ``xs, ps`` (N, nx), (N, nc, nc): the filtered states of :func:`run` (``out_x, out_p``),
    overwritten from the newest backwards by the smoothed ones. A segment (from one
    initialisation or reset to the next) is smoothed on its own: its newest state is its own
    smoothed state. A query between two states of one segment is one :func:`smooth` step
    from the filtered state before it to the smoothed state after it; a query at a state is
    that smoothed state; a query after the newest state of a segment is predicted from it.
    ``queries`` (Q,) must be ascending; those before ``times[0]`` are left unanswered.

    Returns
    -------
    int
        The number of queries answered (the newest ones), written to ``out_t`` (Q, 3),
        ``out_q`` (Q, 4) and ``out_c`` (Q, 6, 6).
    """
    n = times.shape[0]
    j = queries.shape[0] - 1
    answered = 0
    for i in range(n - 1, -1, -1):
        ends = i + 1 >= n or status[i + 1] == INITIALIZED or status[i + 1] == RESET
        ends = ends or status[i + 1] == DIVERGED
        while j >= 0 and queries[j] > times[i]:  # strictly between state i and state i + 1
            if ends:
                x, p = predict(xs[i], ps[i], queries[j] - times[i], n_dp, n_do, additive,
                               kind, sig_p, sig_o)  # fmt: skip
            else:
                x, p = smooth(xs[i], ps[i], times[i], xs[i + 1], ps[i + 1], times[i + 1],
                              queries[j], n_dp, n_do, additive, kind, sig_p, sig_o)  # fmt: skip
            out_t[j], out_q[j], out_c[j] = pose_of(x, p, n_dp, n_do, additive)
            j -= 1
            answered += 1
        if not ends:
            x, p = smooth(xs[i], ps[i], times[i], xs[i + 1], ps[i + 1], times[i + 1], times[i],
                          n_dp, n_do, additive, kind, sig_p, sig_o)  # fmt: skip
            xs[i] = x
            ps[i] = p
        while j >= 0 and queries[j] == times[i]:
            out_t[j], out_q[j], out_c[j] = pose_of(xs[i], ps[i], n_dp, n_do, additive)
            j -= 1
            answered += 1
    return answered
