"""Kernels of the pose Kalman filter, written once for both backends.

This module is plain Python on NumPy arrays. ``_backend.py`` loads it a second time and
compiles every function listed in ``KERNELS`` with ``numba.njit(cache=True)``; the plain copy is
the NumPy reference path. Keep the code numba-compatible: explicit loops, contiguous float64
arrays, no Python objects.

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

KERNELS = (
    "sym",
    "fact",
    "dims",
    "qmul",
    "qexp",
    "qlog",
    "rotmat",
    "right_jac",
    "left_mult",
    "right_mult",
    "exp_jac",
    "level_noise",
    "transition",
    "process_noise",
    "sandwich",
    "sandwich_into",
    "predict",
    "residual",
    "meas_cov",
    "chol",
    "chol_solve",
    "chol_solve_rows",
    "joseph_selection",
    "update",
    "inject",
    "local",
    "initialize",
    "pose_of",
    "predict_pose",
    "smooth",
    "step",
    "row_is_finite",
    "run",
    "qmul_into",
    "qexp_into",
    "mean_transition_into",
    "level_noise_into",
    "predict_cov_into",
    "update_into",
    "update_scratch",
    "pose_mean_into",
    "run_means",
    "twist_ar_top",
    "twist_ar_top_into",
    "twist_ar_run",
)

SMALL = 1e-4
UNKNOWN_VARIANCE = 1e12  # reported for a pose part the model does not estimate
# Covariance entries below this are flushed to zero: cross terms that are zero in theory
# otherwise decay into denormal numbers, which make every later operation ~10x slower.
TINY = 1e-150

# status codes of an update
ACCEPTED = 0
GATED = 1
DIVERGED = 2
INVALID = 3
INITIALIZED = 4
RESET = 5


def sym(a):
    """``(A + A^T) / 2`` as a new C-contiguous array."""
    n = a.shape[0]
    out = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            out[i, j] = 0.5 * (a[i, j] + a[j, i])
    return out


def fact(k):
    r = 1.0
    for i in range(2, k + 1):
        r *= i
    return r


def dims(n_dp, n_do, additive):
    """(position levels, orientation levels, nominal size, covariance size)."""
    npl = n_dp + 1 if n_dp >= 0 else 0
    nol = n_do + 1 if n_do >= 0 else 0
    nx = 3 * npl + (4 + 3 * n_do if n_do >= 0 else 0)
    nc = nx if additive else 3 * npl + 3 * nol
    return npl, nol, nx, nc


# -- quaternion helpers (scalar, (x, y, z, w)) -----------------------------------------------


def qmul(a, b):
    out = np.empty(4)
    out[0] = a[3] * b[0] + a[0] * b[3] + a[1] * b[2] - a[2] * b[1]
    out[1] = a[3] * b[1] - a[0] * b[2] + a[1] * b[3] + a[2] * b[0]
    out[2] = a[3] * b[2] + a[0] * b[1] - a[1] * b[0] + a[2] * b[3]
    out[3] = a[3] * b[3] - a[0] * b[0] - a[1] * b[1] - a[2] * b[2]
    return out


def qexp(v):
    t2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    out = np.empty(4)
    if t2 < SMALL * SMALL:
        k = 0.5 - t2 / 48.0
        out[3] = 1.0 - t2 / 8.0 + t2 * t2 / 384.0
    else:
        t = math.sqrt(t2)
        k = math.sin(0.5 * t) / t
        out[3] = math.cos(0.5 * t)
    out[0] = k * v[0]
    out[1] = k * v[1]
    out[2] = k * v[2]
    return out


def qlog(q):
    s = -1.0 if q[3] < 0.0 else 1.0
    w = s * q[3]
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2])
    if n < 0.5 * SMALL:
        k = 2.0 / w * (1.0 - n * n / (3.0 * w * w))
    else:
        k = 2.0 * math.atan2(n, w) / n
    out = np.empty(3)
    out[0] = s * k * q[0]
    out[1] = s * k * q[1]
    out[2] = s * k * q[2]
    return out


def rotmat(q):
    x, y, z, w = q[0], q[1], q[2], q[3]
    r = np.empty((3, 3))
    r[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    r[0, 1] = 2.0 * (x * y - w * z)
    r[0, 2] = 2.0 * (x * z + w * y)
    r[1, 0] = 2.0 * (x * y + w * z)
    r[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    r[1, 2] = 2.0 * (y * z - w * x)
    r[2, 0] = 2.0 * (x * z - w * y)
    r[2, 1] = 2.0 * (y * z + w * x)
    r[2, 2] = 1.0 - 2.0 * (x * x + y * y)
    return r


def right_jac(v):
    """SO(3) right Jacobian ``Jr(v)``: ``Exp(v + d) ~ Exp(v) Exp(Jr(v) d)``."""
    t2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    if t2 < SMALL * SMALL:
        a = 0.5 - t2 / 24.0
        b = 1.0 / 6.0 - t2 / 120.0
    else:
        t = math.sqrt(t2)
        a = (1.0 - math.cos(t)) / t2
        b = (t - math.sin(t)) / (t2 * t)
    # Jr = I - a [v]x + b [v]x^2 with [v]x^2 = v v^T - |v|^2 I
    j = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            j[r, c] = b * v[r] * v[c]
        j[r, r] += 1.0 - b * t2
    j[0, 1] += a * v[2]
    j[0, 2] -= a * v[1]
    j[1, 0] -= a * v[2]
    j[1, 2] += a * v[0]
    j[2, 0] += a * v[1]
    j[2, 1] -= a * v[0]
    return j


def left_mult(q):
    """``L(q)`` with ``q * p = L(q) p``."""
    m = np.empty((4, 4))
    x, y, z, w = q[0], q[1], q[2], q[3]
    m[0, 0], m[0, 1], m[0, 2], m[0, 3] = w, -z, y, x
    m[1, 0], m[1, 1], m[1, 2], m[1, 3] = z, w, -x, y
    m[2, 0], m[2, 1], m[2, 2], m[2, 3] = -y, x, w, z
    m[3, 0], m[3, 1], m[3, 2], m[3, 3] = -x, -y, -z, w
    return m


def right_mult(d):
    """``M(d)`` with ``q * d = M(d) q`` (the upper-left block of the thesis's ``A_R``)."""
    m = np.empty((4, 4))
    x, y, z, w = d[0], d[1], d[2], d[3]
    m[0, 0], m[0, 1], m[0, 2], m[0, 3] = w, z, -y, x
    m[1, 0], m[1, 1], m[1, 2], m[1, 3] = -z, w, x, y
    m[2, 0], m[2, 1], m[2, 2], m[2, 3] = y, -x, w, z
    m[3, 0], m[3, 1], m[3, 2], m[3, 3] = -x, -y, -z, w
    return m


def exp_jac(b):
    """``d Exp(b) / d b`` (4x3); at ``b = 0`` the limit ``[I/2; 0]`` (thesis's B-tilde)."""
    t2 = b[0] * b[0] + b[1] * b[1] + b[2] * b[2]
    j = np.zeros((4, 3))
    if t2 < SMALL * SMALL:
        s = 0.5 - t2 / 48.0  # sin(t/2)/t
        ds = -1.0 / 24.0 + t2 / 960.0  # (d s / d t) / t
        dw = -0.25 + t2 / 96.0  # (d cos(t/2) / d t) / t
    else:
        t = math.sqrt(t2)
        sn = math.sin(0.5 * t)
        cs = math.cos(0.5 * t)
        s = sn / t
        ds = (0.5 * cs * t - sn) / (t2 * t)
        dw = -0.5 * sn / t
    for i in range(3):
        for k in range(3):
            j[i, k] = ds * b[i] * b[k]
        j[i, i] += s
        j[3, i] = dw * b[i]
    return j


# -- motion model -------------------------------------------------------------------------------


def level_noise(n, sig, dt, kind):
    """Process-noise matrix over derivative levels ``0..n-1`` for one axis.

    ``kind = 0``: continuous white noise of spectral density ``sig[l]^2`` driving level ``l``,
    integrated exactly over ``dt`` (Ude eq. 23 generalised). ``kind = 1``: thesis eq. 6.21,
    ``diag((sig[l] dt)^2)``.
    """
    m = np.zeros((n, n))
    if kind == 1:
        for i in range(n):
            m[i, i] = (sig[i] * dt) ** 2
        return m
    for i in range(n):
        for j in range(n):
            s = 0.0
            for lvl in range(max(i, j), n):
                e = 2 * lvl - i - j + 1
                s += sig[lvl] ** 2 * dt**e / (fact(lvl - i) * fact(lvl - j) * e)
            m[i, j] = s
    return m


def transition(x, dt, n_dp, n_do, additive):
    """Motion-model prediction over ``dt``: returns ``(x_new, A)``.

    Position: Taylor series (thesis eq. 6.18). Orientation: ``q_new = q * Exp(b)`` with
    ``b = sum_l w^(l-1) dt^l / l!`` (eq. 6.19). ``A`` is the Jacobian of the covariance
    coordinates: error state ``dtheta_new = Exp(b)^T dtheta + Jr(b) db``, or, additive, the
    thesis's ``A_R`` with ``M(d)`` and ``B = L(q) dExp/db``.
    """
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    xn = np.zeros(nx)
    a = np.zeros((nc, nc))
    cf = np.empty(max(npl, nol) + 1)  # dt^k / k!
    cf[0] = 1.0
    for i in range(1, cf.shape[0]):
        cf[i] = cf[i - 1] * dt / i
    for i in range(npl):
        for j in range(i, npl):
            c = cf[j - i]
            for k in range(3):
                xn[3 * i + k] += c * x[3 * j + k]
                a[3 * i + k, 3 * j + k] = c
    if n_do < 0:
        return xn, a
    qo = 3 * npl
    q = x[qo : qo + 4].copy()
    b = np.zeros(3)
    for lv in range(1, n_do + 1):
        c = cf[lv]
        for k in range(3):
            b[k] += c * x[qo + 4 + 3 * (lv - 1) + k]
    d = qexp(b)
    xn[qo : qo + 4] = qmul(q, d)
    for lv in range(1, n_do + 1):
        for j in range(lv, n_do + 1):
            c = cf[j - lv]
            for k in range(3):
                xn[qo + 4 + 3 * (lv - 1) + k] += c * x[qo + 4 + 3 * (j - 1) + k]
    if additive:
        a[qo : qo + 4, qo : qo + 4] = right_mult(d)
        bm = left_mult(q) @ exp_jac(b)
        for lv in range(1, n_do + 1):
            c = cf[lv]
            a[qo : qo + 4, qo + 4 + 3 * (lv - 1) : qo + 4 + 3 * lv] = c * bm
        base = qo + 4 - 3  # angular level lv sits at base + 3 lv
    else:
        r = rotmat(d)
        a[qo : qo + 3, qo : qo + 3] = r.T
        jr = right_jac(b)
        for lv in range(1, n_do + 1):
            c = cf[lv]
            a[qo : qo + 3, qo + 3 * lv : qo + 3 * lv + 3] = c * jr
        base = qo
    for lv in range(1, n_do + 1):
        for j in range(lv, n_do + 1):
            c = cf[j - lv]
            for k in range(3):
                a[base + 3 * lv + k, base + 3 * j + k] = c
    return xn, a


def process_noise(x, dt, n_dp, n_do, additive, kind, sig_p, sig_o):
    """Process-noise covariance ``Q`` in the covariance coordinates (see :func:`level_noise`).

    The additive formulation maps the rotation-vector noise onto the quaternion with
    ``dq = L(q)[:, :3] dtheta / 2`` and adds the same variance along ``q`` itself, which makes the
    quaternion block isotropic (``(sig dt / 2)^2 I_4`` for the thesis's diagonal model).
    """
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    qm = np.zeros((nc, nc))
    if npl > 0:
        mp = level_noise(npl, sig_p, dt, kind)
        for i in range(npl):
            for j in range(npl):
                for k in range(3):
                    qm[3 * i + k, 3 * j + k] = mp[i, j]
    if nol == 0:
        return qm
    mo = level_noise(nol, sig_o, dt, kind)
    eo = 3 * npl
    if not additive:
        for i in range(nol):
            for j in range(nol):
                for k in range(3):
                    qm[eo + 3 * i + k, eo + 3 * j + k] = mo[i, j]
        return qm
    g = 0.5 * left_mult(x[eo : eo + 4])[:, :3]
    q = x[eo : eo + 4]
    qq = g @ g.T * mo[0, 0]
    for r in range(4):
        for c in range(4):
            qq[r, c] += 0.25 * mo[0, 0] * q[r] * q[c]
    qm[eo : eo + 4, eo : eo + 4] = qq
    for j in range(1, nol):
        col = eo + 4 + 3 * (j - 1)
        blk = g * mo[0, j]
        qm[eo : eo + 4, col : col + 3] = blk
        qm[col : col + 3, eo : eo + 4] = blk.T
        for i in range(1, nol):
            row = eo + 4 + 3 * (i - 1)
            for k in range(3):
                qm[row + k, col + k] = mo[i, j]
    return qm


def sandwich(a, p, q):
    """``A P A^T + Q`` (symmetric) as a new array; see :func:`sandwich_into`."""
    n = p.shape[0]
    out = p.copy()
    sandwich_into(a, out, q, np.empty((n, n)), np.empty((n, n)))
    return out


def sandwich_into(a, p, q, tmp, out):
    """``p <- A P A^T + Q`` (symmetric) in place, skipping the zeros of the sparse ``A``.

    ``tmp`` and ``out`` (n x n) are scratch.
    """
    n = p.shape[0]
    for i in range(n):
        for j in range(n):
            tmp[i, j] = 0.0
            out[i, j] = 0.0
    for i in range(n):
        for k in range(n):
            v = a[i, k]
            if v != 0.0:
                for j in range(n):
                    tmp[i, j] += v * p[k, j]
    for j in range(n):
        for k in range(n):
            v = a[j, k]
            if v != 0.0:
                for i in range(j + 1):
                    out[i, j] += tmp[i, k] * v
    for j in range(n):
        for i in range(j + 1):
            w = out[i, j] + 0.5 * (q[i, j] + q[j, i])
            if abs(w) < TINY:
                w = 0.0
            p[i, j] = w
            p[j, i] = w


def predict(x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o):
    """Time update: ``x = f(x)``, ``P = A P A^T + Q`` (thesis eqs. 5.59-5.60), new arrays."""
    xn, a = transition(x, dt, n_dp, n_do, additive)
    qm = process_noise(x, dt, n_dp, n_do, additive, kind, sig_p, sig_o)
    return xn, sandwich(a, p, qm)


# -- measurements ----------------------------------------------------------------------------


def residual(x, n_dp, n_do, additive, lp, lo, zp, zo):
    """Innovation ``y = z - h(x)`` and measurement Jacobian ``H`` (``y ~ H e + v``).

    ``lp``/``lo``: measured position / orientation derivative level (thesis 6.3.2), ``-1`` =
    not measured. Orientation (``lo = 0``) residual: error state ``Log(q^* z_q)`` with
    ``H = I``; additive ``z_q - q/|q|`` (``z_q`` sign-aligned to ``q``) with ``H_R`` of eq. 6.23.
    """
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    m = 0
    if lp >= 0:
        m += 3
    if lo >= 0:
        m += 4 if (additive and lo == 0) else 3
    y = np.zeros(m)
    h = np.zeros((m, nc))
    r = 0
    if lp >= 0:
        for k in range(3):
            y[k] = zp[k] - x[3 * lp + k]
            h[k, 3 * lp + k] = 1.0
        r = 3
    if lo < 0:
        return y, h
    qo = 3 * npl
    q = x[qo : qo + 4]
    if lo >= 1:
        xo = qo + 4 + 3 * (lo - 1)
        co = xo if additive else qo + 3 * lo
        for k in range(3):
            y[r + k] = zo[k] - x[xo + k]
            h[r + k, co + k] = 1.0
        return y, h
    if not additive:
        qc = np.empty(4)
        qc[0], qc[1], qc[2], qc[3] = -q[0], -q[1], -q[2], q[3]
        e = qlog(qmul(qc, zo))
        for k in range(3):
            y[r + k] = e[k]
            h[r + k, qo + k] = 1.0
        return y, h
    dd = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]
    ll = math.sqrt(dd)
    s = 1.0
    if zo[0] * q[0] + zo[1] * q[1] + zo[2] * q[2] + zo[3] * q[3] < 0.0:
        s = -1.0
    for i in range(4):
        y[r + i] = s * zo[i] - q[i] / ll
        for j in range(4):
            h[r + i, qo + j] = ((dd if i == j else 0.0) - q[i] * q[j]) / (ll * dd)
    return y, h


