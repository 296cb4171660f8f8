"""Numeric kernels of the inertial error-state filter (plain NumPy, compiled by numba if present).

Every function here works on small dense arrays with loops and elementwise NumPy so that the
same source runs as Python (the reference) and under ``numba.njit`` (``driver`` picks one).
The model, its error state and the formulas are documented in :mod:`.model`; SO(3)
(``Exp``, ``Log``, ``Jr``, ``[v]x``) comes from :mod:`trackflow.math._lie`.

Nominal state: ``x`` (15,) = ``(p_w_s, v_w_s, unused (3), b_g, b_a)`` and ``R`` (3, 3) =
``R_w_s``; covariance ``P`` (n, n) with ``n = 15`` (strapdown) or ``n = 12`` (gyro-driven
orientation, constant-velocity position, no accelerometer bias).
"""

from __future__ import annotations

import numpy as np

from trackflow.math._lie import hat, right_jac, so3_exp, so3_log

__all__ = [
    "KERNELS",
    "transition",
    "propagate",
    "pose_jacobian",
    "update_pose",
    "gravity_jacobian",
    "update_gravity",
    "update_trend",
    "predict_ahead",
    "run_events",
]

#: Names compiled by the driver when numba is available.
KERNEL_SOURCES = ("trackflow.math._lie",)
KERNELS = (
    "transition",
    "propagate",
    "pose_jacobian",
    "update_pose",
    "gravity_jacobian",
    "update_gravity",
    "update_trend",
    "predict_ahead",
    "push_gyro",
    "run_events",
    "_inject",
    "_kalman",
)

# error-state blocks
IP, IV, ITH, IBG, IBA = 0, 3, 6, 9, 12


def transition(x, r, gyro, accel, dt, g, n):
    """Error-state transition ``J_xnext_x`` (n, n) and the input Jacobians of one step.

    Parameters
    ----------
    x : ndarray (15,)
        Nominal state before the step (``p, v, -, b_g, b_a``).
    r : ndarray (3, 3)
        ``R_w_s`` before the step.
    gyro, accel : ndarray (3,)
        Measured angular velocity [rad/s] and specific force [m/s^2] held over the step.
    dt : float
        Step [s].
    g : ndarray (3,)
        Gravity in the world frame [m/s^2].
    n : int
        15 (strapdown) or 12 (gyro only).

    Returns
    -------
    J_xnext_x : ndarray (n, n)
    J_xnext_gyro : ndarray (n, 3)
        Derivative of the next error state by the gyro reading.
    J_xnext_accel : ndarray (n, 3)
        Derivative by the accelerometer reading (zero for ``n = 12``).
    """
    w = gyro - x[IBG : IBG + 3]
    phi = w * dt
    jr = right_jac(phi)
    f = np.zeros(3)
    if n == 15:
        f = accel - x[IBA : IBA + 3]
    rf = r @ hat(f)
    F = np.eye(n)
    for i in range(3):
        F[IP + i, IV + i] = dt
    dexp_t = so3_exp(phi).T
    for i in range(3):
        for j in range(3):
            F[ITH + i, ITH + j] = dexp_t[i, j]
            F[ITH + i, IBG + j] = -jr[i, j] * dt
            if n == 15:
                F[IV + i, ITH + j] = -rf[i, j] * dt
                F[IP + i, ITH + j] = -0.5 * rf[i, j] * dt * dt
                F[IV + i, IBA + j] = -r[i, j] * dt
                F[IP + i, IBA + j] = -0.5 * r[i, j] * dt * dt
    G = np.zeros((n, 3))
    A = np.zeros((n, 3))
    for i in range(3):
        for j in range(3):
            G[ITH + i, j] = jr[i, j] * dt
            if n == 15:
                A[IV + i, j] = r[i, j] * dt
                A[IP + i, j] = 0.5 * r[i, j] * dt * dt
    return F, G, A


