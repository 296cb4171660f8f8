"""Filtering in the unit quaternion space with Gauss-Newton on the manifold (Ude 1999).

The state at time ``t_i`` is ``x = (p, q, v, w)`` on ``R3 x S3 x R3 x R3``: the pose ``T_w_b``
of a rigid body (``x_w = R(q) x_b + p``), the velocity ``v`` of the body origin and the angular
velocity ``w`` [rad/s], both in the world (reference) frame w. Prediction is constant velocity
(paper eqs. 11-14): ``p+ = p + dt v``, ``q+ = Exp(dt w) * q``, ``v+ = v``, ``w+ = w``.
Adjustment minimises the nonlinear least-squares criterion of eq. 24 (image features of M
calibrated cameras plus the prediction prior) by Gauss-Newton on the manifold (eqs. 26-30), or
by Levenberg-Marquardt for bad starting points.

Error parameterisation (12x12 covariance ``S``)
----------------------------------------------
``e = (e_p, e_phi, e_v, e_w)`` with

    p_true = p + e_p,   q_true = Exp(e_phi) * q,   v_true = v + e_v,   w_true = w + e_w

``e_phi`` is a rotation vector (radians, full angle) in the world frame, on the *left*. The
paper writes ``q = exp(u_q) * q_true`` with its half-angle ``exp`` (eq. 6), so
``e_phi = -2 u_q`` (and ``e_p = -u_p`` etc.; the sign does not change a covariance). With the
full angle, the paper's transition matrix (eq. 22, with ``R(dt w)`` and
``G = int_0^dt R(s w) ds``, eq. 21) and process noise (eq. 23) are consistent as printed; the
prior residual of eq. 24 is ``Log(q * q_hat^-1) = 2 log_paper(q * conj(q_hat))`` and the update
of eq. 28 ``exp_paper(dr) * q`` is ``Exp(dphi) * q`` with ``dphi = 2 dr``. (Read literally, the
paper mixes the half-angle ``u_q`` of eqs. 16/24 with the full-angle ``G`` and ``alpha`` of
eqs. 20-23; ``orientation_error="paper"`` reproduces that mix for comparison.)

Conversion to trackflow's :class:`UncertainPose` (``docs/conventions.md``): trackflow's error is
``(dt, dtheta)`` with ``t_true = t + dt`` and ``R_true = R Exp(dtheta)`` (body frame, on the
right). Since ``Exp(e_phi) R = R Exp(R^T e_phi)``: ``dt = e_p``, ``dtheta = R^T e_phi`` and

    C_trackflow = T S[:6, :6] T^T,   T = blockdiag(I, R^T).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from trackflow.math import (
    Pose,
    UncertainPose,
    check_quaternion,
    quat_align_sign,
    quat_conjugate,
    quat_exp,
    quat_log,
    quat_multiply,
    quat_normalize,
    quat_to_matrix,
    so3_right_jacobian,
    so3_right_jacobian_inverse,
)

from ...errors import InputError, NumericalError
from .camera_features import CameraObservation

__all__ = [
    "QuaternionSpaceState",
    "SolverReport",
    "QuaternionSpaceFilter",
    "transition_jacobian",
    "process_noise",
    "predict_state",
    "adjust_state",
    "estimate_pose",
    "solve_on_manifold",
    "prior_residual",
]


@dataclass(frozen=True)
class QuaternionSpaceState:
    """State ``(p, q, v, w)`` and the 12x12 covariance of its error, at one time.

    Parameters
    ----------
    time : float
        [s].
    position : ndarray, shape (3,)
        ``p`` of ``T_w_b`` [m].
    quaternion : ndarray, shape (4,)
        ``q`` of ``T_w_b``, (x, y, z, w).
    velocity : ndarray, shape (3,)
        Velocity of the body origin in w [m/s].
    angular_velocity : ndarray, shape (3,)
        Angular velocity in w [rad/s] (``q(t + s) = Exp(s w) * q(t)``).
    covariance : ndarray, shape (12, 12)
        Covariance of ``e = (e_p, e_phi, e_v, e_w)``: ``p_true = p + e_p``,
        ``q_true = Exp(e_phi) * q`` (world frame, radians), ``v_true = v + e_v``,
        ``w_true = w + e_w`` (module docstring).
    """

    time: float
    position: np.ndarray
    quaternion: np.ndarray
    velocity: np.ndarray
    angular_velocity: np.ndarray
    covariance: np.ndarray

    def __post_init__(self):
        for name in ("position", "velocity", "angular_velocity"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise InputError(f"QuaternionSpaceState.{name} must be 3 finite numbers, got {v}")
            object.__setattr__(self, name, v)
        q = check_quaternion(self.quaternion, name="QuaternionSpaceState.quaternion")
        if q.shape != (4,):
            raise InputError(f"QuaternionSpaceState.quaternion must have shape (4,), got {q.shape}")
        object.__setattr__(self, "quaternion", q)
        c = np.asarray(self.covariance, dtype=float)
        if c.shape != (12, 12) or not np.all(np.isfinite(c)):
            raise InputError(f"QuaternionSpaceState.covariance must be finite 12x12, got {c.shape}")
        if not np.allclose(c, c.T, rtol=1e-9, atol=1e-12 * np.max(np.abs(c), initial=1.0)):
            raise InputError("QuaternionSpaceState.covariance must be symmetric")
        object.__setattr__(self, "covariance", 0.5 * (c + c.T))
        object.__setattr__(self, "time", float(self.time))

    def pose_covariance(self) -> np.ndarray:
        """6x6 covariance in trackflow's convention: ``C = T S[:6,:6] T^T``, T = diag(I, R^T)."""
        T = np.zeros((6, 6))
        T[:3, :3] = np.eye(3)
        T[3:, 3:] = quat_to_matrix(self.quaternion).T
        return T @ self.covariance[:6, :6] @ T.T

    def uncertain_pose(self) -> UncertainPose:
        """The pose ``T_w_b`` with its covariance over ``(dt, dtheta)`` (trackflow convention)."""
        return UncertainPose(Pose(self.position, self.quaternion), self.pose_covariance())

    def as_vector(self) -> np.ndarray:
        """``(p, q, v, w)`` as a flat array of 13 numbers."""
        return np.concatenate(
            [self.position, self.quaternion, self.velocity, self.angular_velocity]
        )


