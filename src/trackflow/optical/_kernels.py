"""Compiled kernels of the filter-guided frame step (numba): projection with Jacobians,
gated blob assignment and point refinement. They compute exactly what
:meth:`Camera.project`, :func:`~trackflow.optical.triangulation.refine_points` and the gating
in :mod:`~trackflow.optical.pipeline` describe, one point at a time without temporaries; the
tests check them against those NumPy versions.

Camera parameters are packed per camera as ``(fx, s, cx, fy, cy, k1, k2, p1, p2, k3, k4, k5,
k6, width, height)`` (:func:`pack_cameras`), rotations ``R_cam_world`` (C, 3, 3) and
translations (C, 3).
"""

from __future__ import annotations

import numpy as np

from ..optional import require
from .camera import CameraRig

numba = require("numba", extra="fast", feature="the optical tracker")

__all__ = ["guided_assign", "pack_cameras", "refine_points_packed"]


def pack_cameras(rig: CameraRig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(params (C, 15), R (C, 3, 3), t (C, 3))`` of a rig for the kernels."""
    P = np.empty((len(rig), 15))
    for i, c in enumerate(rig):
        K = c.K
        P[i, :5] = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
        P[i, 5:13] = np.concatenate([c.dist, np.zeros(8 - c.dist.size)])
        P[i, 13:] = c.size
    R = np.stack([c.R_cam_world for c in rig])
    t = np.stack([c.t_cam_world for c in rig])
    return P, R, t


@numba.njit(cache=True, nogil=True, fastmath=False)
def _project(P, R, t, X, J):
    """Pixel of world point ``X`` (3,) and ``J`` (2, 3) = d uv / d X; NaN behind the camera."""
    xc0 = R[0, 0] * X[0] + R[0, 1] * X[1] + R[0, 2] * X[2] + t[0]
    xc1 = R[1, 0] * X[0] + R[1, 1] * X[1] + R[1, 2] * X[2] + t[1]
    z = R[2, 0] * X[0] + R[2, 1] * X[1] + R[2, 2] * X[2] + t[2]
    if z <= 0.0:
        return np.nan, np.nan
    iz = 1.0 / z
    x = xc0 * iz
    y = xc1 * iz
    fx, s, cx, fy, cy = P[0], P[1], P[2], P[3], P[4]
    k1, k2, p1, p2, k3, k4, k5, k6 = P[5], P[6], P[7], P[8], P[9], P[10], P[11], P[12]
    r2 = x * x + y * y
    num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    a = num / den
    xy = x * y
    xd = x * a + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x)
    yd = y * a + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy
    dnum = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    dden = k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2)
    da = (dnum * den - num * dden) / (den * den)
    d00 = a + 2.0 * x * x * da + 2.0 * p1 * y + 6.0 * p2 * x
    d01 = 2.0 * xy * da + 2.0 * p1 * x + 2.0 * p2 * y
    d11 = a + 2.0 * y * y * da + 6.0 * p1 * y + 2.0 * p2 * x
    # K2 @ Jd
    a00 = fx * d00 + s * d01
    a01 = fx * d01 + s * d11
    a10 = fy * d01
    a11 = fy * d11
    # @ Jn (d(x, y)/d X_cam) = [[iz, 0, -x iz], [0, iz, -y iz]]
    b00 = a00 * iz
    b01 = a01 * iz
    b02 = -(a00 * x + a01 * y) * iz
    b10 = a10 * iz
    b11 = a11 * iz
    b12 = -(a10 * x + a11 * y) * iz
    for j in range(3):
        J[0, j] = b00 * R[0, j] + b01 * R[1, j] + b02 * R[2, j]
        J[1, j] = b10 * R[0, j] + b11 * R[1, j] + b12 * R[2, j]
    return fx * xd + s * yd + cx, fy * yd + cy


@numba.njit(cache=True, nogil=True)
def guided_assign(P, R, t, X, CX, blobs, start, sigma2, gate2):
    """Assign blobs to predicted markers.

    Parameters
    ----------
    X : (Q, 3) predicted marker positions; CX : (Q, 3, 3) their covariances.
    blobs : (K, 2) blob centroids of all cameras, camera ``c`` in ``start[c]:start[c + 1]``.
    sigma2 : centroid variance [px^2]; gate2 : chi-square gate (2 dof).

    Returns
    -------
    uv : (C, Q, 2) assigned blob per marker and camera (NaN: none or ambiguous)
    claim : (K,) marker index of each blob (-1: none)
    """
    C, Q = P.shape[0], X.shape[0]
    uv = np.full((C, Q, 2), np.nan)
    claim = np.full(blobs.shape[0], -1, np.int64)
    J = np.empty((2, 3))
    pu = np.empty(Q)
    pv = np.empty(Q)
    i00 = np.empty(Q)
    i01 = np.empty(Q)
    i11 = np.empty(Q)
    for c in range(C):
        k0, k1 = start[c], start[c + 1]
        if k1 == k0:
            continue
        w, h = P[c, 13], P[c, 14]
        for q in range(Q):
            u, v = _project(P[c], R[c], t[c], X[q], J)
            if not (u >= -0.5 and u <= w - 0.5 and v >= -0.5 and v <= h - 0.5):
                pu[q] = np.nan
                continue
            # S = J CX J^T + sigma2 I, inverted
            s00 = sigma2
            s01 = 0.0
            s11 = sigma2
            for a in range(3):
                ja0 = J[0, a]
                ja1 = J[1, a]
                for b in range(3):
                    cab = CX[q, a, b]
                    s00 += ja0 * cab * J[0, b]
                    s01 += ja0 * cab * J[1, b]
                    s11 += ja1 * cab * J[1, b]
            det = s00 * s11 - s01 * s01
            pu[q], pv[q] = u, v
            i00[q], i01[q], i11[q] = s11 / det, -s01 / det, s00 / det
        n_q = np.zeros(Q, np.int64)
        best_k = np.full(Q, -1, np.int64)
        n_k = np.zeros(k1 - k0, np.int64)
        best_q = np.full(k1 - k0, -1, np.int64)
        for q in range(Q):
            if np.isnan(pu[q]):
                continue
            for k in range(k0, k1):
                du = blobs[k, 0] - pu[q]
                dv = blobs[k, 1] - pv[q]
                m2 = i00[q] * du * du + 2.0 * i01[q] * du * dv + i11[q] * dv * dv
                if m2 < gate2:
                    n_q[q] += 1
                    best_k[q] = k
                    n_k[k - k0] += 1
                    best_q[k - k0] = q
        for q in range(Q):
            k = best_k[q]
            if n_q[q] == 1 and n_k[k - k0] == 1:
                uv[c, q, 0] = blobs[k, 0]
                uv[c, q, 1] = blobs[k, 1]
                claim[k] = q
    return uv, claim


@numba.njit(cache=True, nogil=True)
def refine_points_packed(P, R, t, X0, uv, sigma2, iterations):
    """Gauss-Newton refinement of points (Q, 3) on pixels ``uv`` (C, Q, 2) (NaN: not seen).

    Returns ``X`` (Q, 3), ``cov`` (Q, 3, 3), ``chi2`` (Q,), ``n_views`` (Q,); points with fewer
    than two views or a singular geometry get NaN.
    """
    C, Q = uv.shape[0], uv.shape[1]
    X = X0.copy()
    cov = np.full((Q, 3, 3), np.nan)
    chi2 = np.full(Q, np.nan)
    nv = np.zeros(Q, np.int64)
    J = np.empty((2, 3))
    H = np.empty((3, 3))
    g = np.empty(3)
    w = 1.0 / sigma2
    for q in range(Q):
        n = 0
        for c in range(C):
            if not np.isnan(uv[c, q, 0]):
                n += 1
        nv[q] = n
        if n < 2:
            X[q, :] = np.nan
            continue
        ok = True
        for it in range(iterations + 1):
            H[:, :] = 0.0
            g[:] = 0.0
            e2 = 0.0
            for c in range(C):
                if np.isnan(uv[c, q, 0]):
                    continue
                u, v = _project(P[c], R[c], t[c], X[q], J)
                if np.isnan(u):
                    ok = False
                    break
                ru = uv[c, q, 0] - u
                rv = uv[c, q, 1] - v
                e2 += ru * ru + rv * rv
                for a in range(3):
                    g[a] += w * (J[0, a] * ru + J[1, a] * rv)
                    for b in range(3):
                        H[a, b] += w * (J[0, a] * J[0, b] + J[1, a] * J[1, b])
            if not ok:
                break
            if it == iterations:
                chi2[q] = e2 * w
                break
            dx = np.linalg.solve(H, g)
            for a in range(3):
                X[q, a] += dx[a]
        if not ok or np.abs(np.linalg.det(H)) < 1e-300:
            X[q, :] = np.nan
            chi2[q] = np.nan
            continue
        cov[q] = np.linalg.inv(H)
    return X, cov, chi2, nv


@numba.njit(cache=True, nogil=True)
def _exp_so3(w):
    """Rotation matrix of the rotation vector ``w`` (3,) (Rodrigues)."""
    th = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    K = np.zeros((3, 3))
    K[0, 1], K[0, 2], K[1, 0] = -w[2], w[1], w[2]
    K[1, 2], K[2, 0], K[2, 1] = -w[0], -w[1], w[0]
    if th < 1e-8:
        a, b = 1.0 - th * th / 6.0, 0.5 - th * th / 24.0
    else:
        a, b = np.sin(th) / th, (1.0 - np.cos(th)) / (th * th)
    return np.eye(3) + a * K + b * (K @ K)


@numba.njit(cache=True, nogil=True)
def fit_pose_packed(m, x, W, w_init, iterations):
    """Rigid fit ``x ~ R m + t`` with point information matrices ``W`` (M, 3, 3).

    Closed form (weighted Umeyama, weights ``w_init``) then Gauss-Newton on
    ``sum r_i^T W_i r_i`` with the error ``(dt, dtheta)``, ``R_true = R Exp(dtheta)``.
    Returns ``R`` (3, 3), ``t`` (3,), ``H`` (6, 6) information, ``point_chi2`` (M,).
    """
    M = m.shape[0]
    ws = w_init / w_init.sum()
    ca = np.zeros(3)
    cb = np.zeros(3)
    for i in range(M):
        ca += ws[i] * m[i]
        cb += ws[i] * x[i]
    S = np.zeros((3, 3))
    for i in range(M):
        for a in range(3):
            for b in range(3):
                S[a, b] += ws[i] * (x[i, a] - cb[a]) * (m[i, b] - ca[b])
    U, sv, Vt = np.linalg.svd(S)
    D = np.eye(3)
    if np.linalg.det(U @ Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    t = cb - R @ ca
    H = np.zeros((6, 6))
    pc = np.zeros(M)
    J = np.zeros((3, 6))
    for it in range(iterations + 1):
        H[:, :] = 0.0
        g = np.zeros(6)
        for i in range(M):
            Rm = R @ m[i]
            r = x[i] - Rm - t
            # J = [I, -R [m]x]
            Sk = np.zeros((3, 3))
            Sk[0, 1], Sk[0, 2], Sk[1, 0] = -m[i, 2], m[i, 1], m[i, 2]
            Sk[1, 2], Sk[2, 0], Sk[2, 1] = -m[i, 0], -m[i, 1], m[i, 0]
            J[:, :3] = np.eye(3)
            J[:, 3:] = -(R @ Sk)
            JW = J.T @ W[i]
            H += JW @ J
            g += JW @ r
            pc[i] = r @ (W[i] @ r)
        if it == iterations:
            break
        d = np.linalg.solve(H, g)
        t = t + d[:3]
        R = R @ _exp_so3(d[3:])
    return R, t, H, pc


@numba.njit(cache=True, nogil=True)
def quat_of_matrix(R):
    """Unit quaternion ``(x, y, z, w)`` of a rotation matrix (Shepperd's method), ``w >= 0``."""
    q = np.empty(4)
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > 0.0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q[3] = 0.25 * s
        q[0] = (R[2, 1] - R[1, 2]) / s
        q[1] = (R[0, 2] - R[2, 0]) / s
        q[2] = (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q[3] = (R[2, 1] - R[1, 2]) / s
        q[0] = 0.25 * s
        q[1] = (R[0, 1] + R[1, 0]) / s
        q[2] = (R[0, 2] + R[2, 0]) / s
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q[3] = (R[0, 2] - R[2, 0]) / s
        q[0] = (R[0, 1] + R[1, 0]) / s
        q[1] = 0.25 * s
        q[2] = (R[1, 2] + R[2, 1]) / s
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q[3] = (R[1, 0] - R[0, 1]) / s
        q[0] = (R[0, 2] + R[2, 0]) / s
        q[1] = (R[1, 2] + R[2, 1]) / s
        q[2] = 0.25 * s
    if q[3] < 0.0:
        q = -q
    return q / np.sqrt(q @ q)


@numba.njit(cache=True, nogil=True)
def fit_pose_cov(m, x, C, iterations):
    """:func:`fit_pose_packed` from point covariances ``C`` (M, 3, 3): returns ``t`` (3,),
    ``q`` (4,), the 6x6 covariance and ``point_chi2`` (M,)."""
    M = m.shape[0]
    W = np.empty((M, 3, 3))
    w = np.empty(M)
    for i in range(M):
        W[i] = np.linalg.inv(C[i])
        w[i] = 1.0 / (C[i, 0, 0] + C[i, 1, 1] + C[i, 2, 2])
    R, t, H, pc = fit_pose_packed(m, x, W, w, iterations)
    cov = np.linalg.inv(H)
    cov = 0.5 * (cov + cov.T)
    return t, quat_of_matrix(R), cov, pc


@numba.njit(cache=True, nogil=True)
def drop_merged(uv, claim, owner, n_bodies, areas, start, ratio):
    """Unassign (in place) every claimed blob whose area exceeds ``ratio`` times the median
    area of the blobs claimed by the same body in the same image (at least 3 of them).

    ``owner`` (Q,) is the body of each predicted marker, ``claim`` (K,) the marker of each
    blob (-1: none), ``uv`` (C, Q, 2) the assignment made by :func:`guided_assign`.
    """
    C = len(start) - 1
    buf = np.empty(claim.shape[0])
    for c in range(C):
        for b in range(n_bodies):
            n = 0
            for k in range(start[c], start[c + 1]):
                if claim[k] >= 0 and owner[claim[k]] == b:
                    buf[n] = areas[k]
                    n += 1
            if n < 3:
                continue
            med = np.median(buf[:n])
            for k in range(start[c], start[c + 1]):
                q = claim[k]
                if q >= 0 and owner[q] == b and areas[k] > ratio * med:
                    uv[c, q, 0] = np.nan
                    uv[c, q, 1] = np.nan
                    claim[k] = -1
