"""SO(3) as a Lie group, scalar kernels: the one place of Exp, Log, Jr, rplus, rminus, between.

A kernel source for :mod:`trackflow.math._backend` (``KERNELS`` below): plain Python on NumPy
arrays, kept numba-compatible (explicit loops, contiguous float64 arrays, no Python objects).
Every compiled package calls these functions by name (the filters, the inertial and optical
kernels, the composition kernels), and their compiled copies call the compiled copies of these.
Each allocating function is a thin wrapper of its in-place ``*_into`` twin where one exists, so
every formula is written once. The batched NumPy forms of the same maps are
:func:`~trackflow.math.quat_exp`, :func:`~trackflow.math.quat_log`,
:func:`~trackflow.math.quat_rplus`, :func:`~trackflow.math.quat_rminus` and
:func:`~trackflow.math.quat_between`; they follow the same threshold policy.

Conventions (``docs/conventions.md``): quaternions ``(x, y, z, w)``, Hamilton, unit length;
rotation vectors in radians; errors on the right, ``R_true = R Exp(dtheta)``. For orientations
``q_a = R_w_a`` and ``q_b = R_w_b``:

* ``between(q_a, q_b) = q_a^* q_b`` is ``R_a_b``;
* ``rplus(q, v) = q Exp(v)`` (``q (+) v``);
* ``rminus(q_b, q_a) = Log(q_a^* q_b)`` (``q_b (-) q_a``), so ``rplus(q_a, rminus(q_b, q_a))``
  is ``q_b`` (up to sign).

Small-angle policy, one for every map here: below ``SMALL_ANGLE`` (1e-4 rad) the closed forms
are replaced by their Taylor series, truncated after the ``t^4`` term (truncation error
``< 1e-24`` relative); above it the closed forms are written without cancellation
(``1 - cos t = 2 sin^2(t/2)``, ``atan2`` for the angle). Near ``pi`` no threshold is needed:
``Log`` goes through a unit quaternion (``atan2(|v|, w)``, exact at ``w = 0``) and a rotation
matrix is turned into one by Shepperd's method (the best-conditioned of four branches).

Jacobians are named ``J_<out>_<in>``, all with respect to right-perturbation errors
(``x (+) dx``) of their inputs and outputs, and are checked against finite differences in
``tests/math/test_lie.py``.
"""

from __future__ import annotations

import math

import numpy as np

KERNELS = (
    "exp_coefficients",
    "log_coefficient",
    "jacobian_coefficients",
    "hat",
    "qmul_into",
    "qmul",
    "qexp_into",
    "qexp",
    "qlog_into",
    "qlog",
    "qbetween_into",
    "qbetween",
    "qrplus_into",
    "qrplus",
    "qrminus_into",
    "qrminus",
    "rotmat_into",
    "rotmat",
    "quat_of_rotmat_into",
    "quat_of_rotmat",
    "so3_exp",
    "so3_log",
    "right_jac_into",
    "right_jac",
    "right_jac_inv_into",
    "right_jac_inv",
    "qrplus_jacobians",
    "qrminus_jacobians",
    "qbetween_jacobians",
    "left_mult",
    "right_mult",
    "exp_jac",
)
KERNELS_INLINE = ("exp_coefficients", "log_coefficient", "jacobian_coefficients")
KERNEL_SOURCES = ()

SMALL_ANGLE = 1e-4  # rad: below it every map uses its series (see the module notes)


# -- scalar coefficients (the threshold policy lives here) ---------------------------------------


def exp_coefficients(t2):
    """``(sin(t/2)/t, cos(t/2))`` of ``t2 = t^2``: ``Exp(v) = (k v, w)``."""
    if t2 < SMALL_ANGLE * SMALL_ANGLE:
        return 0.5 - t2 / 48.0, 1.0 - t2 / 8.0 + t2 * t2 / 384.0
    t = math.sqrt(t2)
    return math.sin(0.5 * t) / t, math.cos(0.5 * t)


