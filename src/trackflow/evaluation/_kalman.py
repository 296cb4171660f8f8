"""Compiled constant-derivative Kalman predictor used for prediction-error evaluation and tuning.

Position and orientation are filtered independently (thesis section 9.2.1: "position and
orientation can be tuned separately"). Each is a chain of ``n + 1`` derivative levels
(value, velocity, acceleration) per axis:

* position: state ``(p, v, a)`` in the world frame ``a`` of ``T_a_b``, metres;
* orientation: the estimate ``q`` (``R_a_b``) plus body-frame angular velocity ``w`` and
  acceleration ``alpha``; the orientation error is ``R_true = R Exp(dtheta)`` (right, body frame,
  radians), as in ``docs/conventions.md``.

With isotropic process and measurement noise and the small cross-axis coupling of the
orientation error dynamics neglected, the three axes share one ``(n+1) x (n+1)`` covariance, so
a step costs a few dozen flops and a full 60 s, 120 Hz run takes well under a millisecond.

Process noise is the white-noise model of ``trackflow.filters.MotionModel`` (kind
``"white_noise"``), so a tuned model transfers to the full 6-DoF filter unchanged. A
measurement whose squared normalised innovation ``d2 = |r|^2 / S`` exceeds ``gate`` gets its
variance inflated by ``d2 / gate`` (a Huber-type weight, for isolated outliers only), so a spike
pulls the state a bounded amount while genuine fast motion is still followed. After a gap
longer than ``gap_s`` the filter restarts from the measurement.
"""

from __future__ import annotations

import numpy as np

from ..math import numba_available

__all__ = ["run_predictor_position", "run_predictor_orientation"]


def _njit(fn):
    if numba_available():
        import numba

        return numba.njit(cache=True, fastmath=False)(fn)
    return fn  # pragma: no cover - NumPy-only installs run the same code uncompiled


@_njit
def _fact(k):
    f = 1.0
    for i in range(2, k + 1):
        f *= i
    return f


@_njit
def _propagate_cov(P, n, dt, noise, F, T):
    # P <- F P F^T + Q in place, F the Taylor transition of the derivative chain; F and T are
    # (n, n) scratch arrays (no allocation in the per-sample loop).
    for i in range(n):
        for j in range(n):
            F[i, j] = dt ** (j - i) / _fact(j - i) if j >= i else 0.0
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for m in range(i, n):
                acc += F[i, m] * P[m, j]
            T[i, j] = acc
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for m in range(j, n):
                acc += T[i, m] * F[j, m]
            P[i, j] = acc
    # white-noise process model (as trackflow.filters.MotionModel kind "white_noise"): level l
    # is driven by continuous white noise of density noise[l]^2, integrated exactly over dt:
    # Q_ij = sum_l s_l^2 dt^(2l-i-j+1) / ((l-i)! (l-j)! (2l-i-j+1)) for i, j <= l
    for lv in range(n):
        s2 = noise[lv] * noise[lv]
        if s2 == 0.0:
            continue
        for i in range(lv + 1):
            for j in range(lv + 1):
                e = 2 * lv - i - j + 1
                P[i, j] += s2 * dt**e / (_fact(lv - i) * _fact(lv - j) * e)


@_njit
def _joseph_update(P, n, S, R_eff, K, T):
    # Joseph form (I - K H) P (I - K H)^T + K R K^T with H = e_0, in place: it stays symmetric
    # positive semi-definite under rounding, which the short form P - K S K^T does not
    # guarantee when the gain is far from optimal (inflated measurement variances do exactly
    # that). With A = I - K e_0^T: (A P)_ij = P_ij - K_i P_0j.
    for i in range(n):
        K[i] = P[i, 0] / S
    for i in range(n):
        for j in range(n):
            T[i, j] = P[i, j] - K[i] * P[0, j]
    for i in range(n):
        for j in range(n):
            P[i, j] = T[i, j] - T[i, 0] * K[j] + K[i] * K[j] * R_eff


@_njit
def _advance(x, n, dt):
    # x[i] <- sum_j x[j] dt^(j-i) / (j-i)!, in place (ascending i reads only unchanged levels)
    for i in range(n):
        for j in range(i + 1, n):
            c = dt ** (j - i) / _fact(j - i)
            for a in range(3):
                x[i, a] += c * x[j, a]


