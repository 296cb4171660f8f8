"""Relative-motion extended Kalman filter of Dorfmueller-Ulhaas (seed 000, section 3).

The filter estimates only the *relative* motion of a rigid body between two frames,

    s = (omega, v, a)                                   (eq. 9)

angular velocity ``omega`` [rad/s], translational velocity ``v`` [m/s] and translational
acceleration ``a`` [m/s^2], all expressed in the fixed (world) frame ``w`` of the measurements.
Its measurements are three points on the body at the previous and at the current frame
(eq. 10), made from a pose by ``P_i = R e_i + t`` (eq. 11) when the sensor gives poses. The motion
model is Theorem 1: over an interval ``h`` a point moves as

    p(h) = W p(0) + V v + A a                           (eqs. 3-6)

with ``W = Exp(h omega)`` and ``V``, ``A`` the first and second time integrals of ``W``. This is
the exact flow of the velocity field ``dp/ds = omega x (p - c) + v + a s`` about an origin ``c``;
``v`` is the velocity of the spatial point ``c`` at the start of the interval. The paper uses the
world origin (``origin="world"``); ``origin="body"`` puts ``c`` at the previous body position
(the point C of the paper's figure 7), which keeps ``v`` the body's own velocity when the body is
far from the world origin. The state is shifted exactly when ``c`` moves (see :func:`predict`).

The update uses the implicit measurement function of eq. 13,
``f(x, s) = W P_i + V v + A a - P'_i = 0`` for ``i = 1..3``, with its derivatives eqs. 14-16
(:func:`residual`). The derivative of ``W P`` (and ``V v``, ``A a``) with respect to ``omega``
printed in the paper is right only when its ``[-omega~ P~ ...]`` bracket is read as the skew
matrix of the *vector* ``omega~ P``; read as the matrix product ``omega~ P~`` it disagrees with
finite differences. This module uses the form checked against finite differences; see
``docs/seed_filter_relative_motion.md``.

Uncertainty conventions: poses and their 6x6 covariances follow ``docs/conventions.md``
(``t_true = t + dt`` in frame w, ``R_true = R Exp(dtheta)`` with ``dtheta`` in the body frame).
The state covariance ``P`` is over the additive state error ``s_true = s + ds``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from trackflow.math import Pose, UncertainPose, quat_exp, quat_multiply, skew, so3_right_jacobian

from ...errors import InputError

__all__ = [
    "RelativeMotionEKF",
    "RelativeMotionState",
    "UpdateInfo",
    "motion_jacobians_omega",
    "motion_matrices",
    "points_from_poses",
    "predict",
    "predict_pose",
    "process_noise",
    "residual",
    "transition_matrix",
    "update",
]

Origin = Literal["world", "body"]

#: Body-frame vectors of the three measurement points of eq. 11 (rows): the unit axes.
UNIT_POINTS = np.eye(3)

# Below this angle phi = |omega| h the coefficient functions use their Taylor series; above it
# the closed forms lose at most ~eps / phi^6 ~ 1e-14 (the worst one divides by phi^6).
_SERIES_BELOW = 0.5
_SERIES_TERMS = 9
# Eigenvalues of the residual covariance below this fraction of the largest are treated as 0.
_RANK_TOLERANCE = 1e-10


def _series_tables() -> tuple[np.ndarray, np.ndarray]:
    """Taylor coefficients (in powers of ``phi^2``) of ``a_k`` and ``b_k``, k = 1..4: (4, terms)."""
    fact = np.cumprod(np.concatenate([[1.0], np.arange(1.0, 2 * _SERIES_TERMS + 6)]))
    ta = np.zeros((4, _SERIES_TERMS))
    tb = np.zeros((4, _SERIES_TERMS))
    for k in range(1, 5):
        for n in range(_SERIES_TERMS):
            sign = -1.0 if n % 2 else 1.0
            ta[k - 1, n] = sign / fact[2 * n + k]
            if n >= 1:
                tb[k - 1, n - 1] = sign * 2 * n / fact[2 * n + k]
    return ta, tb


_SERIES_A, _SERIES_B = _series_tables()


def _coefficients(phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Coefficient functions ``a_k(phi)`` and ``b_k(phi) = a_k'(phi) / phi`` for k = 1..4.

    ``a_k(phi) = sum_n (-1)^n phi^(2n) / (2n + k)!``, i.e.
    ``a1 = sin(phi)/phi``, ``a2 = (1 - cos phi)/phi^2``, ``a3 = (phi - sin phi)/phi^3``,
    ``a4 = (phi^2/2 - 1 + cos phi)/phi^4``. Returns arrays of shape ``(4,) + phi.shape``.
    """
    phi = np.asarray(phi, dtype=float)
    powers = (phi * phi)[..., None] ** np.arange(_SERIES_TERMS)
    series_a = np.moveaxis(powers @ _SERIES_A.T, -1, 0)
    series_b = np.moveaxis(powers @ _SERIES_B.T, -1, 0)
    if np.all(phi < _SERIES_BELOW):  # the usual case: no closed forms needed
        return series_a, series_b
    small = phi < _SERIES_BELOW
    p = np.where(small, 1.0, phi)  # safe divisor for the closed forms
    s, c = np.sin(p), np.cos(p)
    closed_a = np.stack(
        [
            s / p,
            (1.0 - c) / p**2,
            (p - s) / p**3,
            (0.5 * p**2 - 1.0 + c) / p**4,
        ]
    )
    closed_b = np.stack(
        [
            (p * c - s) / p**3,
            (p * s - 2.0 * (1.0 - c)) / p**4,
            (3.0 * s - p * (2.0 + c)) / p**5,
            (4.0 * (1.0 - c) - p**2 - p * s) / p**6,
        ]
    )
    return np.where(small, series_a, closed_a), np.where(small, series_b, closed_b)