def meas_cov(c, q, lp, lo, additive):
    """Measurement noise in residual coordinates from the caller's covariance ``c``.

    ``c`` is 3x3 (one part) or 6x6 (position and orientation, conventions.md order). For the
    additive orientation it becomes 4x4 / 7x7 via ``V [[C, 0], [0, 1]] V^T`` (eqs. 6.24-6.25),
    ``V`` mapping ``dtheta`` to ``dq = L(q)[:, :3] dtheta / 2`` and the unit scalar along ``q``.
    """
    if not (additive and lo == 0):
        return c.copy()
    m = c.shape[0] + 1
    v = np.zeros((m, c.shape[0] + 1))
    r = 0
    if lp >= 0:
        for k in range(3):
            v[k, k] = 1.0
        r = 3
    lq = left_mult(q)
    for i in range(4):
        for j in range(3):
            v[r + i, r + j] = 0.5 * lq[i, j]
        v[r + i, r + 3] = q[i]
    ce = np.zeros((m, m))
    ce[: c.shape[0], : c.shape[0]] = c
    ce[m - 1, m - 1] = 1.0
    return sym(v @ ce @ v.T)


def chol(s):
    """Lower Cholesky factor; ``ok = False`` if ``s`` is not positive definite."""
    n = s.shape[0]
    lo = np.zeros((n, n))
    for j in range(n):
        d = s[j, j]
        for k in range(j):
            d -= lo[j, k] * lo[j, k]
        if not d > 0.0:
            return lo, False
        lo[j, j] = math.sqrt(d)
        for i in range(j + 1, n):
            v = s[i, j]
            for k in range(j):
                v -= lo[i, k] * lo[j, k]
            lo[i, j] = v / lo[j, j]
    return lo, True