@dataclass(frozen=True)
class SolverReport:
    """Iteration history of :func:`solve_on_manifold`.

    ``steps[l]`` is the correction ``(dp, dphi, ...)`` of iteration l (``dphi`` full angle, so
    the paper's ``2 |dr|`` of Table 1 is ``|dphi|``); ``gradients[l]`` is ``D^T h`` at the
    iterate before step l (the last row at the final iterate); ``costs[l] = |h|^2 / 2``.
    """

    method: str
    steps: np.ndarray
    gradients: np.ndarray
    costs: np.ndarray
    converged: bool

    @property
    def iterations(self) -> int:
        return int(self.steps.shape[0])


# -- prediction (eqs. 11-14, 18-23) ---------------------------------------------------------------


def transition_jacobian(angular_velocity, dt: float) -> np.ndarray:
    """``J_pred_state`` of eq. 22: error of the prediction w.r.t. the error of the state.

    ``[[I, 0, dt I, 0], [0, R(dt w), 0, G], [0, 0, I, 0], [0, 0, 0, I]]`` with ``R(dt w)`` the
    rotation by ``dt w`` (eq. 18) and ``G = int_0^dt R(s w) ds = dt J_l(dt w)`` (eqs. 20-21;
    ``J_l`` the left Jacobian of SO(3)). Errors as in :class:`QuaternionSpaceState`.

    Parameters
    ----------
    angular_velocity : array_like, shape (3,)
        [rad/s], world frame.
    dt : float
        Prediction interval [s].

    Returns
    -------
    ndarray, shape (12, 12)
    """
    phi = dt * np.asarray(angular_velocity, dtype=float)
    J = np.eye(12)
    J[0:3, 6:9] = dt * np.eye(3)
    J[3:6, 3:6] = quat_to_matrix(quat_exp(phi))
    J[3:6, 9:12] = dt * so3_right_jacobian(-phi)  # J_l(phi) = J_r(-phi)
    return J