def _matrix_coefficients(omega: np.ndarray, dt) -> tuple[np.ndarray, np.ndarray]:
    """``c[m, j]``, ``d[m, j]``: ``M_m = c[m,0] I + c[m,1] K + c[m,2] K^2``, ``K = [omega]x``.

    ``m`` indexes (W, V, A); ``d[m, j] = (dc[m, j]/dtheta) / theta`` so that
    ``d c[m, j] / d omega = d[m, j] omega``. Shapes ``(3, 3) + batch``.
    """
    h = np.asarray(dt, dtype=float)
    theta = np.linalg.norm(omega, axis=-1)
    a, b = _coefficients(theta * h)
    one = np.ones_like(theta)
    zero = np.zeros_like(theta)
    c = np.stack(
        [
            np.stack([one, h * a[0], h**2 * a[1]]),
            np.stack([h * one, h**2 * a[1], h**3 * a[2]]),
            np.stack([0.5 * h**2 * one, h**3 * a[2], h**4 * a[3]]),
        ]
    )
    d = np.stack(
        [
            np.stack([zero, h**3 * b[0], h**4 * b[1]]),
            np.stack([zero, h**4 * b[1], h**5 * b[2]]),
            np.stack([zero, h**5 * b[2], h**6 * b[3]]),
        ]
    )
    return c, d