def chol_solve(lo, b):
    """Solve ``L L^T X = B`` for ``B`` of shape (n, k)."""
    n = lo.shape[0]
    x = b.copy()
    for c in range(b.shape[1]):
        for i in range(n):
            v = x[i, c]
            for k in range(i):
                v -= lo[i, k] * x[k, c]
            x[i, c] = v / lo[i, i]
        for i in range(n - 1, -1, -1):
            v = x[i, c]
            for k in range(i + 1, n):
                v -= lo[k, i] * x[k, c]
            x[i, c] = v / lo[i, i]
    return x


def chol_solve_rows(lo, b):
    """Solve ``L L^T X = B`` in place for ``B`` of shape (n, k), row operations (contiguous)."""
    n = lo.shape[0]
    k = b.shape[1]
    for i in range(n):
        for j in range(i):
            f = lo[i, j]
            for c in range(k):
                b[i, c] -= f * b[j, c]
        d = 1.0 / lo[i, i]
        for c in range(k):
            b[i, c] *= d
    for i in range(n - 1, -1, -1):
        for j in range(i + 1, n):
            f = lo[j, i]
            for c in range(k):
                b[i, c] -= f * b[j, c]
        d = 1.0 / lo[i, i]
        for c in range(k):
            b[i, c] *= d