@_njit
def run_predictor_position(t, z, n_deriv, noise, meas_sigma, gate, gap_s, horizons):
    """Filter positions and predict them ``horizons`` ahead of every sample.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Sample times [s], increasing.
    z : ndarray, shape (N, 3)
        Measured positions [m] (frame a).
    n_deriv : int
        Derivative levels above the value (0, 1 or 2).
    noise : ndarray, shape (n_deriv + 1,)
        White-noise densities per level [m / s^i / sqrt(s)] (``MotionModel`` "white_noise").
    meas_sigma : float
        Measurement standard deviation per axis [m].
    gate, gap_s : float
        Normalised-innovation threshold (squared, 3 DoF) and restart gap [s].
    horizons : ndarray, shape (H,)
        Prediction horizons [s].

    Returns
    -------
    pred : ndarray, shape (H, N, 3)
        ``pred[h, k]``: position at ``t[k] + horizons[h]`` predicted from samples ``0..k``.
    n_inflated : int
        Number of measurements whose variance was inflated by the gate.
    """
    N = t.shape[0]
    n = n_deriv + 1
    H = horizons.shape[0]
    pred = np.empty((H, N, 3))
    x = np.zeros((n, 3))
    P = np.zeros((n, n))
    F = np.zeros((n, n))
    T = np.zeros((n, n))
    K = np.zeros(n)
    r = np.zeros(3)
    R = meas_sigma * meas_sigma
    n_inflated = 0
    was_inflated = False
    for k in range(N):
        if k == 0 or (t[k] - t[k - 1]) > gap_s:
            x[:, :] = 0.0
            for a in range(3):
                x[0, a] = z[k, a]
            P[:, :] = 0.0
            P[0, 0] = R
            for i in range(1, n):
                P[i, i] = 1e6  # unknown derivatives: the next measurements determine them
            was_inflated = False
        else:
            dt = t[k] - t[k - 1]
            _propagate_cov(P, n, dt, noise, F, T)
            _advance(x, n, dt)
            d2 = 0.0
            for a in range(3):
                r[a] = z[k, a] - x[0, a]
                d2 += r[a] * r[a]
            S = P[0, 0] + R
            d2 /= S
            R_eff = R
            # Huber-type weight for isolated outliers only: a second large innovation in a row
            # is taken as real motion, so a lagging filter can never lock itself out.
            if d2 > gate and not was_inflated:
                R_eff = R + S * (d2 / gate - 1.0)
                n_inflated += 1
                was_inflated = True
            else:
                was_inflated = False
            _joseph_update(P, n, P[0, 0] + R_eff, R_eff, K, T)
            for i in range(n):
                for a in range(3):
                    x[i, a] += K[i] * r[a]
        for h in range(H):
            dh = horizons[h]
            for a in range(3):
                pred[h, k, a] = x[0, a]
            c = 1.0
            for i in range(1, n):
                c = c * dh / i
                for a in range(3):
                    pred[h, k, a] += c * x[i, a]
    return pred, n_inflated


@_njit
def _qmul(p0, p1, p2, p3, q0, q1, q2, q3):
    return (
        p3 * q0 + p0 * q3 + p1 * q2 - p2 * q1,
        p3 * q1 - p0 * q2 + p1 * q3 + p2 * q0,
        p3 * q2 + p0 * q1 - p1 * q0 + p2 * q3,
        p3 * q3 - p0 * q0 - p1 * q1 - p2 * q2,
    )


@_njit
def _qexp(v0, v1, v2):
    th = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    if th < 1e-8:
        return 0.5 * v0, 0.5 * v1, 0.5 * v2, 1.0
    k = np.sin(0.5 * th) / th
    return k * v0, k * v1, k * v2, np.cos(0.5 * th)


@_njit
def _qlog(q0, q1, q2, q3):
    if q3 < 0.0:
        q0, q1, q2, q3 = -q0, -q1, -q2, -q3
    nv = np.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
    k = 2.0 if nv < 1e-12 else 2.0 * np.arctan2(nv, q3) / nv
    return k * q0, k * q1, k * q2


@_njit
def _qnorm(q0, q1, q2, q3):
    s = 1.0 / np.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    return q0 * s, q1 * s, q2 * s, q3 * s