def motion_matrices(omega, dt) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The matrices ``W``, ``V``, ``A`` of Theorem 1 (eqs. 4-6).

    ``W = I + sin(th h)/th K + (1 - cos(th h))/th^2 K^2 = Exp(h omega)``,
    ``V = h I + (1 - cos(th h))/th^2 K + (th h - sin(th h))/th^3 K^2``,
    ``A = h^2/2 I + (th h - sin(th h))/th^3 K + ((th h)^2 - 2(1 - cos(th h)))/(2 th^4) K^2``,
    with ``K = [omega]x`` and ``th = |omega|``; Taylor series are used for small ``th h`` so the
    result is smooth through ``omega = 0`` (where ``W = I``, ``V = h I``, ``A = h^2/2 I``).

    Parameters
    ----------
    omega : array_like, shape (..., 3)
        Angular velocity [rad/s] in the world frame.
    dt : float
        Interval ``h`` [s].

    Returns
    -------
    W, V, A : ndarray, shape (..., 3, 3)
        Point ``p(0)`` moves to ``W p(0) + V v + A a`` after ``h`` seconds (eq. 3).
    """
    omega = np.asarray(omega, dtype=float)
    if omega.shape[-1:] != (3,):
        raise InputError(f"omega must have shape (..., 3), got {omega.shape}")
    c, _ = _matrix_coefficients(omega, dt)
    k = skew(omega)
    k2 = k @ k
    eye = np.eye(3)
    mats = [
        c[m, 0][..., None, None] * eye
        + c[m, 1][..., None, None] * k
        + c[m, 2][..., None, None] * k2
        for m in range(3)
    ]
    return mats[0], mats[1], mats[2]


def motion_jacobians_omega(omega, dt, p, v, a) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Derivatives ``d(W p)/d omega``, ``d(V v)/d omega``, ``d(A a)/d omega`` (eq. 16).

    For ``M = c0 I + c1 K + c2 K^2`` and a fixed vector ``x``:

        d(M x)/d omega = -c1 [x]x + (K x)(dc1/d omega)^T
                         + c2 ((omega.x) I + omega x^T - 2 x omega^T) + (K^2 x)(dc2/d omega)^T

    with ``dc/d omega = (c'(th)/th) omega``. The third term is the derivative of
    ``omega x (omega x x)``; the paper prints it as ``-K [x]x + (omega^T x) I - x omega^T``, which
    equals it only if ``-K [x]x`` is read as ``-[K x]x`` (see the module docstring). At
    ``omega -> 0`` the derivatives tend to ``-h [p]x``, ``-h^2/2 [v]x`` and ``-h^3/6 [a]x``
    (the paper's limits); series keep them smooth there.

    Parameters
    ----------
    omega : array_like, shape (3,)
        Angular velocity [rad/s].
    dt : float
        Interval ``h`` [s].
    p, v, a : array_like, shape (3,)
        A point [m], a velocity [m/s] and an acceleration [m/s^2] (world frame).

    Returns
    -------
    J_Wp_omega, J_Vv_omega, J_Aa_omega : ndarray, shape (3, 3)
    """
    omega = np.asarray(omega, dtype=float)
    c, d = _matrix_coefficients(omega, dt)
    out = [
        _jacobian_omega(c[m], d[m], omega, np.asarray(x, dtype=float))
        for m, x in enumerate((p, v, a))
    ]
    return out[0], out[1], out[2]


def _jacobian_omega(c, d, omega, x):
    """``d(M x)/d omega`` for ``M = c0 I + c1 K + c2 K^2``; ``x`` of shape (..., 3)."""
    k = skew(omega)
    kx = x @ k.T
    kkx = kx @ k.T
    wx = x @ omega
    J_kkx_omega = (
        wx[..., None, None] * np.eye(3)
        + omega[:, None] * x[..., None, :]
        - 2.0 * x[..., :, None] * omega[None, :]
    )
    return (
        -c[1] * skew(x)
        + d[1] * kx[..., :, None] * omega
        + c[2] * J_kkx_omega
        + d[2] * kkx[..., :, None] * omega
    )