def inject(x, delta, n_dp, n_do, additive, wmax):
    """Apply a correction in the covariance coordinates (``x <- x [+] delta``) in place.

    Error state: ``q <- q Exp(dtheta)``; additive: ``q <- q + dq``; then ``q`` is normalised and
    the angular velocity clipped to ``|w| <= wmax`` (if ``wmax > 0``), which changes the mean
    only: the covariance stays symmetric positive definite.
    """
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    qo = 3 * npl
    for i in range(qo):
        x[i] += delta[i]
    if n_do < 0:
        return
    if additive:
        for i in range(qo, nx):
            x[i] += delta[i]
    else:
        x[qo : qo + 4] = qmul(x[qo : qo + 4].copy(), qexp(delta[qo : qo + 3]))
        for i in range(qo + 4, nx):
            x[i] += delta[i - 1]
    n = math.sqrt(x[qo] ** 2 + x[qo + 1] ** 2 + x[qo + 2] ** 2 + x[qo + 3] ** 2)
    for i in range(4):
        x[qo + i] /= n
    if n_do >= 1 and wmax > 0.0:
        w = x[qo + 4 : qo + 7]
        wn = math.sqrt(w[0] ** 2 + w[1] ** 2 + w[2] ** 2)
        if wn > wmax:
            for i in range(3):
                x[qo + 4 + i] *= wmax / wn


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
    qc = x0[qo : qo + 4].copy()
    qc[0], qc[1], qc[2] = -qc[0], -qc[1], -qc[2]
    d[qo : qo + 3] = qlog(qmul(qc, x1[qo : qo + 4]))
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


def joseph_selection(p, kt, kr, hp, idx, mp, g, acc):
    """Joseph-form covariance update for a measurement that selects state rows ``idx``.

    ``(I - K H) P (I - K H)^T + K R K^T = MP + (K R - MP H^T) K^T`` with ``MP = P - K (H P)``:
    it keeps ``P`` symmetric positive definite even when ``K`` is not exactly optimal
    (rounding, gating, clipped angular velocity). ``kt`` is ``K^T``, ``kr`` is ``K R`` and
    ``hp`` is ``H P``; ``mp``, ``g`` and ``acc`` are scratch buffers. Writes ``P`` in place,
    upper triangle mirrored.
    """
    nc = p.shape[0]
    m = kt.shape[0]
    for i in range(nc):
        for j in range(nc):
            mp[i, j] = p[i, j]
    for i in range(nc):
        for a in range(m):
            ka = kt[a, i]
            for j in range(nc):
                mp[i, j] -= ka * hp[a, j]
    for i in range(nc):
        for a in range(m):
            g[a] = kr[i, a] - mp[i, idx[a]]
        for j in range(nc):
            acc[j] = mp[i, j]
        for a in range(m):
            ga = g[a]
            for j in range(nc):
                acc[j] += ga * kt[a, j]
        for j in range(i, nc):
            w = acc[j]
            if abs(w) < TINY:
                w = 0.0
            p[i, j] = w
            p[j, i] = w


def update(x, p, y, h, r, gate, n_dp, n_do, additive, wmax):
    """EKF measurement update in place (thesis eqs. 5.61-5.63); returns ``(status, nis)``.

    ``status``: ACCEPTED, GATED (``nis > gate``; state untouched) or DIVERGED (singular
    innovation covariance or a non-finite result; the caller resets the filter).
    """
    nc = p.shape[0]
    m = y.shape[0]
    # H is a plain selection of state entries (error state, additive non-quaternion parts):
    # exploit it; otherwise (additive quaternion normalisation) use dense products.
    idx = np.empty(m, np.int64)
    selection = True
    for row in range(m):
        idx[row] = -1
        for c in range(nc):
            if h[row, c] != 0.0:
                if h[row, c] == 1.0 and idx[row] < 0:
                    idx[row] = c
                else:
                    selection = False
        if idx[row] < 0:
            selection = False
    if selection:
        hp = np.empty((m, nc))  # H P: rows idx of P
        for a in range(m):
            for j in range(nc):
                hp[a, j] = p[idx[a], j]
        s = np.empty((m, m))
        for a in range(m):
            for b in range(m):
                s[a, b] = 0.5 * (hp[a, idx[b]] + hp[b, idx[a]]) + 0.5 * (r[a, b] + r[b, a])
    else:
        hp = h @ p
        s = sym(hp @ h.T + r)
    lo, ok = chol(s)
    if not ok:
        return DIVERGED, np.nan
    sy = y.reshape((m, 1)).copy()
    chol_solve_rows(lo, sy)
    nis = 0.0
    for i in range(m):
        nis += y[i] * sy[i, 0]
    if not np.isfinite(nis):
        return DIVERGED, nis
    if nis > gate:
        return GATED, nis
    kt = hp.copy()  # K^T = S^-1 H P
    chol_solve_rows(lo, kt)
    delta = np.zeros(nc)
    for a in range(m):
        for i in range(nc):
            delta[i] += kt[a, i] * y[a]
    kr = np.zeros((nc, m))  # K R
    for i in range(nc):
        for a in range(m):
            for b in range(m):
                kr[i, b] += kt[a, i] * r[a, b]
    # Joseph form (I - K H) P (I - K H)^T + K R K^T: keeps P symmetric positive definite even
    # when K is not exactly optimal (rounding, gating, clipped angular velocity).
    if selection:
        joseph_selection(p, kt, kr, hp, idx, np.empty((nc, nc)), np.empty(m), np.empty(nc))
    else:
        mm = np.eye(nc) - kt.T @ h
        pn = mm @ p @ mm.T
        for i in range(nc):
            for j in range(i, nc):
                w = 0.5 * (pn[i, j] + pn[j, i])
                for b in range(m):
                    w += kr[i, b] * kt[b, j]
                if abs(w) < TINY:
                    w = 0.0
                p[i, j] = w
                p[j, i] = w
    inject(x, delta, n_dp, n_do, additive, wmax)
    for i in range(nc):
        if not (p[i, i] > 0.0 and np.isfinite(p[i, i])):
            return DIVERGED, nis
    for i in range(x.shape[0]):
        if not np.isfinite(x[i]):
            return DIVERGED, nis
    return ACCEPTED, nis


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


def predict_pose(x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o):
    """Pose part of the prediction over ``dt``: ``(t, q, C)`` as :func:`pose_of` of
    :func:`predict`, computing only the pose rows of ``A P A^T + Q``."""
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    if additive:
        xn, pn = predict(x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o)
        return pose_of(xn, pn, n_dp, n_do, additive)
    xn, a = transition(x, dt, n_dp, n_do, additive)
    qm = process_noise(x, dt, n_dp, n_do, additive, kind, sig_p, sig_o)
    qo = 3 * npl
    sel = np.empty(6, np.int64)
    for k in range(3):
        sel[k] = k if npl > 0 else 0
        sel[3 + k] = qo + k if nol > 0 else 0
    t = np.zeros((6, nc))
    for r in range(6):
        for k in range(nc):
            v = a[sel[r], k]
            if v != 0.0:
                for j in range(nc):
                    t[r, j] += v * p[k, j]
    c = np.zeros((6, 6))
    for r in range(6):
        for col in range(r, 6):
            w = qm[sel[r], sel[col]]
            for k in range(nc):
                w += t[r, k] * a[sel[col], k]
            c[r, col] = w
            c[col, r] = w
    pos = np.zeros(3)
    q = np.zeros(4)
    q[3] = 1.0
    if npl > 0:
        pos[:] = xn[:3]
    else:
        for k in range(3):
            for j in range(6):
                c[k, j] = 0.0
                c[j, k] = 0.0
            c[k, k] = UNKNOWN_VARIANCE
    if nol > 0:
        q[:] = xn[qo : qo + 4]
    else:
        for k in range(3, 6):
            for j in range(6):
                c[k, j] = 0.0
                c[j, k] = 0.0
            c[k, k] = UNKNOWN_VARIANCE
    return pos, q, c


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
    inject(xs, g @ d, n_dp, n_do, additive, 0.0)
    ps = pf + g @ (p1 - pm) @ g.T
    return xs, sym(ps)