def process_noise(dt: float, a: float, alpha: float) -> np.ndarray:
    """Process noise of eq. 23 for white accelerations of power spectral densities a and alpha.

    Parameters
    ----------
    dt : float
        [s].
    a : float
        Linear acceleration PSD [m^2/s^3].
    alpha : float
        Angular acceleration PSD [rad^2/s^3].

    Returns
    -------
    ndarray, shape (12, 12)
        Over ``(e_p, e_phi, e_v, e_w)``.
    """
    if dt < 0 or a < 0 or alpha < 0:
        raise InputError(f"process_noise needs dt, a, alpha >= 0, got {dt}, {a}, {alpha}")
    Q = np.zeros((12, 12))
    eye = np.eye(3)
    for k, s in ((0, a), (3, alpha)):
        Q[k : k + 3, k : k + 3] = s * dt**3 / 3.0 * eye
        Q[k : k + 3, k + 6 : k + 9] = Q[k + 6 : k + 9, k : k + 3] = s * dt**2 / 2.0 * eye
        Q[k + 6 : k + 9, k + 6 : k + 9] = s * dt * eye
    return Q


_HALF = np.diag([1.0] * 3 + [0.5] * 3 + [1.0] * 6)


def predict_state(
    state: QuaternionSpaceState, dt: float, a: float, alpha: float, orientation_error: str = "full"
) -> tuple[QuaternionSpaceState, np.ndarray]:
    """Constant-velocity prediction (eqs. 11-14) with covariance (eqs. 22-23).

    ``S_pred = J S J^T + Q(dt, a, alpha)``; errors as in :class:`QuaternionSpaceState`.

    Parameters
    ----------
    state : QuaternionSpaceState
    dt : float
        [s], ``>= 0``.
    a, alpha : float
        Process noise PSDs [m^2/s^3], [rad^2/s^3] (eq. 2).
    orientation_error : {"full", "paper"}
        "full" (default): the consistent model of this module. "paper": the printed equations
        read literally, i.e. J and Q of eqs. 22-23 applied to the half-angle error ``u_q``.

    Returns
    -------
    prediction : QuaternionSpaceState
        At ``state.time + dt``.
    J_pred_state : ndarray, shape (12, 12)
    """
    if not np.isfinite(dt) or dt < 0:
        raise InputError(f"prediction interval must be finite and >= 0, got {dt}")
    w = state.angular_velocity
    J = transition_jacobian(w, dt)
    Q = process_noise(dt, a, alpha)
    if orientation_error == "full":
        S = J @ state.covariance @ J.T + Q
    elif orientation_error == "paper":
        inv = np.linalg.inv(_HALF)
        S = inv @ (J @ (_HALF @ state.covariance @ _HALF) @ J.T + Q) @ inv
    else:
        raise InputError(f"orientation_error must be 'full' or 'paper', got {orientation_error!r}")
    q = quat_normalize(quat_multiply(quat_exp(dt * w), state.quaternion))
    pred = QuaternionSpaceState(
        state.time + dt, state.position + dt * state.velocity, q, state.velocity.copy(), w.copy(), S
    )
    return pred, J


# -- manifold least squares (eqs. 24-30) --------------------------------------------------------