def propagate(x, r, P, gyro, accel, dt, g, noise, n):
    """One strapdown step in place: nominal state, ``R_w_s`` and covariance.

    ``noise`` (4,) holds white-noise densities: gyro [rad/s/sqrt(Hz)], accelerometer
    [m/s^2/sqrt(Hz)] (for ``n = 12`` the white acceleration of the constant-velocity model),
    gyro bias random walk [rad/s^2/sqrt(Hz)], accelerometer bias random walk
    [m/s^3/sqrt(Hz)]. Returns the new ``R_w_s`` (3, 3).
    """
    if dt <= 0.0:
        return r
    F, G, A = transition(x, r, gyro, accel, dt, g, n)
    w = gyro - x[IBG : IBG + 3]
    if n == 15:
        a = r @ (accel - x[IBA : IBA + 3]) + g
    else:
        a = np.zeros(3)
    for i in range(3):
        x[IP + i] += x[IV + i] * dt + 0.5 * a[i] * dt * dt
        x[IV + i] += a[i] * dt
    r_new = r @ so3_exp(w * dt)
    Pn = F @ P @ F.T
    sg2 = noise[0] * noise[0] / dt  # discrete variance of one held reading
    sa2 = noise[1] * noise[1] / dt
    Pn += sg2 * (G @ G.T)
    if n == 15:
        Pn += sa2 * (A @ A.T)
    else:
        q = noise[1] * noise[1]
        for i in range(3):  # white acceleration on a constant-velocity model
            Pn[IP + i, IP + i] += q * dt**3 / 3.0
            Pn[IP + i, IV + i] += q * dt * dt / 2.0
            Pn[IV + i, IP + i] += q * dt * dt / 2.0
            Pn[IV + i, IV + i] += q * dt
    for i in range(3):
        Pn[IBG + i, IBG + i] += noise[2] * noise[2] * dt
        if n == 15:
            Pn[IBA + i, IBA + i] += noise[3] * noise[3] * dt
    P[:, :] = 0.5 * (Pn + Pn.T)
    return r_new


def pose_jacobian(x, r, r_sb, t_sb, n):
    """``J_pose_x`` (6, n): pose ``T_w_b = T_w_s T_s_b`` error ``(dt, dtheta_b)`` by error state."""
    H = np.zeros((6, n))
    k = -(r @ hat(t_sb))
    for i in range(3):
        H[i, IP + i] = 1.0
        for j in range(3):
            H[i, ITH + j] = k[i, j]
            H[3 + i, ITH + j] = r_sb[j, i]
    return H


def _inject(x, r, dx, n):
    for i in range(3):
        x[IP + i] += dx[IP + i]
        x[IV + i] += dx[IV + i]
        x[IBG + i] += dx[IBG + i]
        if n == 15:
            x[IBA + i] += dx[IBA + i]
    return r @ so3_exp(dx[ITH : ITH + 3])


def _kalman(x, r, P, y, H, Rm, gate, n):
    """Shared gain, gate and Joseph update; returns (new R_w_s, NIS, accepted)."""
    S = H @ P @ H.T + Rm
    Sinv = np.linalg.inv(S)
    nis = y @ Sinv @ y
    if gate > 0.0 and nis > gate:
        return r, nis, False
    K = P @ H.T @ Sinv
    dx = K @ y
    r_new = _inject(x, r, dx, n)
    IKH = np.eye(n) - K @ H
    Pn = IKH @ P @ IKH.T + K @ Rm @ K.T
    P[:, :] = 0.5 * (Pn + Pn.T)
    return r_new, nis, True


def update_pose(x, r, P, z_p, z_r, Rm, r_sb, t_sb, gate, n):
    """Fuse a pose ``T_w_b`` (position ``z_p`` (3,), rotation ``z_r`` (3, 3)), cov ``Rm`` (6, 6).

    The innovation is ``(z_p - p_pred, Log(R_pred^T z_r))`` (trackflow's error convention).
    ``gate > 0`` rejects an innovation whose NIS exceeds it. Returns ``(R_w_s, nis, accepted)``.
    """
    p_pred = x[IP : IP + 3] + r @ t_sb
    r_pred = r @ r_sb
    y = np.empty(6)
    y[:3] = z_p - p_pred
    y[3:] = so3_log(r_pred.T @ z_r)
    H = pose_jacobian(x, r, r_sb, t_sb, n)
    return _kalman(x, r, P, y, H, Rm, gate, n)


def gravity_jacobian(x, r, g, n):
    """``J_accel_x`` (3, n) of the at-rest accelerometer model ``f = -R_w_s^T g + b_a``."""
    H = np.zeros((3, n))
    k = hat(-(r.T @ g))
    for i in range(3):
        for j in range(3):
            H[i, ITH + j] = k[i, j]
        if n == 15:
            H[i, IBA + i] = 1.0
    return H


def update_gravity(x, r, P, accel, g, sigma, gate, n):
    """Fuse an accelerometer reading as a gravity direction measurement (IMU-only mode).

    ``sigma`` [m/s^2] is the per-axis standard deviation (sensor noise plus unmodelled linear
    acceleration). Returns ``(R_w_s, nis, accepted)``.
    """
    h = -(r.T @ g)
    if n == 15:
        h = h + x[IBA : IBA + 3]
    y = accel - h
    H = gravity_jacobian(x, r, g, n)
    Rm = np.eye(3) * (sigma * sigma)
    return _kalman(x, r, P, y, H, Rm, gate, n)