def transition_matrix(dt, origin_shift=None) -> np.ndarray:
    """State transition ``H`` (eq. 12), optionally with a shift of the velocity origin.

    ``H = [[I, 0, 0], [-[dc]x, I, h I], [0, 0, I]]``: ``omega`` and ``a`` stay, ``v`` advances
    by ``a h``. ``dc`` (default zero: the paper's eq. 12) moves the point whose velocity ``v``
    is: the flow's velocity at ``c + dc`` is ``v + omega x dc``.

    Parameters
    ----------
    dt : float
        Interval ``h`` [s] over which ``v`` advances.
    origin_shift : array_like, shape (3,), optional
        ``dc`` [m], world frame.

    Returns
    -------
    ndarray, shape (9, 9)
    """
    H = np.eye(9)
    H[3:6, 6:9] = float(dt) * np.eye(3)
    if origin_shift is not None:
        H[3:6, 0:3] = -skew(np.asarray(origin_shift, dtype=float))
    return H


def process_noise(dt, omega_sigma, velocity_sigma, accel_sigma) -> np.ndarray:
    """A diagonal process noise ``Q`` (9x9) of random-walk steps per frame.

    Parameters
    ----------
    dt : float
        Frame interval [s]; the sigmas are per ``sqrt(s)`` (random-walk densities), so the
        variances added per frame are ``sigma^2 dt``.
    omega_sigma : float
        [rad/s/sqrt(s)].
    velocity_sigma : float
        [m/s/sqrt(s)].
    accel_sigma : float
        [m/s^2/sqrt(s)].

    Returns
    -------
    ndarray, shape (9, 9)
        Covariance of the additive state change ``s_k = H s_{k-1} + n`` per frame.
    """
    sig = np.repeat([omega_sigma, velocity_sigma, accel_sigma], 3).astype(float)
    if np.any(sig < 0) or not np.all(np.isfinite(sig)) or not dt > 0:
        raise InputError("process noise sigmas must be finite and >= 0, dt > 0")
    return np.diag(sig**2 * float(dt))


def residual(state, points_prev, points_curr, dt, jacobians: bool = False):
    """The residual of eq. 13 and, optionally, its Jacobians (eqs. 14-16).

    ``f_i = W P_i + V v + A a - P'_i`` for the three points, with ``P_i`` at the previous frame
    and ``P'_i`` at the current one (the paper's eq. 13 maps the earlier points forward; its
    eq. 10 lists them the other way round).

    Parameters
    ----------
    state : array_like, shape (9,)
        ``(omega, v, a)``.
    points_prev, points_curr : array_like, shape (3, 3)
        Rows are the three points [m] relative to the motion origin ``c``, world axes.
    dt : float
        Interval between the two frames [s].
    jacobians : bool
        Also return ``J_f_s`` (9, 9) (eq. 15) and ``J_f_x`` (9, 18) (eq. 14). The measurement
        vector ``x`` is ordered ``(P_1, P_2, P_3, P'_1, P'_2, P'_3)`` (block order, not the
        interleaved columns printed in eq. 14).

    Returns
    -------
    f : ndarray, shape (9,)
    J_f_s, J_f_x : ndarray, only if ``jacobians``
    """
    s = np.asarray(state, dtype=float)
    prev = np.asarray(points_prev, dtype=float)
    curr = np.asarray(points_curr, dtype=float)
    if s.shape != (9,) or prev.shape != (3, 3) or curr.shape != (3, 3):
        raise InputError(
            f"state must be (9,), points (3, 3); got {s.shape}, {prev.shape}, {curr.shape}"
        )
    omega, v, a = s[0:3], s[3:6], s[6:9]
    W, V, A = motion_matrices(omega, dt)
    shift = V @ v + A @ a
    f = (prev @ W.T + shift - curr).reshape(9)
    if not jacobians:
        return f
    c, d = _matrix_coefficients(omega, dt)
    J_Wp = _jacobian_omega(c[0], d[0], omega, prev)  # (3, 3, 3): one per point
    J_shift = _jacobian_omega(c[1], d[1], omega, v) + _jacobian_omega(c[2], d[2], omega, a)
    J_f_s = np.zeros((9, 9))
    J_f_x = np.zeros((9, 18))
    for i in range(3):
        rows = slice(3 * i, 3 * i + 3)
        J_f_s[rows, 0:3] = J_Wp[i] + J_shift
        J_f_s[rows, 3:6] = V
        J_f_s[rows, 6:9] = A
        J_f_x[rows, 3 * i : 3 * i + 3] = W
        J_f_x[rows, 9 + 3 * i : 9 + 3 * i + 3] = -np.eye(3)
    return f, J_f_s, J_f_x