def _retract(x: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """``x (+) delta`` for flat ``x = (p, q, rest)``: ``p + dp, Exp(dphi) * q, rest + d``."""
    out = x.copy()
    out[0:3] += delta[0:3]
    out[3:7] = quat_normalize(quat_multiply(quat_exp(delta[3:6]), x[3:7]))
    out[7:] += delta[6:]
    return out


def _equilibrated_pinv_normal(D: np.ndarray) -> np.ndarray:
    """``(D^T D)^-1`` via the SVD of the column-scaled ``D`` (robust to mixed units)."""
    scale = np.linalg.norm(D, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    _, s, Vt = np.linalg.svd(D / scale, full_matrices=False)
    if s[-1] <= s[0] * 1e-14:
        raise NumericalError("least-squares problem is singular: the state is not observable")
    Vs = Vt.T / s
    cov = (Vs @ Vs.T) / np.outer(scale, scale)
    return 0.5 * (cov + cov.T)


def _solve_step(D: np.ndarray, h: np.ndarray, damping: float) -> np.ndarray:
    """Gauss-Newton (damping 0, eq. 27) or Levenberg-Marquardt step, column-equilibrated."""
    scale = np.linalg.norm(D, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    Ds = D / scale
    if damping > 0:
        n = D.shape[1]
        Ds = np.vstack([Ds, np.sqrt(damping) * np.eye(n)])
        h = np.concatenate([h, np.zeros(n)])
    step, *_ = np.linalg.lstsq(Ds, -h, rcond=None)
    return step / scale


def solve_on_manifold(
    residual: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    x0: np.ndarray,
    method: str = "gauss_newton",
    gradient_tolerance: float = 1e-6,
    max_iterations: int = 20,
    initial_damping: float = 1e-3,
) -> tuple[np.ndarray, np.ndarray, SolverReport]:
    """Minimise ``|h(x)|^2 / 2`` over ``x = (p, q, rest)`` on ``R3 x S3 x R^k``.

    Each iteration linearises ``h(x (+) delta) ~ h + D delta`` at ``delta = 0`` (eq. 26), takes
    the Gauss-Newton step ``delta = -(D^T D)^-1 D^T h`` (eq. 27) and updates
    ``p + dp, Exp(dphi) * q, rest + d`` (eq. 28). It stops when ``|D^T h| < gradient_tolerance``
    (eq. 29). ``method="levenberg_marquardt"`` damps the step, ``(D^T D + mu diag) delta``, and
    only accepts steps that lower the cost, for starting points far from the minimum.

    Parameters
    ----------
    residual : callable
        ``x -> (h, D)``: whitened residuals (n,) and their Jacobian ``J_h_delta`` (n, 6 + k).
    x0 : ndarray, shape (7 + k,)
    method : {"gauss_newton", "levenberg_marquardt"}
    gradient_tolerance : float
        Threshold of eq. 29 on ``|D^T h|`` (units of the residual per unit of the state).
    max_iterations : int
    initial_damping : float
        Initial ``mu`` (relative to the equilibrated normal matrix) for Levenberg-Marquardt.

    Returns
    -------
    x : ndarray, shape (7 + k,)
    covariance : ndarray, shape (6 + k, 6 + k)
        ``(D^T D)^-1`` at ``x`` (eq. 30), over the error ``delta`` of ``x (+) delta``.
    report : SolverReport
    """
    if method not in ("gauss_newton", "levenberg_marquardt"):
        raise InputError(f"method must be 'gauss_newton' or 'levenberg_marquardt', got {method!r}")
    x = np.asarray(x0, dtype=float).copy()
    h, D = residual(x)
    grad = D.T @ h
    steps, grads, costs = [], [grad], [0.5 * h @ h]
    mu = initial_damping if method == "levenberg_marquardt" else 0.0
    converged = bool(np.linalg.norm(grad) < gradient_tolerance)
    it = 0
    while not converged and it < max_iterations:
        it += 1
        step = _solve_step(D, h, mu)
        x_new = _retract(x, step)
        h_new, D_new = residual(x_new)
        cost_new = 0.5 * h_new @ h_new
        if method == "levenberg_marquardt":
            tries = 0
            while cost_new > costs[-1] and tries < 30:
                mu = max(mu * 4.0, 1e-9)
                tries += 1
                step = _solve_step(D, h, mu)
                x_new = _retract(x, step)
                h_new, D_new = residual(x_new)
                cost_new = 0.5 * h_new @ h_new
            if cost_new > costs[-1]:
                break  # no descent possible: stationary to numerical precision
            mu /= 3.0
        x, h, D = x_new, h_new, D_new
        grad = D.T @ h
        steps.append(step)
        grads.append(grad)
        costs.append(cost_new)
        converged = bool(np.linalg.norm(grad) < gradient_tolerance)
    n = D.shape[1]
    report = SolverReport(
        method,
        np.array(steps).reshape(-1, n),
        np.array(grads),
        np.array(costs),
        converged,
    )
    return x, _equilibrated_pinv_normal(D), report


def _prior_whitening(S: np.ndarray) -> np.ndarray:
    """``W`` with ``W^T W = S^-1``, via the Cholesky factor of the correlation matrix."""
    d = np.sqrt(np.diag(S))
    if np.any(~(d > 0)):
        raise NumericalError("prediction covariance has a zero or negative variance")
    try:
        L = np.linalg.cholesky(S / np.outer(d, d))
    except np.linalg.LinAlgError:
        raise NumericalError("prediction covariance is not positive definite") from None
    return np.linalg.solve(L, np.eye(S.shape[0])) / d


def prior_residual(
    x: np.ndarray, prediction: QuaternionSpaceState
) -> tuple[np.ndarray, np.ndarray]:
    """Unwhitened prior residual of eq. 24 and its Jacobian w.r.t. the update ``delta``.

    ``r = (p - p_hat, Log(q * q_hat^-1), v - v_hat, w - w_hat)`` (``Log`` full angle, i.e.
    twice the paper's quaternion logarithm). With ``q = Exp(dphi) * q_l``,
    ``d Log / d dphi = J_l^-1(Log(q_l * q_hat^-1))``.

    Returns
    -------
    r : ndarray, shape (12,)
    J_r_delta : ndarray, shape (12, 12)
    """
    phi = quat_log(quat_multiply(x[3:7], quat_conjugate(prediction.quaternion)))
    r = np.concatenate(
        [
            x[0:3] - prediction.position,
            phi,
            x[7:10] - prediction.velocity,
            x[10:13] - prediction.angular_velocity,
        ]
    )
    J = np.eye(12)
    J[3:6, 3:6] = so3_right_jacobian_inverse(-phi)  # J_l^-1(phi)
    return r, J


def _stack_measurements(x, observations: Sequence[CameraObservation], n_state: int):
    hs, Ds = [], []
    for obs in observations:
        h, J = obs.whitened_residual(x[0:3], x[3:7])
        D = np.zeros((h.shape[0], n_state))
        D[:, :6] = J
        hs.append(h)
        Ds.append(D)
    return hs, Ds


def adjust_state(
    prediction: QuaternionSpaceState,
    observations: Sequence[CameraObservation],
    method: str = "gauss_newton",
    gradient_tolerance: float = 1e-6,
    max_iterations: int = 20,
    start: QuaternionSpaceState | None = None,
) -> tuple[QuaternionSpaceState, SolverReport]:
    """Adjust the prediction to the image features of M cameras (eqs. 24-30).

    Minimises ``sum_jk |W_jk (g_jk(p, q) - y_jk)|^2 / 2 + |W_hat r_prior|^2 / 2`` with
    ``W_hat^T W_hat = S_hat^-1`` by :func:`solve_on_manifold` started at the prediction (or at
    ``start``); the new covariance is ``(D^T D)^-1`` at the solution (eq. 30).

    Parameters
    ----------
    prediction : QuaternionSpaceState
        ``(p_hat, q_hat, v_hat, w_hat)`` and ``S_hat``.
    observations : sequence of CameraObservation
        Features measured at ``prediction.time`` (one entry per camera).
    method, gradient_tolerance, max_iterations
        See :func:`solve_on_manifold`.
    start : QuaternionSpaceState, optional
        Starting point of the iteration (default: the prediction).

    Returns
    -------
    state : QuaternionSpaceState
        Filtered state with covariance over ``(e_p, e_phi, e_v, e_w)``.
    report : SolverReport
    """
    W = _prior_whitening(prediction.covariance)

    def residual(x):
        hs, Ds = _stack_measurements(x, observations, 12)
        r, J = prior_residual(x, prediction)
        hs.append(W @ r)
        Ds.append(W @ J)
        return np.concatenate(hs), np.vstack(Ds)

    x0 = (start or prediction).as_vector()
    x, S, report = solve_on_manifold(residual, x0, method, gradient_tolerance, max_iterations)
    q = quat_align_sign(x[3:7], prediction.quaternion)
    return QuaternionSpaceState(prediction.time, x[0:3], q, x[7:10], x[10:13], S), report


def estimate_pose(
    observations: Sequence[CameraObservation],
    position,
    quaternion,
    method: str = "levenberg_marquardt",
    gradient_tolerance: float = 1e-6,
    max_iterations: int = 50,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, SolverReport]:
    """Pose ``T_w_b`` from the features of one time instant alone (no prior).

    Parameters
    ----------
    observations : sequence of CameraObservation
    position, quaternion : array_like
        Starting guess [m], (x, y, z, w).
    method, gradient_tolerance, max_iterations
        See :func:`solve_on_manifold` (Levenberg-Marquardt by default: the guess may be poor).

    Returns
    -------
    position : ndarray, shape (3,)
    quaternion : ndarray, shape (4,)
    covariance : ndarray, shape (6, 6)
        Over ``(e_p, e_phi)``: ``p_true = p + e_p``, ``q_true = Exp(e_phi) * q`` (world frame).
    report : SolverReport
    """

    def residual(x):
        hs, Ds = _stack_measurements(x, observations, 6)
        return np.concatenate(hs), np.vstack(Ds)

    q0 = check_quaternion(quaternion, normalize=True)
    x0 = np.concatenate([np.asarray(position, dtype=float), q0])
    x, S, report = solve_on_manifold(residual, x0, method, gradient_tolerance, max_iterations)
    return x[0:3], x[3:7], S, report


# -- the filter -------------------------------------------------------------------------------


@dataclass(frozen=True)
class QuaternionSpaceFilter:
    """Ude's quaternion-space tracker: predict (eqs. 11-23), adjust (eqs. 24-30).

    A stateless configuration: every method takes a state and returns new objects.

    Parameters
    ----------
    a : float
        Linear acceleration PSD [m^2/s^3] (eq. 2).
    alpha : float
        Angular acceleration PSD [rad^2/s^3] (eq. 2).
    method : {"gauss_newton", "levenberg_marquardt"}
    gradient_tolerance : float
        Eq. 29 threshold on ``|D^T h|``, SI units.
    max_iterations : int
    orientation_error : {"full", "paper"}
        See :func:`predict_state`.
    """

    a: float
    alpha: float
    method: str = "gauss_newton"
    gradient_tolerance: float = 1e-6
    max_iterations: int = 20
    orientation_error: str = "full"

    def __post_init__(self):
        if not (self.a >= 0 and self.alpha >= 0):
            raise InputError(f"a and alpha must be >= 0, got {self.a}, {self.alpha}")

    def initial_state(
        self, time: float, position, quaternion, pose_covariance, velocity_variance: float = 1e2,
        angular_velocity_variance: float = 1e8,
    ) -> QuaternionSpaceState:  # fmt: skip
        """State from a pose estimate with zero velocities of large variance (paper, section 5).

        ``pose_covariance`` (6x6) is over ``(e_p, e_phi)`` as returned by :func:`estimate_pose`.
        """
        S = np.zeros((12, 12))
        S[:6, :6] = pose_covariance
        S[6:9, 6:9] = velocity_variance * np.eye(3)
        S[9:12, 9:12] = angular_velocity_variance * np.eye(3)
        return QuaternionSpaceState(time, position, quaternion, np.zeros(3), np.zeros(3), S)

    def predict(self, state: QuaternionSpaceState, time: float) -> QuaternionSpaceState:
        """Prediction to ``time`` (>= ``state.time``)."""
        pred, _ = predict_state(
            state, time - state.time, self.a, self.alpha, self.orientation_error
        )
        return pred

    def update(
        self, prediction: QuaternionSpaceState, observations: Sequence[CameraObservation]
    ) -> tuple[QuaternionSpaceState, SolverReport]:
        """Adjustment of a prediction to the features measured at its time."""
        return adjust_state(
            prediction, observations, self.method, self.gradient_tolerance, self.max_iterations
        )

    def step(
        self, state: QuaternionSpaceState, time: float, observations: Sequence[CameraObservation]
    ) -> tuple[QuaternionSpaceState, QuaternionSpaceState, SolverReport]:
        """Predict to ``time`` and adjust: returns ``(prediction, filtered, report)``."""
        pred = self.predict(state, time)
        filt, report = self.update(pred, observations)
        return pred, filt, report

    def with_options(self, **changes) -> QuaternionSpaceFilter:
        """A copy with some parameters changed."""
        return replace(self, **changes)