def update_trend(trend, x, r, gyro, accel, g, dt, smooth, n):
    """Track level and slope of the bias-corrected inputs for prediction (in place).

    ``trend`` (4, 3) holds the angular velocity ``omega_s`` [rad/s], its slope [rad/s^2], the
    world acceleration ``a_w = R (f - b_a) + g`` [m/s^2] and its slope [m/s^3]. Brown's double
    exponential smoothing with time constant ``smooth`` [s] (``theta = exp(-dt / smooth)``,
    gains ``1 - theta^2`` and ``(1 - theta)^2 / dt``); ``smooth <= 0`` holds the raw sample and
    a zero slope. For ``n = 12`` the acceleration stays zero.
    """
    w = gyro - x[IBG : IBG + 3]
    a = np.zeros(3)
    if n == 15:
        a = r @ (accel - x[IBA : IBA + 3]) + g
    if smooth <= 0.0 or dt <= 0.0:
        for i in range(3):
            trend[0, i] = w[i]
            trend[1, i] = 0.0
            trend[2, i] = a[i]
            trend[3, i] = 0.0
        return
    th = np.exp(-dt / smooth)
    ga = 1.0 - th * th
    gb = (1.0 - th) * (1.0 - th) / dt
    for i in range(3):
        e = w[i] - (trend[0, i] + trend[1, i] * dt)
        trend[0, i] += trend[1, i] * dt + ga * e
        trend[1, i] += gb * e
        e = a[i] - (trend[2, i] + trend[3, i] * dt)
        trend[2, i] += trend[3, i] * dt + ga * e
        trend[3, i] += gb * e