def points_from_poses(pose_prev: UncertainPose, pose_curr: UncertainPose, origin: Origin = "world"):
    """Measurement points of eq. 11 for two successive poses, with their covariance.

    ``P_i = R e_i + t - c`` with ``e_i`` the unit axes and ``c`` the motion origin: ``0`` for
    ``origin="world"`` (the paper), the previous position ``t_prev`` for ``origin="body"``.

    Uncertainty: with ``t_true = t + dt`` and ``R_true = R Exp(dtheta)`` (trackflow convention)
    a point moves by ``dP_i = dt - R [e_i]x dtheta`` (minus ``dt_prev`` for the body origin); the
    two poses are taken as independent, ``C_x = J_x_poses diag(C_prev, C_curr) J_x_poses^T``.

    Parameters
    ----------
    pose_prev, pose_curr : UncertainPose
        ``T_w_body`` at the previous and the current frame (single poses).
    origin : {"world", "body"}

    Returns
    -------
    points_prev, points_curr : ndarray, shape (3, 3)
        Rows are the points [m] relative to ``c``.
    cov_x : ndarray, shape (18, 18)
        Covariance of ``x = (P_1, P_2, P_3, P'_1, P'_2, P'_3)``.
    J_x_poses : ndarray, shape (18, 12)
        Jacobian of ``x`` with respect to ``(e_prev, e_curr)`` (6 + 6 pose errors).
    """
    if origin not in ("world", "body"):
        raise InputError(f"origin must be 'world' or 'body', got {origin!r}")
    if pose_prev.shape != () or pose_curr.shape != ():
        raise InputError("points_from_poses takes single poses")
    Rp, Rc = pose_prev.pose.rotation_matrix, pose_curr.pose.rotation_matrix
    c = pose_prev.position if origin == "body" else np.zeros(3)
    prev = UNIT_POINTS @ Rp.T + pose_prev.position - c
    curr = UNIT_POINTS @ Rc.T + pose_curr.position - c
    J = np.zeros((18, 12))
    for i in range(3):
        e = skew(UNIT_POINTS[i])
        r = slice(3 * i, 3 * i + 3)
        rc = slice(9 + 3 * i, 9 + 3 * i + 3)
        J[r, 3:6] = -Rp @ e
        J[rc, 9:12] = -Rc @ e
        J[rc, 6:9] = np.eye(3)
        if origin == "world":
            J[r, 0:3] = np.eye(3)
        else:
            J[rc, 0:3] = -np.eye(3)
    C = np.zeros((12, 12))
    C[:6, :6] = pose_prev.covariance
    C[6:, 6:] = pose_curr.covariance
    return prev, curr, J @ C @ J.T, J


@dataclass(frozen=True)
class RelativeMotionState:
    """Mean and covariance of the relative-motion state ``s = (omega, v, a)`` (eq. 9).

    Attributes
    ----------
    mean : ndarray, shape (9,)
        ``omega`` [rad/s], ``v`` [m/s], ``a`` [m/s^2], world axes; ``v`` is the velocity of the
        motion origin at the start of the interval the state describes.
    covariance : ndarray, shape (9, 9)
        Covariance of the additive error ``s_true = s + ds``.
    """

    mean: np.ndarray
    covariance: np.ndarray

    def __post_init__(self):
        m = np.array(self.mean, dtype=float)
        c = np.array(self.covariance, dtype=float)
        if m.shape != (9,) or c.shape != (9, 9):
            raise InputError(
                f"state mean (9,) and covariance (9, 9) expected, got {m.shape}, {c.shape}"
            )
        if not (np.all(np.isfinite(m)) and np.all(np.isfinite(c))):
            raise InputError("state mean and covariance must be finite")
        m.flags.writeable = False
        c.flags.writeable = False
        object.__setattr__(self, "mean", m)
        object.__setattr__(self, "covariance", c)

    @property
    def omega(self) -> np.ndarray:
        return self.mean[0:3]

    @property
    def velocity(self) -> np.ndarray:
        return self.mean[3:6]

    @property
    def acceleration(self) -> np.ndarray:
        return self.mean[6:9]