def log_coefficient(n, w):
    """``k`` with ``Log(q) = k (x, y, z)`` for ``n = |(x, y, z)|`` and ``w >= 0``."""
    if n < 0.5 * SMALL_ANGLE:
        # 2 atan(n / w) / n, series in (n / w)^2 (to the order whose error is below rounding)
        return 2.0 / w * (1.0 - n * n / (3.0 * w * w))
    return 2.0 * math.atan2(n, w) / n


def jacobian_coefficients(t2):
    """``(a, b, c)`` of ``t2 = t^2`` for the right Jacobian and its inverse.

    ``Jr = I - a [v]x + b [v]x^2`` and ``Jr^-1 = I + [v]x / 2 + c [v]x^2`` with
    ``a = (1 - cos t)/t^2``, ``b = (t - sin t)/t^3``, ``c = 1/t^2 - (1 + cos t)/(2 t sin t)``.
    """
    if t2 < SMALL_ANGLE * SMALL_ANGLE:
        a = 0.5 - t2 / 24.0
        b = 1.0 / 6.0 - t2 / 120.0
        c = 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0
        return a, b, c
    t = math.sqrt(t2)
    sh = math.sin(0.5 * t)
    # (1 - cos t) / t^2 as recorded runs were computed (bit for bit; 2 sin^2(t/2) / t^2 would
    # avoid the cancellation, whose relative error is below 1e-8 just above the threshold)
    a = (1.0 - math.cos(t)) / t2
    b = (t - math.sin(t)) / (t2 * t)
    # (1 + cos t) / (2 t sin t) written as cos(t/2) / (2 t sin(t/2)): exact near pi
    c = 1.0 / t2 - math.cos(0.5 * t) / (2.0 * t * sh)
    return a, b, c


def hat(v):
    """``[v]x`` (3, 3) with ``[v]x u = v x u``."""
    k = np.zeros((3, 3))
    k[0, 1] = -v[2]
    k[0, 2] = v[1]
    k[1, 0] = v[2]
    k[1, 2] = -v[0]
    k[2, 0] = -v[1]
    k[2, 1] = v[0]
    return k


# -- quaternions --------------------------------------------------------------------------------


def qmul_into(a, b, out):
    """``out = a * b`` (Hamilton); ``out`` must not alias ``a`` or ``b``."""
    out[0] = a[3] * b[0] + a[0] * b[3] + a[1] * b[2] - a[2] * b[1]
    out[1] = a[3] * b[1] - a[0] * b[2] + a[1] * b[3] + a[2] * b[0]
    out[2] = a[3] * b[2] + a[0] * b[1] - a[1] * b[0] + a[2] * b[3]
    out[3] = a[3] * b[3] - a[0] * b[0] - a[1] * b[1] - a[2] * b[2]


def qmul(a, b):
    """``a * b`` as a new array (see :func:`qmul_into`)."""
    out = np.empty(4)
    qmul_into(a, b, out)
    return out


def qexp_into(v, out):
    """``out = Exp(v)``: unit quaternion of the rotation vector ``v`` (rad)."""
    k, w = exp_coefficients(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    out[0] = k * v[0]
    out[1] = k * v[1]
    out[2] = k * v[2]
    out[3] = w


def qexp(v):
    """``Exp(v)`` as a new array (see :func:`qexp_into`)."""
    out = np.empty(4)
    qexp_into(v, out)
    return out


def qlog_into(q, out):
    """``out`` (3) = ``Log(q)``: rotation vector (rad) of the shortest rotation, ``|Log| <= pi``.

    ``q`` and ``-q`` give the same result; at exactly ``pi`` (``w = 0``) the axis keeps the sign
    of ``q``'s vector part.
    """
    s = -1.0 if q[3] < 0.0 else 1.0
    k = s * log_coefficient(math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]), s * q[3])
    out[0] = k * q[0]
    out[1] = k * q[1]
    out[2] = k * q[2]


def qlog(q):
    """``Log(q)`` as a new array (see :func:`qlog_into`)."""
    out = np.empty(3)
    qlog_into(q, out)
    return out