def step(x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o, lp, lo, zp, zo, r, gate, wmax):
    """Streaming predict + update in place; returns ``(status, nis)``.

    On GATED ``x, p`` hold the prediction to the measurement time; on DIVERGED they are
    undefined (the caller resets the filter).
    """
    xn, pn = predict(x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o)
    x[:] = xn
    p[:, :] = pn
    y, h = residual(x, n_dp, n_do, additive, lp, lo, zp, zo)
    if additive and lo == 0:
        q = x[3 * (n_dp + 1 if n_dp >= 0 else 0) :][:4]
        n = math.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
        rr = meas_cov(r, q / n, lp, lo, additive)
    else:
        rr = r
    return update(x, p, y, h, rr, gate, n_dp, n_do, additive, wmax)


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
    gate, wmax, reset_after, out_t, out_q, out_c, pred_t, pred_q, pred_c, nis, status,
):  # fmt: skip
    """Offline run over time-sorted pose measurements; fills the output arrays.

    ``x, p`` hold the initial (uninitialised) state. Rows with non-finite values are skipped
    (status INVALID) and get the prediction. ``reset_after`` consecutive gated measurements
    re-initialise the filter from the current one (status INITIALIZED).
    """
    npl, nol, nx, nc = dims(n_dp, n_do, additive)
    lp = 0 if n_dp >= 0 else -1
    lo = 0 if n_do >= 0 else -1
    x0 = x.copy()
    p0 = p.copy()
    initialized = False
    t_state = 0.0
    gated_run = 0
    n = times.shape[0]
    for i in range(n):
        zp = pos[i]
        zo = quat[i]
        valid = row_is_finite(pos, quat, cov, i)
        if lp >= 0 and lo >= 0:
            r = cov[i]
        elif lp >= 0:
            r = cov[i, :3, :3].copy()
        else:
            r = cov[i, 3:, 3:].copy()
        if not valid:
            status[i] = INVALID
            if initialized:
                xx, pp = predict(x, p, times[i] - t_state, n_dp, n_do, additive, kind, sig_p, sig_o)
            else:
                xx, pp = x, p
        elif not initialized or gated_run >= reset_after:
            status[i] = RESET if initialized else INITIALIZED
            if initialized:
                x[:] = x0
                p[:, :] = p0
            initialize(
                x, p, n_dp, n_do, additive, lp, lo, zp, zo, meas_cov(r, zo, lp, lo, additive)
            )
            t_state = times[i]
            initialized = True
            gated_run = 0
            nis[i] = np.nan
            xx, pp = x, p
        else:
            st, v = step(
                x, p, times[i] - t_state, n_dp, n_do, additive, kind, sig_p, sig_o,
                lp, lo, zp, zo, r, gate, wmax,
            )  # fmt: skip
            t_state = times[i]
            status[i] = st
            nis[i] = v
            if st == GATED:
                gated_run += 1
            elif st == DIVERGED:
                x[:] = x0
                p[:, :] = p0
                initialize(
                    x, p, n_dp, n_do, additive, lp, lo, zp, zo, meas_cov(r, zo, lp, lo, additive)
                )
                gated_run = 0
            else:
                gated_run = 0
            xx, pp = x, p
        t, q, c = pose_of(xx, pp, n_dp, n_do, additive)
        out_t[i] = t
        out_q[i] = q
        out_c[i] = c
        if initialized:
            for h in range(horizons.shape[0]):
                dt = times[i] - t_state + horizons[h]
                t, q, c = predict_pose(x, p, dt, n_dp, n_do, additive, kind, sig_p, sig_o)
                pred_t[h, i] = t
                pred_q[h, i] = q
                pred_c[h, i] = c
        else:
            for h in range(horizons.shape[0]):
                pred_t[h, i] = out_t[i]
                pred_q[h, i] = out_q[i]
                pred_c[h, i] = out_c[i]


# -- fast path: error-state offline run without covariance output ------------------------------
#
# The functions below compute exactly what :func:`run` computes for ``additive = 0`` (same
# formulas, same order of operations up to floating-point rounding) but write into scratch
# buffers allocated once per run and only output the means. They make a whole-recording run
# cheap enough for parameter searches (``trackflow.evaluation.tune_model``).


def qmul_into(a, b, out):
    """``out = a * b`` (Hamilton, ``(x, y, z, w)``); ``out`` must not alias ``a`` or ``b``."""
    out[0] = a[3] * b[0] + a[0] * b[3] + a[1] * b[2] - a[2] * b[1]
    out[1] = a[3] * b[1] - a[0] * b[2] + a[1] * b[3] + a[2] * b[0]
    out[2] = a[3] * b[2] + a[0] * b[1] - a[1] * b[0] + a[2] * b[3]
    out[3] = a[3] * b[3] - a[0] * b[0] - a[1] * b[1] - a[2] * b[2]


def qexp_into(v, out):
    """``out = Exp(v)`` as :func:`qexp`."""
    t2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    if t2 < SMALL * SMALL:
        k = 0.5 - t2 / 48.0
        out[3] = 1.0 - t2 / 8.0 + t2 * t2 / 384.0
    else:
        t = math.sqrt(t2)
        k = math.sin(0.5 * t) / t
        out[3] = math.cos(0.5 * t)
    out[0] = k * v[0]
    out[1] = k * v[1]
    out[2] = k * v[2]


def mean_transition_into(x, dt, n_dp, n_do, out, cf, b, d):
    """``out`` = nominal part of :func:`transition` (error state); returns nothing.

    ``cf`` (>= max levels + 1), ``b`` (3) and ``d`` (4) are scratch; ``d`` holds ``Exp(b)``
    and ``b`` the rotation increment afterwards.
    """
    npl = n_dp + 1 if n_dp >= 0 else 0
    cf[0] = 1.0
    for i in range(1, cf.shape[0]):
        cf[i] = cf[i - 1] * dt / i
    for i in range(npl):
        for k in range(3):
            v = 0.0
            for j in range(i, npl):
                v += cf[j - i] * x[3 * j + k]
            out[3 * i + k] = v
    if n_do < 0:
        return
    qo = 3 * npl
    b[0] = 0.0
    b[1] = 0.0
    b[2] = 0.0
    for lv in range(1, n_do + 1):
        c = cf[lv]
        for k in range(3):
            b[k] += c * x[qo + 4 + 3 * (lv - 1) + k]
    qexp_into(b, d)
    qmul_into(x[qo : qo + 4], d, out[qo : qo + 4])
    for lv in range(1, n_do + 1):
        for k in range(3):
            v = 0.0
            for j in range(lv, n_do + 1):
                v += cf[j - lv] * x[qo + 4 + 3 * (j - 1) + k]
            out[qo + 4 + 3 * (lv - 1) + k] = v