@dataclass(frozen=True)
class UpdateInfo:
    """Diagnostics of one update: residual before the update, its covariance and NIS.

    Attributes
    ----------
    residual : ndarray, shape (9,)
        ``f(x, s_prior)`` of eq. 13 [m].
    residual_covariance : ndarray, shape (9, 9)
        ``S = J_f_s P J_f_s^T + J_f_x C_x J_f_x^T (+ J_f_s C_motion J_f_s^T)``.
    nis : float
        ``f^T S^+ f`` (pseudo-inverse); chi-square with ``dof`` degrees of freedom when the
        model is consistent.
    dof : int
        Rank of ``S``: 9 for independent point noise, 6 when the points come from poses.
    """

    residual: np.ndarray
    residual_covariance: np.ndarray
    nis: float
    dof: int


def predict(
    state: RelativeMotionState, dt, process_noise_cov, origin_shift=None
) -> RelativeMotionState:
    """Time update ``s = H s``, ``P = H P H^T + Q`` (eq. 12).

    Parameters
    ----------
    state : RelativeMotionState
        Posterior of the interval just processed.
    dt : float
        Length [s] of that interval (``v`` advances to the start of the next one).
    process_noise_cov : array_like, shape (9, 9)
        ``Q`` (see :func:`process_noise`).
    origin_shift : array_like, shape (3,), optional
        Move of the motion origin ``c`` [m] (the body displacement for ``origin="body"``).

    Returns
    -------
    RelativeMotionState
    """
    H = transition_matrix(dt, origin_shift)
    Q = np.asarray(process_noise_cov, dtype=float)
    return RelativeMotionState(H @ state.mean, H @ state.covariance @ H.T + Q)