def qbetween_into(qa, qb, out):
    """``out = qa^* qb``: ``R_a_b`` of ``qa = R_w_a`` and ``qb = R_w_b``."""
    out[0] = qa[3] * qb[0] - qa[0] * qb[3] - qa[1] * qb[2] + qa[2] * qb[1]
    out[1] = qa[3] * qb[1] + qa[0] * qb[2] - qa[1] * qb[3] - qa[2] * qb[0]
    out[2] = qa[3] * qb[2] - qa[0] * qb[1] + qa[1] * qb[0] - qa[2] * qb[3]
    out[3] = qa[3] * qb[3] + qa[0] * qb[0] + qa[1] * qb[1] + qa[2] * qb[2]


def qbetween(qa, qb):
    """``qa^* qb`` as a new array (see :func:`qbetween_into`)."""
    out = np.empty(4)
    qbetween_into(qa, qb, out)
    return out


def qrplus_into(q, v, out):
    """``out = q (+) v = q Exp(v)`` (``out`` must not alias ``q``)."""
    k, w = exp_coefficients(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    ex, ey, ez = k * v[0], k * v[1], k * v[2]
    out[0] = q[3] * ex + q[0] * w + q[1] * ez - q[2] * ey
    out[1] = q[3] * ey - q[0] * ez + q[1] * w + q[2] * ex
    out[2] = q[3] * ez + q[0] * ey - q[1] * ex + q[2] * w
    out[3] = q[3] * w - q[0] * ex - q[1] * ey - q[2] * ez


def qrplus(q, v):
    """``q Exp(v)`` as a new array (see :func:`qrplus_into`)."""
    out = np.empty(4)
    qrplus_into(q, v, out)
    return out


def qrminus_into(qb, qa, out):
    """``out`` (3) = ``qb (-) qa = Log(qa^* qb)`` [rad], the right error from ``qa`` to ``qb``."""
    x = qa[3] * qb[0] - qa[0] * qb[3] - qa[1] * qb[2] + qa[2] * qb[1]
    y = qa[3] * qb[1] + qa[0] * qb[2] - qa[1] * qb[3] - qa[2] * qb[0]
    z = qa[3] * qb[2] - qa[0] * qb[1] + qa[1] * qb[0] - qa[2] * qb[3]
    w = qa[3] * qb[3] + qa[0] * qb[0] + qa[1] * qb[1] + qa[2] * qb[2]
    s = -1.0 if w < 0.0 else 1.0
    k = s * log_coefficient(math.sqrt(x * x + y * y + z * z), s * w)
    out[0] = k * x
    out[1] = k * y
    out[2] = k * z


def qrminus(qb, qa):
    """``Log(qa^* qb)`` as a new array (see :func:`qrminus_into`)."""
    out = np.empty(3)
    qrminus_into(qb, qa, out)
    return out


# -- rotation matrices --------------------------------------------------------------------------


def rotmat_into(q, r):
    """``r`` (3x3) = rotation matrix of the unit quaternion ``q``."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    r[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    r[0, 1] = 2.0 * (x * y - w * z)
    r[0, 2] = 2.0 * (x * z + w * y)
    r[1, 0] = 2.0 * (x * y + w * z)
    r[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    r[1, 2] = 2.0 * (y * z - w * x)
    r[2, 0] = 2.0 * (x * z - w * y)
    r[2, 1] = 2.0 * (y * z + w * x)
    r[2, 2] = 1.0 - 2.0 * (x * x + y * y)


def rotmat(q):
    """Rotation matrix of ``q`` as a new array (see :func:`rotmat_into`)."""
    r = np.empty((3, 3))
    rotmat_into(q, r)
    return r


def quat_of_rotmat_into(r, q):
    """``q`` (4) = unit quaternion with ``w >= 0`` of the rotation matrix ``r`` (3, 3).

    Shepperd's method: of ``4 w^2, 4 x^2, 4 y^2, 4 z^2`` the largest sets the branch, so no
    square root of a small number is taken (exact near ``pi`` as near ``0``).
    """
    tr = r[0, 0] + r[1, 1] + r[2, 2]
    if tr >= r[0, 0] and tr >= r[1, 1] and tr >= r[2, 2]:
        s = 2.0 * math.sqrt(max(1.0 + tr, 0.0))
        q[3] = 0.25 * s
        q[0] = (r[2, 1] - r[1, 2]) / s
        q[1] = (r[0, 2] - r[2, 0]) / s
        q[2] = (r[1, 0] - r[0, 1]) / s
    elif r[0, 0] >= r[1, 1] and r[0, 0] >= r[2, 2]:
        s = 2.0 * math.sqrt(max(1.0 + r[0, 0] - r[1, 1] - r[2, 2], 0.0))
        q[3] = (r[2, 1] - r[1, 2]) / s
        q[0] = 0.25 * s
        q[1] = (r[0, 1] + r[1, 0]) / s
        q[2] = (r[0, 2] + r[2, 0]) / s
    elif r[1, 1] >= r[2, 2]:
        s = 2.0 * math.sqrt(max(1.0 + r[1, 1] - r[0, 0] - r[2, 2], 0.0))
        q[3] = (r[0, 2] - r[2, 0]) / s
        q[0] = (r[0, 1] + r[1, 0]) / s
        q[1] = 0.25 * s
        q[2] = (r[1, 2] + r[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(max(1.0 + r[2, 2] - r[0, 0] - r[1, 1], 0.0))
        q[3] = (r[1, 0] - r[0, 1]) / s
        q[0] = (r[0, 2] + r[2, 0]) / s
        q[1] = (r[1, 2] + r[2, 1]) / s
        q[2] = 0.25 * s
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if q[3] < 0.0:
        n = -n
    for i in range(4):
        q[i] /= n


def quat_of_rotmat(r):
    """Unit quaternion of ``r`` as a new array (see :func:`quat_of_rotmat_into`)."""
    q = np.empty(4)
    quat_of_rotmat_into(r, q)
    return q


def so3_exp(phi):
    """Rotation matrix ``Exp(phi)`` (3, 3) of a rotation vector ``phi`` (3,) [rad]."""
    q = np.empty(4)
    qexp_into(phi, q)
    r = np.empty((3, 3))
    rotmat_into(q, r)
    return r


def so3_log(r):
    """Rotation vector ``Log(R)`` (3,) [rad], angle in ``[0, pi]``, of a rotation matrix."""
    q = np.empty(4)
    quat_of_rotmat_into(r, q)
    v = np.empty(3)
    qlog_into(q, v)
    return v


# -- Jacobians ----------------------------------------------------------------------------------


def right_jac_into(v, j):
    """``j`` (3x3) = SO(3) right Jacobian ``Jr(v)``: ``Exp(v + d) ~ Exp(v) Exp(Jr(v) d)``.

    ``J_Exp_v`` of :func:`qexp` / :func:`so3_exp` with right-perturbation output error.
    """
    t2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    a, b, _ = jacobian_coefficients(t2)
    # Jr = I - a [v]x + b [v]x^2 with [v]x^2 = v v^T - |v|^2 I
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


def right_jac(v):
    """``Jr(v)`` as a new array (see :func:`right_jac_into`)."""
    j = np.empty((3, 3))
    right_jac_into(v, j)
    return j


def right_jac_inv_into(v, j):
    """``j`` (3x3) = ``Jr(v)^-1``: ``Log(Exp(v) Exp(d)) ~ v + Jr(v)^-1 d`` for ``|v| < pi``.

    ``J_Log_R`` of :func:`qlog` / :func:`so3_log` with right-perturbation input error.
    """
    t2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    _, _, c = jacobian_coefficients(t2)
    # Jr^-1 = I + [v]x / 2 + c [v]x^2
    for r in range(3):
        for k in range(3):
            j[r, k] = c * v[r] * v[k]
        j[r, r] += 1.0 - c * t2
    j[0, 1] -= 0.5 * v[2]
    j[0, 2] += 0.5 * v[1]
    j[1, 0] += 0.5 * v[2]
    j[1, 2] -= 0.5 * v[0]
    j[2, 0] -= 0.5 * v[1]
    j[2, 1] += 0.5 * v[0]


def right_jac_inv(v):
    """``Jr(v)^-1`` as a new array (see :func:`right_jac_inv_into`)."""
    j = np.empty((3, 3))
    right_jac_inv_into(v, j)
    return j


def qrplus_jacobians(q, v):
    """``(J_out_q, J_out_v)`` (3x3 each) of ``out = q Exp(v)``: ``Exp(v)^T`` and ``Jr(v)``."""
    e = np.empty(4)
    qexp_into(v, e)
    J_out_q = np.empty((3, 3))
    rotmat_into(e, J_out_q)
    J_out_q = J_out_q.T.copy()
    J_out_v = np.empty((3, 3))
    right_jac_into(v, J_out_v)
    return J_out_q, J_out_v


def qrminus_jacobians(qb, qa):
    """``(J_d_qb, J_d_qa)`` (3x3 each) of ``d = Log(qa^* qb)``: ``Jr(d)^-1`` and ``-Jr(d)^-T``.

    Valid for ``|d| < pi`` (at ``pi`` the sign of ``d`` is a choice; its one-sided derivative
    on the branch chosen is still these).
    """
    d = np.empty(3)
    qrminus_into(qb, qa, d)
    J_d_qb = np.empty((3, 3))
    right_jac_inv_into(d, J_d_qb)
    J_d_qa = -J_d_qb.T.copy()
    return J_d_qb, J_d_qa


def qbetween_jacobians(qa, qb):
    """``(J_c_qa, J_c_qb)`` (3x3 each) of ``c = qa^* qb``: ``-R(c)^T`` and ``I``."""
    c = np.empty(4)
    qbetween_into(qa, qb, c)
    r = np.empty((3, 3))
    rotmat_into(c, r)
    J_c_qa = -r.T.copy()
    J_c_qb = np.eye(3)
    return J_c_qa, J_c_qb


def left_mult(q):
    """``L(q)`` (4x4) with ``q * p = L(q) p``."""
    m = np.empty((4, 4))
    x, y, z, w = q[0], q[1], q[2], q[3]
    m[0, 0], m[0, 1], m[0, 2], m[0, 3] = w, -z, y, x
    m[1, 0], m[1, 1], m[1, 2], m[1, 3] = z, w, -x, y
    m[2, 0], m[2, 1], m[2, 2], m[2, 3] = -y, x, w, z
    m[3, 0], m[3, 1], m[3, 2], m[3, 3] = -x, -y, -z, w
    return m


def right_mult(d):
    """``M(d)`` (4x4) with ``q * d = M(d) q`` (the upper-left block of the thesis's ``A_R``)."""
    m = np.empty((4, 4))
    x, y, z, w = d[0], d[1], d[2], d[3]
    m[0, 0], m[0, 1], m[0, 2], m[0, 3] = w, z, -y, x
    m[1, 0], m[1, 1], m[1, 2], m[1, 3] = -z, w, x, y
    m[2, 0], m[2, 1], m[2, 2], m[2, 3] = y, -x, w, z
    m[3, 0], m[3, 1], m[3, 2], m[3, 3] = -x, -y, -z, w
    return m


def exp_jac(b):
    """``d Exp(b) / d b`` (4x3) in quaternion components; at ``b = 0`` the limit ``[I/2; 0]``
    (the thesis's B-tilde)."""
    t2 = b[0] * b[0] + b[1] * b[1] + b[2] * b[2]
    j = np.zeros((4, 3))
    s, w = exp_coefficients(t2)
    if t2 < SMALL_ANGLE * SMALL_ANGLE:
        ds = -1.0 / 24.0 + t2 / 960.0  # (d s / d t) / t
        dw = -0.25 + t2 / 96.0  # (d cos(t/2) / d t) / t
    else:
        t = math.sqrt(t2)
        sn = math.sin(0.5 * t)
        ds = (0.5 * w * t - sn) / (t2 * t)
        dw = -0.5 * sn / t
    for i in range(3):
        for k in range(3):
            j[i, k] = ds * b[i] * b[k]
        j[i, i] += s
        j[3, i] = dw * b[i]
    return j