@_njit
def run_predictor_orientation(t, z, n_deriv, noise, meas_sigma, gate, gap_s, horizons):
    """Filter orientations and predict them ``horizons`` ahead of every sample.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Sample times [s], increasing.
    z : ndarray, shape (N, 4)
        Measured unit quaternions ``(x, y, z, w)`` of ``R_a_b``; sign flips are harmless.
    n_deriv : int
        Derivative levels above the orientation (0, 1 or 2); velocities are body-frame.
    noise : ndarray, shape (n_deriv + 1,)
        White-noise densities per level [rad / s^i / sqrt(s)] (``MotionModel`` "white_noise").
    meas_sigma : float
        Measurement standard deviation per axis of ``dtheta`` [rad].
    gate, gap_s : float
        Normalised-innovation threshold (squared, 3 DoF) and restart gap [s].
    horizons : ndarray, shape (H,)
        Prediction horizons [s].

    Returns
    -------
    pred : ndarray, shape (H, N, 4)
        Predicted orientation at ``t[k] + horizons[h]`` from samples ``0..k``.
    n_inflated : int
        Number of measurements whose variance was inflated by the gate.
    """
    N = t.shape[0]
    n = n_deriv + 1
    H = horizons.shape[0]
    pred = np.empty((H, N, 4))
    q0, q1, q2, q3 = 0.0, 0.0, 0.0, 1.0
    w = np.zeros((n, 3))  # w[0] is the orientation error itself (always folded into q)
    P = np.zeros((n, n))
    F = np.zeros((n, n))
    T = np.zeros((n, n))
    K = np.zeros(n)
    R = meas_sigma * meas_sigma
    n_inflated = 0
    was_inflated = False
    for k in range(N):
        if k == 0 or (t[k] - t[k - 1]) > gap_s:
            q0, q1, q2, q3 = z[k, 0], z[k, 1], z[k, 2], z[k, 3]
            w[:, :] = 0.0
            P[:, :] = 0.0
            P[0, 0] = R
            for i in range(1, n):
                P[i, i] = 1e6
            was_inflated = False
        else:
            dt = t[k] - t[k - 1]
            _propagate_cov(P, n, dt, noise, F, T)
            # q <- q Exp(w dt + alpha dt^2 / 2), w <- w + alpha dt (body frame)
            _advance(w, n, dt)
            d0, d1, d2_ = w[0, 0], w[0, 1], w[0, 2]
            w[0, :] = 0.0
            e = _qexp(d0, d1, d2_)
            q0, q1, q2, q3 = _qnorm(*_qmul(q0, q1, q2, q3, e[0], e[1], e[2], e[3]))
            c = _qmul(-q0, -q1, -q2, q3, z[k, 0], z[k, 1], z[k, 2], z[k, 3])
            r0, r1, r2 = _qlog(c[0], c[1], c[2], c[3])
            S = P[0, 0] + R
            d2 = (r0 * r0 + r1 * r1 + r2 * r2) / S
            R_eff = R
            if d2 > gate and not was_inflated:  # isolated outliers only, as for position
                R_eff = R + S * (d2 / gate - 1.0)
                n_inflated += 1
                was_inflated = True
            else:
                was_inflated = False
            _joseph_update(P, n, P[0, 0] + R_eff, R_eff, K, T)
            e = _qexp(K[0] * r0, K[0] * r1, K[0] * r2)
            q0, q1, q2, q3 = _qnorm(*_qmul(q0, q1, q2, q3, e[0], e[1], e[2], e[3]))
            for i in range(1, n):
                w[i, 0] += K[i] * r0
                w[i, 1] += K[i] * r1
                w[i, 2] += K[i] * r2
        for h in range(H):
            dh = horizons[h]
            s0, s1, s2 = 0.0, 0.0, 0.0
            c1 = 1.0
            for i in range(1, n):
                c1 = c1 * dh / i
                s0 += c1 * w[i, 0]
                s1 += c1 * w[i, 1]
                s2 += c1 * w[i, 2]
            e = _qexp(s0, s1, s2)
            p = _qmul(q0, q1, q2, q3, e[0], e[1], e[2], e[3])
            for a in range(4):
                pred[h, k, a] = p[a]
    return pred, n_inflated