def level_noise_into(n, sig, dt, kind, m):
    """:func:`level_noise` written into ``m`` (at least ``n x n``)."""
    for i in range(n):
        for j in range(n):
            m[i, j] = 0.0
    if kind == 1:
        for i in range(n):
            m[i, i] = (sig[i] * dt) ** 2
        return
    for i in range(n):
        for j in range(n):
            s = 0.0
            for lvl in range(max(i, j), n):
                e = 2 * lvl - i - j + 1
                s += sig[lvl] ** 2 * dt**e / (fact(lvl - i) * fact(lvl - j) * e)
            m[i, j] = s


def predict_cov_into(p, dt, n_dp, n_do, kind, sig_p, sig_o, cf, b, d, a, qm, lv, tmp, out):
    """``p <- A P A^T + Q`` of :func:`predict` (error state) in place.

    Needs ``cf``, ``b`` and ``d`` as left by :func:`mean_transition_into` for the same ``dt``
    and state; ``a``, ``qm``, ``tmp``, ``out`` (nc x nc) and ``lv`` (levels x levels) are scratch.
    """
    npl = n_dp + 1 if n_dp >= 0 else 0
    nol = n_do + 1 if n_do >= 0 else 0
    nc = p.shape[0]
    for i in range(nc):
        for j in range(nc):
            a[i, j] = 0.0
            qm[i, j] = 0.0
    for i in range(npl):
        for j in range(i, npl):
            c = cf[j - i]
            for k in range(3):
                a[3 * i + k, 3 * j + k] = c
    if npl > 0:
        level_noise_into(npl, sig_p, dt, kind, lv)
        for i in range(npl):
            for j in range(npl):
                for k in range(3):
                    qm[3 * i + k, 3 * j + k] = lv[i, j]
    if nol > 0:
        qo = 3 * npl
        r = rotmat(d)
        jr = right_jac(b)
        for i in range(3):
            for j in range(3):
                a[qo + i, qo + j] = r[j, i]
        for lvl in range(1, nol):
            c = cf[lvl]
            for i in range(3):
                for j in range(3):
                    a[qo + i, qo + 3 * lvl + j] = c * jr[i, j]
            for j in range(lvl, nol):
                c = cf[j - lvl]
                for k in range(3):
                    a[qo + 3 * lvl + k, qo + 3 * j + k] = c
        level_noise_into(nol, sig_o, dt, kind, lv)
        for i in range(nol):
            for j in range(nol):
                for k in range(3):
                    qm[qo + 3 * i + k, qo + 3 * j + k] = lv[i, j]
    sandwich_into(a, p, qm, tmp, out)


def update_into(x, p, y, r, idx, gate, n_dp, n_do, wmax, ws):
    """:func:`update` for a selection ``H`` (rows ``idx`` of the error state), in place.

    ``ws`` is a tuple of scratch arrays from :func:`update_scratch`. Returns ``(status, nis)``.
    """
    hp, s, lo, sy, kt, kr, delta, g, acc, mp, d4, q4 = ws
    nc = p.shape[0]
    m = y.shape[0]
    for a_ in range(m):
        for j in range(nc):
            hp[a_, j] = p[idx[a_], j]
    for a_ in range(m):
        for b_ in range(m):
            s[a_, b_] = 0.5 * (hp[a_, idx[b_]] + hp[b_, idx[a_]]) + 0.5 * (r[a_, b_] + r[b_, a_])
    for i in range(m):
        for j in range(m):
            lo[i, j] = 0.0
    for j in range(m):  # the arithmetic of :func:`chol`
        dd = s[j, j]
        for k in range(j):
            dd -= lo[j, k] * lo[j, k]
        if not dd > 0.0:
            return DIVERGED, np.nan
        lo[j, j] = math.sqrt(dd)
        for i in range(j + 1, m):
            v = s[i, j]
            for k in range(j):
                v -= lo[i, k] * lo[j, k]
            lo[i, j] = v / lo[j, j]
    for i in range(m):
        sy[i, 0] = y[i]
    chol_solve_rows(lo, sy)
    nis = 0.0
    for i in range(m):
        nis += y[i] * sy[i, 0]
    if not np.isfinite(nis):
        return DIVERGED, nis
    if nis > gate:
        return GATED, nis
    for a_ in range(m):
        for j in range(nc):
            kt[a_, j] = hp[a_, j]
    chol_solve_rows(lo, kt)
    for i in range(nc):
        delta[i] = 0.0
    for a_ in range(m):
        for i in range(nc):
            delta[i] += kt[a_, i] * y[a_]
    for i in range(nc):
        for b_ in range(m):
            kr[i, b_] = 0.0
    for i in range(nc):
        for a_ in range(m):
            for b_ in range(m):
                kr[i, b_] += kt[a_, i] * r[a_, b_]
    # Joseph form, as in :func:`update`.
    joseph_selection(p, kt, kr, hp, idx, mp, g, acc)
    # inject (error state): t += dt, q <- q Exp(dtheta), rates += d; normalise, clip |w|
    npl = n_dp + 1 if n_dp >= 0 else 0
    qo = 3 * npl
    nx = x.shape[0]
    for i in range(qo):
        x[i] += delta[i]
    if n_do >= 0:
        qexp_into(delta[qo : qo + 3], d4)
        for k in range(4):
            q4[k] = x[qo + k]
        qmul_into(q4, d4, x[qo : qo + 4])
        for i in range(qo + 4, nx):
            x[i] += delta[i - 1]
        nq = math.sqrt(x[qo] ** 2 + x[qo + 1] ** 2 + x[qo + 2] ** 2 + x[qo + 3] ** 2)
        for k in range(4):
            x[qo + k] /= nq
        if n_do >= 1 and wmax > 0.0:
            wn = math.sqrt(x[qo + 4] ** 2 + x[qo + 5] ** 2 + x[qo + 6] ** 2)
            if wn > wmax:
                for k in range(3):
                    x[qo + 4 + k] *= wmax / wn
    for i in range(nc):
        if not (p[i, i] > 0.0 and np.isfinite(p[i, i])):
            return DIVERGED, nis
    for i in range(nx):
        if not np.isfinite(x[i]):
            return DIVERGED, nis
    return ACCEPTED, nis