def update(
    state: RelativeMotionState,
    points_prev,
    points_curr,
    points_covariance,
    dt,
    motion_noise=None,
) -> tuple[RelativeMotionState, UpdateInfo]:
    """Measurement update with the implicit measurement ``f(x, s) = 0`` of eq. 13.

    Linearising ``f(x_true, s_true) = 0`` about ``(x, s)`` gives
    ``0 = f + J_f_s ds - J_f_x dx`` (``dx`` the measurement noise), so the EKF innovation is
    ``-f`` with effective noise ``R_e = J_f_x C_x J_f_x^T`` and ``K = P J_f_s^T S^-1``.

    Parameters
    ----------
    state : RelativeMotionState
        Prior ``s_{t|t-1}``.
    points_prev, points_curr : array_like, shape (3, 3)
        The three points at the previous and current frame (rows), relative to the origin.
    points_covariance : array_like, shape (18, 18)
        Covariance ``C_x`` of ``x = (P_1, P_2, P_3, P'_1, P'_2, P'_3)``.
    dt : float
        Interval between the two frames [s].
    motion_noise : array_like, shape (9, 9), optional
        Covariance of a white, per-interval deviation of the true kinematics from the state
        (the rectangular perturbations of the paper's section 3.3); enters as
        ``J_f_s C_motion J_f_s^T``.

    Returns
    -------
    RelativeMotionState, UpdateInfo
    """
    f, J_f_s, J_f_x = residual(state.mean, points_prev, points_curr, dt, jacobians=True)
    Cx = np.asarray(points_covariance, dtype=float)
    if Cx.shape != (18, 18):
        raise InputError(f"points_covariance must be (18, 18), got {Cx.shape}")
    R = J_f_x @ Cx @ J_f_x.T
    if motion_noise is not None:
        R = R + J_f_s @ np.asarray(motion_noise, dtype=float) @ J_f_s.T
    P = state.covariance
    S = J_f_s @ P @ J_f_s.T + R
    S = 0.5 * (S + S.T)
    # A rigid relative motion has 6 degrees of freedom but f has 9 components: when the points
    # come from poses (always exactly rigid), S is singular in the 3 directions that break
    # rigidity, and f has no first-order component there. The pseudo-inverse drops them.
    lam, U = np.linalg.eigh(S)
    keep = lam > _RANK_TOLERANCE * max(lam[-1], 0.0)
    if not np.any(keep):
        raise InputError("residual covariance is zero: give the points or the state a covariance")
    S_pinv = (U[:, keep] / lam[keep]) @ U[:, keep].T
    K = P @ J_f_s.T @ S_pinv
    mean = state.mean - K @ f
    # Joseph form: stays symmetric positive semi-definite under rounding and is correct for
    # any gain (here a pseudo-inverse gain), which matters because S can be badly conditioned
    # (v and a are nearly collinear in one interval: V ~ h I, A ~ h^2/2 I).
    I_KH = np.eye(9) - K @ J_f_s
    cov = I_KH @ P @ I_KH.T + K @ R @ K.T
    cov = 0.5 * (cov + cov.T)
    nis = float(f @ S_pinv @ f)
    return RelativeMotionState(mean, cov), UpdateInfo(f, S, nis, int(np.count_nonzero(keep)))


def predict_pose(
    state: RelativeMotionState,
    pose: UncertainPose,
    horizon,
    origin: Origin = "world",
    jacobians: bool = False,
):
    """Predicted pose ``R+, t+`` from the state (the paper's F4), for latency compensation.

    ``R+ = W R``, ``t+ = c + W (t - c) + V v + A a`` with ``W, V, A`` of Theorem 1 for
    ``h = horizon``, ``c = 0`` (world origin) or ``c = t`` (body origin). ``state`` must describe
    the motion *starting at the time of* ``pose`` (a prior from :func:`predict`).

    Uncertainty: ``R+ Exp(dtheta+) = W(omega + domega) R Exp(dtheta)`` and
    ``Exp(h (omega + domega)) ~ Exp(h omega) Exp(h J_r(h omega) domega)`` give
    ``dtheta+ = dtheta + h R^T J_r(h omega) domega``; ``dt+ = W dt + d(W t)/d omega domega +
    V dv + A da + d(Vv + Aa)/d omega domega`` (``W dt`` is replaced by ``dt`` for the body origin).
    The state and the pose are taken as independent:
    ``C+ = J_+_s P J_+_s^T + J_+_pose C J_+_pose^T`` in trackflow's convention.

    Parameters
    ----------
    state : RelativeMotionState
    pose : UncertainPose
        ``T_w_body`` at the start of the prediction (single pose).
    horizon : float
        Prediction time [s] (0 returns the pose).
    origin : {"world", "body"}
        Must match the origin the state was estimated with.
    jacobians : bool
        Also return ``J_pred_state`` (6, 9) and ``J_pred_pose`` (6, 6).

    Returns
    -------
    UncertainPose (and the Jacobians if asked)
    """
    if origin not in ("world", "body"):
        raise InputError(f"origin must be 'world' or 'body', got {origin!r}")
    h = float(horizon)
    omega, v, a = state.omega, state.velocity, state.acceleration
    W, V, A = motion_matrices(omega, h)
    R = pose.pose.rotation_matrix
    t = pose.position
    c = t if origin == "body" else np.zeros(3)
    t_new = c + W @ (t - c) + V @ v + A @ a
    q_new = quat_multiply(quat_exp(h * omega), pose.quaternion)
    J_Wp, J_Vv, J_Aa = motion_jacobians_omega(omega, h, t - c, v, a)
    J_s = np.zeros((6, 9))
    J_s[0:3, 0:3] = J_Wp + J_Vv + J_Aa
    J_s[0:3, 3:6] = V
    J_s[0:3, 6:9] = A
    J_s[3:6, 0:3] = h * R.T @ so3_right_jacobian(h * omega)
    J_p = np.zeros((6, 6))
    J_p[0:3, 0:3] = np.eye(3) if origin == "body" else W
    J_p[3:6, 3:6] = np.eye(3)
    cov = J_s @ state.covariance @ J_s.T + J_p @ pose.covariance @ J_p.T
    out = UncertainPose(Pose(t_new, q_new, normalize=True), 0.5 * (cov + cov.T))
    if jacobians:
        return out, J_s, J_p
    return out