def predict_ahead(
    x, r, trend, use_slope, coef, wbuf, coef_a, abuf, h, hi, r_sb, t_sb, out_p, out_r,
    dt_extra=0.0,
):  # fmt: skip
    """Pose ``T_w_b`` ``h + dt_extra`` seconds after the state's time, from the input trend
    (no state change).

    ``dt_extra`` >= 0 is the time from the state to the query the horizon ``h`` counts from
    (0 right after a sample): the trend extrapolations run over ``h + dt_extra``; a learned
    extrapolation, fitted for ``h`` itself, starts from the orientation turned on by the
    trend's angular velocity over ``dt_extra``.

    Orientation: with learned coefficients (``coef`` (H, 3 L), ``L > 0``) it turns by
    ``Exp(phi_w) R`` with ``phi_w[i] = sum_j coef[hi, 3 j + i] wbuf[j, i]`` over the last ``L``
    world-frame angular velocities (newest first, one weight per lag and axis), else by
    ``R Exp(omega h + alpha h^2 / 2)`` from the trend (``alpha`` only when ``use_slope``).
    Position moves with the velocity, the world acceleration and
    (``use_slope``) its slope, or with learned weights ``coef_a`` (H, La) over the world
    acceleration history ``abuf``. Writes ``out_p`` (3,) and ``out_r`` (3, 3).
    """
    s = 1.0 if use_slope else 0.0
    L = coef.shape[1]
    hq = h + dt_extra
    if L > 0:  # world-frame rotation increment from the world-frame history
        phi = np.zeros(3)
        for j in range(L // 3):
            for i in range(3):
                phi[i] += coef[hi, 3 * j + i] * wbuf[j, i]
        if dt_extra > 0.0:
            rh = so3_exp(phi) @ (r @ so3_exp(trend[0] * dt_extra))
        else:
            rh = so3_exp(phi) @ r
    else:
        phi = trend[0] * hq + s * 0.5 * trend[1] * hq * hq
        rh = r @ so3_exp(phi)
    h = hq
    ph = x[IP : IP + 3] + x[IV : IV + 3] * h
    if coef_a.shape[1] > 0:
        for j in range(coef_a.shape[1]):
            for i in range(3):
                ph[i] += coef_a[hi, j] * abuf[j, i]
    else:
        ph = ph + 0.5 * trend[2] * h * h + s * trend[3] * (h * h * h / 6.0)
    out_p[:] = ph + rh @ t_sb
    out_r[:, :] = rh @ r_sb


def push_gyro(wbuf, abuf, trend, x, r, gyro):
    """Shift the histories by one: the bias-corrected angular velocity in the world frame,
    ``R_w_s (omega - b_g)``, into ``wbuf`` (L, 3), the world acceleration of the trend
    (``trend[2]``, updated first) into ``abuf`` (La, 3)."""
    for j in range(wbuf.shape[0] - 1, 0, -1):
        for i in range(3):
            wbuf[j, i] = wbuf[j - 1, i]
    if wbuf.shape[0] > 0:
        w_world = r @ (gyro - x[IBG : IBG + 3])
        for i in range(3):
            wbuf[0, i] = w_world[i]
    for j in range(abuf.shape[0] - 1, 0, -1):
        for i in range(3):
            abuf[j, i] = abuf[j - 1, i]
    if abuf.shape[0] > 0:
        for i in range(3):
            abuf[0, i] = trend[2, i]


def run_events(
    kind,
    t,
    idx,
    gyro,
    accel,
    z_p,
    z_r,
    Rm,
    x,
    r,
    P,
    g,
    noise,
    r_sb,
    t_sb,
    gate,
    horizons,
    smooth,
    use_slope,
    coef,
    coef_a,
    hold_preceding,
    n,
    out_p,
    out_r,
    out_nis,
):
    """Run the filter over a merged, time-sorted event list (the offline driver's loop).

    Parameters
    ----------
    kind : int8 (E,)
        0 = IMU sample, 1 = pose measurement, 2 = pose measurement scored (predict after it),
        3 = query: predict ``horizons`` after the event's time from the state at the last IMU
        sample (:func:`predict_ahead` with ``dt_extra``; no state change; output row ``idx``).
    t : float (E,)
        Event times [s].
    idx : int (E,)
        Row in ``gyro``/``accel`` (IMU events) or in ``z_p``/``z_r``/``out_*`` (pose events).
    gyro, accel : (M, 3); z_p : (K, 3); z_r : (K, 3, 3); Rm : (6, 6)
    x, r, P : initial state (modified in place)
    smooth, use_slope : input trend for the predictions (:func:`update_trend`)
    coef : (H, 3 L) learned gyro extrapolation per horizon and axis (``L = 0``: the trend)
    coef_a : (H, La) learned world-acceleration extrapolation (``La = 0``: the trend)
    hold_preceding : integrate each IMU sample over the interval ending at its stamp (else the
        trapezoid of the two samples bounding the interval)
    out_p : (H, K, 3), out_r : (H, K, 3, 3)
        Predicted poses ``T_w_b`` written at scored pose events.
    out_nis : (K,) NIS of each pose update (``nan`` when gated out)

    Returns
    -------
    (R_w_s, t_state) at the end.
    """
    t_state = t[0]
    last = -1
    t_imu = t[0]
    trend = np.zeros((4, 3))
    wbuf = np.zeros((coef.shape[1] // 3, 3))
    abuf = np.zeros((coef_a.shape[1], 3))
    for e in range(t.shape[0]):
        k = kind[e]
        te = t[e]
        if k == 0:
            i = idx[e]
            if last >= 0:
                if hold_preceding:  # each sample covers the interval that ends at its stamp
                    wg, wa = gyro[i], accel[i]
                else:
                    wg = 0.5 * (gyro[last] + gyro[i])
                    wa = 0.5 * (accel[last] + accel[i])
                r = propagate(x, r, P, wg, wa, te - t_state, g, noise, n)
            dt_imu = te - t_imu
            update_trend(trend, x, r, gyro[i], accel[i], g, dt_imu, smooth, n)
            push_gyro(wbuf, abuf, trend, x, r, gyro[i])
            t_state = te
            t_imu = te
            last = i
        elif k == 3:
            if last < 0:
                continue
            j = idx[e]
            for hh in range(horizons.shape[0]):
                predict_ahead(
                    x, r, trend, use_slope, coef, wbuf, coef_a, abuf, horizons[hh], hh,
                    r_sb, t_sb, out_p[hh, j], out_r[hh, j], te - t_state,
                )  # fmt: skip
        else:
            if last < 0:
                continue
            j = idx[e]
            r = propagate(x, r, P, gyro[last], accel[last], te - t_state, g, noise, n)
            t_state = te
            r, nis, ok = update_pose(x, r, P, z_p[j], z_r[j], Rm, r_sb, t_sb, gate, n)
            out_nis[j] = nis if ok else np.nan
            if k == 2:
                for hh in range(horizons.shape[0]):
                    predict_ahead(
                        x, r, trend, use_slope, coef, wbuf, coef_a, abuf, horizons[hh], hh,
                        r_sb, t_sb, out_p[hh, j], out_r[hh, j],
                    )  # fmt: skip
    return r, t_state