def update_scratch(m, nc):
    """Scratch arrays for :func:`update_into` (``m`` measured rows, ``nc`` error size)."""
    return (
        np.empty((m, nc)), np.empty((m, m)), np.empty((m, m)), np.empty((m, 1)),
        np.empty((m, nc)), np.empty((nc, m)), np.empty(nc), np.empty(m), np.empty(nc),
        np.empty((nc, nc)), np.empty(4), np.empty(4),
    )  # fmt: skip


def pose_mean_into(x, n_dp, n_do, pos, quat):
    """Pose part of a nominal state (error state) into ``pos`` (3) and ``quat`` (4)."""
    npl = n_dp + 1 if n_dp >= 0 else 0
    for k in range(3):
        pos[k] = x[k] if npl > 0 else 0.0
    if n_do >= 0:
        for k in range(4):
            quat[k] = x[3 * npl + k]
    else:
        quat[0], quat[1], quat[2], quat[3] = 0.0, 0.0, 0.0, 1.0


def run_means(
    times, pos, quat, cov, horizons, x, p, n_dp, n_do, kind, sig_p, sig_o,
    gate, wmax, reset_after, out_t, out_q, pred_t, pred_q, nis, status,
):  # fmt: skip
    """:func:`run` for the error-state formulation, means only (no covariance output).

    The filter is the same (same predictions, gating, resets and statuses); only the pose
    covariances are not written, and the loop allocates nothing per measurement. About ten
    times faster than :func:`run`, which makes parameter searches over whole recordings cheap.
    """
    npl, nol, nx, nc = dims(n_dp, n_do, 0)
    qo = 3 * npl
    lp = 0 if n_dp >= 0 else -1
    lo = 0 if n_do >= 0 else -1
    m = (3 if lp >= 0 else 0) + (3 if lo >= 0 else 0)
    roff = 0 if lp >= 0 else 3  # first row/column of the measured block in cov[i]
    idx = np.empty(m, np.int64)
    c = 0
    if lp >= 0:
        for k in range(3):
            idx[c] = k
            c += 1
    if lo >= 0:
        for k in range(3):
            idx[c] = qo + k
            c += 1
    x0 = x.copy()
    p0 = p.copy()
    nlev = max(npl, nol)
    cf = np.empty(nlev + 1)
    b = np.empty(3)
    d = np.empty(4)
    a = np.empty((nc, nc))
    qm = np.empty((nc, nc))
    tmp = np.empty((nc, nc))
    out = np.empty((nc, nc))
    lv = np.empty((nlev, nlev))
    xn = np.empty(nx)
    r = np.empty((m, m))
    y = np.empty(m)
    qc = np.empty(4)
    e4 = np.empty(4)
    ws = update_scratch(m, nc)
    initialized = False
    t_state = 0.0
    gated_run = 0
    n = times.shape[0]
    for i in range(n):
        zp = pos[i]
        zo = quat[i]
        valid = row_is_finite(pos, quat, cov, i)
        for k in range(m):
            for j in range(m):
                r[k, j] = cov[i, roff + k, roff + j]
        if not valid:
            status[i] = INVALID
            if initialized:
                mean_transition_into(x, times[i] - t_state, n_dp, n_do, xn, cf, b, d)
                pose_mean_into(xn, n_dp, n_do, out_t[i], out_q[i])
            else:
                pose_mean_into(x, n_dp, n_do, out_t[i], out_q[i])
        elif not initialized or gated_run >= reset_after:
            status[i] = RESET if initialized else INITIALIZED
            if initialized:
                x[:] = x0
                p[:, :] = p0
            initialize(x, p, n_dp, n_do, 0, lp, lo, zp, zo, r)
            t_state = times[i]
            initialized = True
            gated_run = 0
            nis[i] = np.nan
            pose_mean_into(x, n_dp, n_do, out_t[i], out_q[i])
        else:
            dt = times[i] - t_state
            mean_transition_into(x, dt, n_dp, n_do, xn, cf, b, d)
            predict_cov_into(p, dt, n_dp, n_do, kind, sig_p, sig_o, cf, b, d, a, qm, lv, tmp, out)
            x[:] = xn
            # residual of :func:`residual` (error state): position, then Log(q^* z_q)
            c = 0
            if lp >= 0:
                for k in range(3):
                    y[k] = zp[k] - x[k]
                c = 3
            if lo >= 0:
                qc[0], qc[1], qc[2], qc[3] = -x[qo], -x[qo + 1], -x[qo + 2], x[qo + 3]
                qmul_into(qc, zo, e4)
                ev = qlog(e4)
                for k in range(3):
                    y[c + k] = ev[k]
            st, v = update_into(x, p, y, r, idx, gate, n_dp, n_do, wmax, ws)
            t_state = times[i]
            status[i] = st
            nis[i] = v
            if st == GATED:
                gated_run += 1
            elif st == DIVERGED:
                x[:] = x0
                p[:, :] = p0
                initialize(x, p, n_dp, n_do, 0, lp, lo, zp, zo, r)
                gated_run = 0
            else:
                gated_run = 0
            pose_mean_into(x, n_dp, n_do, out_t[i], out_q[i])
        if initialized:
            for h in range(horizons.shape[0]):
                mean_transition_into(x, times[i] - t_state + horizons[h], n_dp, n_do, xn, cf, b, d)
                pose_mean_into(xn, n_dp, n_do, pred_t[h, i], pred_q[h, i])
        else:
            for h in range(horizons.shape[0]):
                for k in range(3):
                    pred_t[h, i, k] = out_t[i, k]
                for k in range(4):
                    pred_q[h, i, k] = out_q[i, k]


# -- autoregressive-twist filter (``twist_ar.py``) ---------------------------------------------
# State: pose (t, q) and the last L body-frame increments h (6 L, newest first); error state
# (dt, dtheta, dh), size n = 6 + 6 L. ``a_cat`` is [A_0 ... A_{L-1}] (6 x 6 L).


def twist_ar_top(q, h, a_cat):
    """Next increment ``xi = a_cat h`` and rows 0..11 of the step Jacobians.

    Returns ``(xi (6,), top (12, n), jn (12, 6))`` with ``e' = F e + G n`` where ``F`` has
    ``top`` as rows 0..11 and shifts the history below, ``G`` has ``jn`` as rows 0..11.
    """
    n = 6 + a_cat.shape[1]
    top = np.empty((12, n))
    jn = np.empty((12, 6))
    xi = twist_ar_top_into(q, h, a_cat, top, jn)
    return xi, top, jn