class RelativeMotionEKF:
    """Runs the relative-motion EKF on a stream of uncertain poses.

    Explicit state only: ``state`` (the prior for the interval that starts at the last pose,
    after the first update) and ``last_pose``; nothing else is kept between calls.

    Parameters
    ----------
    initial : RelativeMotionState
        Prior for the first interval.
    process_noise_cov : array_like, shape (9, 9)
        ``Q`` per frame (see :func:`process_noise`).
    origin : {"world", "body"}
        Motion origin (see the module docstring); the paper uses ``"world"``.
    motion_noise : array_like, shape (9, 9), optional
        Per-interval white kinematic noise (see :func:`update`).

    Examples
    --------
    >>> import numpy as np
    >>> from trackflow import Pose, UncertainPose
    >>> ekf = RelativeMotionEKF(RelativeMotionState(np.zeros(9), np.eye(9)),
    ...                         process_noise(0.01, 0.1, 0.1, 1.0))
    >>> cov = np.diag([1e-6] * 3 + [1e-6] * 3)
    >>> for k in range(5):
    ...     info = ekf.step(k * 0.01, UncertainPose(Pose([0.005 * k, 0, 0], [0, 0, 0, 1]), cov))
    >>> bool(abs(ekf.state.velocity[0] - 0.5) < 0.05)
    True
    """

    def __init__(self, initial, process_noise_cov, origin: Origin = "world", motion_noise=None):
        if origin not in ("world", "body"):
            raise InputError(f"origin must be 'world' or 'body', got {origin!r}")
        self.state: RelativeMotionState = initial
        self.Q = np.asarray(process_noise_cov, dtype=float)
        self.origin: Origin = origin
        self.motion_noise = motion_noise
        self.last_pose: UncertainPose | None = None
        self.last_time: float | None = None
        self.posterior: RelativeMotionState | None = None

    def step(self, time, pose: UncertainPose) -> UpdateInfo | None:
        """Feed the pose at ``time`` [s]; returns the update diagnostics (None for the first).

        Raises ``ValueError`` for non-increasing time stamps.
        """
        time = float(time)
        if self.last_pose is None:
            self.last_pose, self.last_time = pose, time
            return None
        dt = time - self.last_time
        if not dt > 0:
            raise InputError(f"time stamps must increase: {time} after {self.last_time}")
        prev, curr, Cx, _ = points_from_poses(self.last_pose, pose, self.origin)
        post, info = update(self.state, prev, curr, Cx, dt, self.motion_noise)
        shift = pose.position - self.last_pose.position if self.origin == "body" else None
        self.posterior = post
        self.state = predict(post, dt, self.Q, shift)
        self.last_pose, self.last_time = pose, time
        return info

    def predicted_pose(self, horizon) -> UncertainPose:
        """Pose ``horizon`` seconds after the last one fed (F4); see :func:`predict_pose`."""
        if self.last_pose is None:
            raise InputError("no pose has been fed yet")
        return predict_pose(self.state, self.last_pose, horizon, self.origin)