def twist_ar_top_into(q, h, a_cat, top, jn):
    """:func:`twist_ar_top` writing into ``top`` (12, n) and ``jn`` (12, 6); returns ``xi``."""
    n = 6 + a_cat.shape[1]
    xi = np.dot(a_cat, h)
    r = rotmat(q)
    jr = right_jac(xi[3:])
    back = rotmat(qexp(-xi[3:]))
    u = xi[:3]
    for i in range(12):
        for c in range(6):
            top[i, c] = 0.0
            jn[i, c] = 0.0
    for i in range(3):
        top[i, i] = 1.0
        # -R [u]x, column by column: [u]x e_c = u x e_c
        for c in range(3):
            top[i, 3 + c] = -(
                r[i, (c + 1) % 3] * u[(c + 2) % 3] - r[i, (c + 2) % 3] * u[(c + 1) % 3]
            )
            top[3 + i, 3 + c] = back[i, c]
            jn[i, c] = r[i, c]
            jn[3 + i, 3 + c] = jr[i, c]
    for i in range(3):
        for c in range(n - 6):
            a0 = a_cat[0, c] * r[i, 0] + a_cat[1, c] * r[i, 1] + a_cat[2, c] * r[i, 2]
            a1 = a_cat[3, c] * jr[i, 0] + a_cat[4, c] * jr[i, 1] + a_cat[5, c] * jr[i, 2]
            top[i, 6 + c] = a0
            top[3 + i, 6 + c] = a1
    for i in range(6):
        jn[6 + i, i] = 1.0
        for c in range(n - 6):
            top[6 + i, 6 + c] = a_cat[i, c]
    return xi


def twist_ar_run(t, pm, qm, a_cat, qn, prior, r_diag, dt, gap):
    """The autoregressive-twist Kalman filter over a whole recording.

    ``pm`` (N, 3), ``qm`` (N, 4): measured poses; ``qn`` (6, 6): increment noise; ``prior``
    (6, 6): covariance of each history entry after a (re)start; ``r_diag`` (6,): measurement
    variances; ``dt``: model step; ``gap``: restart after longer intervals. Returns filtered
    ``(t (N, 3), q (N, 4), h (N, 6 L), pose covariance (N, 6, 6), nis (N,), restarts)``.
    """
    ns = t.shape[0]
    nh = a_cat.shape[1]
    n = 6 + nh
    out_p = np.empty((ns, 3))
    out_q = np.empty((ns, 4))
    out_h = np.empty((ns, nh))
    out_c = np.empty((ns, 6, 6))
    nis = np.full(ns, np.nan)
    p = np.zeros(3)
    q = np.zeros(4)
    h = np.zeros(nh)
    cov = np.zeros((n, n))
    fp = np.empty((12, n))
    top = np.empty((12, n))
    jn = np.empty((12, 6))
    idx = np.arange(6)
    mp = np.empty((n, n))
    g = np.empty(6)
    acc = np.empty(n)
    restarts = 0
    for k in range(ns):
        dtk = t[k] - t[k - 1] if k > 0 else np.inf
        if k == 0 or dtk > gap:
            for i in range(3):
                p[i] = pm[k, i]
            nq = math.sqrt(qm[k, 0] ** 2 + qm[k, 1] ** 2 + qm[k, 2] ** 2 + qm[k, 3] ** 2)
            for i in range(4):
                q[i] = qm[k, i] / nq
            h[:] = 0.0
            cov[:, :] = 0.0
            for i in range(6):
                cov[i, i] = r_diag[i]
            for j in range(nh // 6):
                for a in range(6):
                    for b in range(6):
                        cov[6 + 6 * j + a, 6 + 6 * j + b] = prior[a, b]
            restarts += 1
        else:
            steps = max(1, int(round(dtk / dt)))
            for _ in range(steps):
                xi = twist_ar_top_into(q, h, a_cat, top, jn)
                # covariance, rows 0..11 of F P: the history rows are A_cat P_h (6 L x n), the
                # pose rows add the pose block; F's other rows shift P's rows by one entry
                ac = np.dot(a_cat, np.ascontiguousarray(cov[6:, :]))
                fpose = np.dot(np.ascontiguousarray(top[:6, :6]), np.ascontiguousarray(cov[:6, :]))
                for i in range(3):
                    for j in range(n):
                        fp[6 + i, j] = ac[i, j]
                        fp[9 + i, j] = ac[3 + i, j]
                        fp[i, j] = fpose[i, j]
                        fp[3 + i, j] = fpose[3 + i, j]
                        for c in range(3):
                            fp[i, j] += jn[i, c] * ac[c, j]
                            fp[3 + i, j] += jn[3 + i, 3 + c] * ac[3 + c, j]
                tt = np.dot(fp, top.T) + np.dot(np.dot(jn, qn), jn.T)
                for i in range(n - 1, 11, -1):  # descending: sources are not yet overwritten
                    for j in range(n - 1, 11, -1):
                        cov[i, j] = cov[i - 6, j - 6]
                for i in range(12):
                    for j in range(12):
                        cov[i, j] = tt[i, j]
                    for j in range(12, n):
                        cov[i, j] = fp[i, j - 6]
                        cov[j, i] = fp[i, j - 6]
                # mean: t += R u, q = q Exp(w), the history shifts in xi
                u = np.dot(rotmat(q), xi[:3])
                for i in range(3):
                    p[i] += u[i]
                q = qmul(q, qexp(xi[3:]))
                for i in range(nh - 1, 5, -1):
                    h[i] = h[i - 6]
                for i in range(6):
                    h[i] = xi[i]
            zq = qm[k].copy()
            if q[0] * zq[0] + q[1] * zq[1] + q[2] * zq[2] + q[3] * zq[3] < 0.0:
                zq = -zq
            conj = np.array([-q[0], -q[1], -q[2], q[3]])
            dth = qlog(qmul(conj, zq))
            y = np.empty(6)
            for i in range(3):
                y[i] = pm[k, i] - p[i]
                y[3 + i] = dth[i]
            s = np.empty((6, 6))
            for i in range(6):
                for j in range(6):
                    s[i, j] = cov[i, j]
                s[i, i] += r_diag[i]
            s_inv = np.linalg.inv(s)
            sy = np.dot(s_inv, y)
            nis[k] = np.dot(y, sy)
            hp = np.ascontiguousarray(cov[:6, :])  # H P with H = [I_6 0]
            kt = np.dot(s_inv, hp)  # K^T (S and P symmetric)
            dx = np.dot(sy, hp)  # K y
            for i in range(3):
                p[i] += dx[i]
            q = qmul(q, qexp(dx[3:6]))
            for i in range(nh):
                h[i] += dx[6 + i]
            kr = np.empty((n, 6))
            for i in range(n):
                for a in range(6):
                    kr[i, a] = kt[a, i] * r_diag[a]
            # Joseph form (shared with the derivative filter): stays symmetric positive
            # semi-definite under rounding, unlike P - K H P
            joseph_selection(cov, kt, kr, hp, idx, mp, g, acc)
        for i in range(3):
            out_p[k, i] = p[i]
        for i in range(4):
            out_q[k, i] = q[i]
        for i in range(nh):
            out_h[k, i] = h[i]
        for i in range(6):
            for j in range(6):
                out_c[k, i, j] = cov[i, j]
    return out_p, out_q, out_h, out_c, nis, restarts
