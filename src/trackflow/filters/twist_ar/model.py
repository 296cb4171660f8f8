"""A Kalman filter whose motion model is a vector autoregression of body-frame pose increments.

The derivative models of :class:`~trackflow.filters.MotionModel` extrapolate a Taylor
polynomial: position, velocity, acceleration... each carried on unchanged. Hand-held motion
that was smoothed offline (mocap fused with an IMU) is predicted better by a model *learned*
from the recording: how the next increment of the pose, seen from the moving body, follows from
the last few. That is a linear-Gaussian model, so a Kalman filter runs on it exactly as on the
thesis's motion models (Pustka 6.2: a process model, its noise, a pose measurement).

Model (step ``dt``; ``xi_k = (u_k, w_k)`` is the increment from sample ``k-1`` to ``k`` in the
body frame of ``k-1``: ``u_k = R_{k-1}^T (t_k - t_{k-1})`` [m], ``w_k = Log(q_{k-1}^* q_k)``
[rad])::

    xi_{k+1} = sum_{j=0}^{L-1} A_j xi_{k-j} + n_k,        n_k ~ N(0, Q)
    t_{k+1}  = t_k + R_k u_{k+1}
    R_{k+1}  = R_k Exp(w_{k+1})

State of the filter: the pose and the last ``L`` increments. Error state, conventions of
``docs/conventions.md``: ``t_true = t + dt`` (frame a), ``R_true = R Exp(dtheta)`` (body),
``xi_true = xi + dxi``; ``e = (dt, dtheta, dxi_k, ..., dxi_{k-L+1})``, length ``6 + 6 L``.
One step's error Jacobian (``u``, ``w``: the new increment's mean)::

    dt'     = dt - R [u]x dtheta + R du'
    dtheta' = Exp(-w) dtheta + J_r(w) dw'
    dxi'    = sum_j A_j dxi_{k-j} + n,    dxi'_{k-j+1} = dxi_{k-j}  (the history shifts)

Measurements are poses with isotropic noise; a measurement interval of ``m`` model steps
(rounded) is ``m`` predictions, and longer intervals than ``max_gap`` restart the filter.
The model is fitted by (Huber-weighted) least squares to the increments of a recording:
:meth:`TwistARModel.fit`. ``docs/filters.md`` (autoregressive motion model) has the details.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from trackflow.math import (
    check_trajectory,
    frozen,
    kernels_for,
    quat_conjugate,
    quat_exp,
    quat_multiply,
    quat_rminus,
    quat_rotate,
)

from ...errors import InputError
from ..gating import GatePolicy
from . import kernels as _source

__all__ = [
    "TwistARModel",
    "TwistARResult",
    "body_increments",
    "excitation_ratios",
    "run_twist_ar",
]

#: sample intervals within this fraction of the model step count as one step when fitting
_STEP_TOLERANCE = 0.25


def body_increments(position: np.ndarray, quaternion: np.ndarray) -> np.ndarray:
    """Body-frame increments between consecutive poses.

    Parameters
    ----------
    position : ndarray, shape (N, 3)
        ``t_a_b`` [m].
    quaternion : ndarray, shape (N, 4)
        ``q_a_b`` ``(x, y, z, w)``.

    Returns
    -------
    ndarray, shape (N, 6)
        Row ``k >= 1``: ``(R_{k-1}^T (t_k - t_{k-1}), Log(q_{k-1}^* q_k))`` [m, rad]; row 0
        is zero.
    """
    p = np.asarray(position, dtype=float)
    q = np.asarray(quaternion, dtype=float)
    xi = np.zeros((p.shape[0], 6))
    if p.shape[0] > 1:
        qc = quat_conjugate(q[:-1])
        xi[1:, :3] = quat_rotate(qc, p[1:] - p[:-1])
        xi[1:, 3:] = quat_rminus(q[1:], q[:-1])
    return xi


def _recording(t, position, quaternion):
    """The checked arrays ``(t (N,), p (N, 3), q (N, 4))``; ``ValueError`` naming the problem."""
    return check_trajectory(t, position, quaternion)


def _regular(t, step):
    """Shape (N,) bool: the increment into sample ``k`` spans one model step (within 25 %)."""
    out = np.zeros(t.shape[0], dtype=bool)
    out[1:] = np.abs(np.diff(t) / step - 1.0) < _STEP_TOLERANCE
    return out


def excitation_ratios(t, position, quaternion) -> tuple[float, float]:
    """How evenly a recording moves along the body axes: a persistent-excitation check.

    For the translation and the rotation parts of the body-frame increments (regular sample
    intervals only), the square root of the smallest over the largest eigenvalue of their
    covariance: 1 = the same spread along every axis, near 0 = (almost) no motion along some
    axis. A full coupling model (:meth:`TwistARModel.fit` with ``structure="full"``) says
    little about axes the data hardly moved along.

    Parameters
    ----------
    t : array_like, shape (N,)
        Strictly increasing times [s].
    position, quaternion : array_like, shapes (N, 3), (N, 4)

    Returns
    -------
    translation, rotation : float
        In [0, 1]; 0 when fewer than 7 regular increments exist.
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    if t.shape[0] < 8:
        return 0.0, 0.0
    xi = body_increments(position, quaternion)[_regular(t, np.median(np.diff(t)))]
    if xi.shape[0] < 7:
        return 0.0, 0.0
    out = []
    for block in (xi[:, :3], xi[:, 3:]):
        ev = np.linalg.eigvalsh(np.cov(block.T))
        out.append(float(np.sqrt(max(ev[0], 0.0) / ev[-1])) if ev[-1] > 0 else 0.0)
    return out[0], out[1]


def _apply(position, quaternion, xi, fraction=1.0):
    """``(t + R f u, q Exp(f w))``, batched over leading axes."""
    p = position + quat_rotate(quaternion, fraction * xi[..., :3])
    q = quat_multiply(quaternion, quat_exp(fraction * xi[..., 3:]))
    return p, q


def _spiky(xi, regular, k_sigma=10.0):
    """Increments next to a jump (see :meth:`TwistARModel.fit`), shape (N,) bool."""
    both = regular[1:] & regular[:-1]
    d2 = np.zeros_like(xi)
    d2[1:] = np.where(both[:, None], xi[1:] - xi[:-1], 0.0)
    if np.count_nonzero(both) < 10:
        return np.zeros(xi.shape[0], dtype=bool)
    scale = 1.4826 * np.median(np.abs(d2[1:][both]), axis=0) + 1e-300
    jump = np.any(np.abs(d2) > k_sigma * scale, axis=1)  # xi_k differs from xi_{k-1}
    out = jump.copy()
    out[:-1] |= jump[1:]  # ... or from xi_{k+1}
    return out


def _ridge_solve(x, y, w, ridge):
    """Weighted ridge least squares ``min sum_i w_i |y_i - x_i c|^2 + ridge' |c|^2``."""
    sw = np.sqrt(w)[:, None]
    xw = x * sw
    g = xw.T @ xw
    g[np.diag_indices_from(g)] += ridge * np.trace(g) / g.shape[0] + 1e-300
    return np.linalg.solve(g, xw.T @ (y * sw))


def _weighted_solve(x, y, w, order, structure, ridge):
    """Coefficients (6 L, 6) of ``y ~ x coef`` for the given structure (see ``fit``)."""
    if structure == "full":
        return _ridge_solve(x, y, w, ridge)
    coef = np.zeros((6 * order, 6))
    for block in (0, 3):  # translation, rotation: one scalar per tap, shared by the axes
        xs = np.concatenate([x[:, block + i :: 6] for i in range(3)], axis=0)  # (3n, L)
        ys = np.concatenate([y[:, block + i] for i in range(3)])[:, None]
        c = _ridge_solve(xs, ys, np.tile(w, 3), ridge)[:, 0]
        for i in range(3):
            coef[block + i :: 6, block + i] = c
    return coef


@dataclass(frozen=True)
class TwistARModel:
    """Vector autoregression of body-frame pose increments (see the module docstring).

    Attributes
    ----------
    dt : float
        Model step [s] (the recording's sample interval).
    coefficients : ndarray, shape (L, 6, 6)
        ``A_j``: ``xi_{k+1} = sum_j A_j xi_{k-j} + n``; increments ``(u [m], w [rad])`` per step.
    noise : ndarray, shape (6, 6)
        ``Q``, covariance of ``n`` (per step) [m, rad].
    twist_covariance : ndarray, shape (6, 6), optional
        Spread of the increments themselves, the filter's prior on each history entry after a
        (re)start; default ``100 Q``.
    """

    dt: float
    coefficients: np.ndarray = field(repr=False)
    noise: np.ndarray = field(repr=False)
    twist_covariance: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self):
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise InputError(f"dt must be a positive number of seconds, got {self.dt!r}")
        a = np.array(self.coefficients, dtype=float)
        if a.ndim != 3 or a.shape[1:] != (6, 6) or a.shape[0] < 1:
            raise InputError(f"coefficients must have shape (L, 6, 6), L >= 1; got {a.shape}")
        q = np.array(self.noise, dtype=float)
        if q.shape != (6, 6):
            raise InputError(f"noise must have shape (6, 6), got {q.shape}")
        c = 100.0 * q if self.twist_covariance is None else np.array(self.twist_covariance)
        if c.shape != (6, 6):
            raise InputError(f"twist_covariance must have shape (6, 6), got {c.shape}")
        for name, m in (("coefficients", a), ("noise", q), ("twist_covariance", c)):
            if not np.all(np.isfinite(m)):
                raise InputError(f"{name} must be finite")
        for name, m in (("noise", q), ("twist_covariance", c)):
            if not np.allclose(m, m.T, rtol=1e-9, atol=1e-300):
                raise InputError(f"{name} must be symmetric")
            if np.min(np.linalg.eigvalsh(m)) < -1e-12 * max(np.max(np.abs(m)), 1e-300):
                raise InputError(f"{name} must be positive semi-definite")
        for name, m in (("coefficients", a), ("noise", q), ("twist_covariance", c)):
            m.setflags(write=False)
            object.__setattr__(self, name, m)

    @property
    def order(self) -> int:
        """``L``, the number of past increments the next one depends on."""
        return int(self.coefficients.shape[0])

    @property
    def state_dim(self) -> int:
        """Length of the error state, ``6 + 6 L``."""
        return 6 + 6 * self.order

    def spectral_radius(self) -> float:
        """Largest eigenvalue modulus of the companion matrix (< 1: the increments decay)."""
        n = 6 * self.order
        comp = np.zeros((n, n))
        comp[:6] = np.concatenate(list(self.coefficients), axis=1)
        comp[6:, :-6] = np.eye(n - 6)
        return float(np.max(np.abs(np.linalg.eigvals(comp))))

    def as_dict(self) -> dict:
        """Summary for reports (the coefficients themselves are not included)."""
        return {
            "kind": "twist_ar",
            "order": self.order,
            "dt": self.dt,
            "noise_sigma": np.sqrt(np.diag(self.noise)).tolist(),
            "spectral_radius": self.spectral_radius(),
        }

    # -- fitting ----------------------------------------------------------------------------
    @classmethod
    def fit(
        cls,
        t,
        position,
        quaternion,
        order: int,
        dt: float | None = None,
        structure: str = "full",
        use=None,
        robust: bool = True,
        ridge: float = 1e-6,
    ) -> TwistARModel:
        """Least-squares fit to the increments of a recording.

        Only windows of ``order + 1`` consecutive increments whose sample intervals are all
        within 25 % of ``dt`` are used (gaps and dropped frames are skipped). With ``robust``
        the rows are re-weighted three times with Huber weights (threshold 3 x the median
        normalised residual), and increments next to a jump are left out first: a tracking
        spike in one sample puts a large increment into and out of it, which would otherwise
        sit in the regressors, where residual weights cannot see it. A jump is a change of
        increment (``xi_k - xi_{k-1}``) beyond 10 robust standard deviations (1.4826 x median
        absolute value, per component). The fit is a
        correction to constant increments (``A_0 = I + B_0``, ``A_j = B_j``), so the ridge
        shrinks directions the data hardly excites toward constant velocity.

        ``structure`` says which couplings are learned: ``"full"``, every ``A_j`` a full 6x6
        matrix (36 L numbers: translation and rotation, all axes coupled, in the body frame);
        ``"isotropic"``, ``A_j = diag(a_j I_3, b_j I_3)`` (2 L numbers: the same dynamics on
        every axis), which transfers to motion along axes the fitted data hardly used.

        Parameters
        ----------
        t : array_like, shape (N,)
            Strictly increasing times [s].
        position, quaternion : array_like, shapes (N, 3), (N, 4)
            ``T_a_b`` [m], ``(x, y, z, w)``, sign-continuous.
        order : int
            ``L >= 1``.
        dt : float, optional
            Model step [s]; default the median sample interval.
        structure : {"full", "isotropic"}
        use : array_like of bool, shape (N,), optional
            Only windows whose samples all have ``use`` true are fitted (cross-validation).
        robust : bool
        ridge : float
            Tikhonov weight relative to the mean diagonal of the normal matrix (keeps the
            solve well-posed when the motion does not excite every direction).

        Returns
        -------
        TwistARModel
        """
        order = int(order)
        if order < 1:
            raise InputError(f"order must be >= 1, got {order}")
        t, p, q = _recording(t, position, quaternion)
        step = float(np.median(np.diff(t))) if dt is None and t.shape[0] > 1 else dt
        if step is None or not (np.isfinite(step) and step > 0):
            raise InputError(f"dt must be a positive number of seconds, got {step!r}")
        if structure not in ("full", "isotropic"):
            raise InputError(f"structure must be 'full' or 'isotropic', got {structure!r}")
        xi = body_increments(p, q)
        regular = _regular(t, step)
        if use is not None:
            use = np.asarray(use, dtype=bool).reshape(-1)
            if use.shape != t.shape:
                raise InputError(f"use must have shape {t.shape}, got {use.shape}")
            regular[1:] &= use[1:] & use[:-1]
        if robust:
            regular &= ~_spiky(xi, regular)
        # row k predicts xi[k+1] from xi[k], ..., xi[k-L+1]: all L+1 increments regular
        run = np.convolve(regular.astype(float), np.ones(order + 1), mode="valid")
        rows = np.flatnonzero(run > order + 0.5) + order - 1  # window xi[k-L+1 .. k+1]
        rows = rows[rows + 1 < t.shape[0]]
        # at least ten windows per coefficient of one output (6 L full; isotropic: L, each
        # window giving three equations, so the floor of 24 L is the binding one)
        need = 60 * order if structure == "full" else 24 * order
        if rows.size < need:
            raise InputError(
                f"too few regular samples to fit an order-{order} {structure} model: "
                f"{rows.size} windows, need at least {need}"
            )
        x = np.concatenate([xi[rows - j] for j in range(order)], axis=1)  # (n, 6L)
        # fitted as a correction to constant increments (A_0 = I + B_0, A_j = B_j): the ridge
        # shrinks directions the data hardly excites toward constant velocity, not toward zero
        y = xi[rows + 1] - xi[rows]
        scale = np.std(y, axis=0) + 1e-15
        w = np.ones(rows.size)
        for _ in range(3 if robust else 1):
            coef = _weighted_solve(x, y, w, order, structure, ridge)  # (6L, 6)
            res = (y - x @ coef) / scale
            r = np.linalg.norm(res, axis=1)
            c = 3.0 * float(np.median(r)) + 1e-300
            w = np.where(r <= c, 1.0, c / np.maximum(r, 1e-300))
        resid = y - x @ coef
        coef[:6] += np.eye(6)
        noise = (resid * w[:, None]).T @ resid / np.sum(w)
        noise = 0.5 * (noise + noise.T)
        a = coef.T.reshape(6, order, 6).transpose(1, 0, 2)  # A_j = coef[6j:6j+6].T
        twist_cov = np.cov(xi[regular].T) if np.count_nonzero(regular) > 6 else 100.0 * noise
        return cls(step, a, noise, 0.5 * (twist_cov + twist_cov.T))

    # -- mean propagation ---------------------------------------------------------------------
    def next_increment(self, history: np.ndarray) -> np.ndarray:
        """``sum_j A_j xi_{k-j}``, history shape (..., L, 6) newest first -> (..., 6)."""
        return np.einsum("jab,...jb->...a", self.coefficients, history)

    def step(self, position, quaternion, history):
        """One model step of the mean: ``(t, q, history) -> (t', q', history')`` (batched)."""
        xi = self.next_increment(history)
        p, q = _apply(position, quaternion, xi)
        h = np.concatenate([xi[..., None, :], history[..., :-1, :]], axis=-2)
        return p, q, h

    def predict(self, position, quaternion, history, horizon: float):
        """Mean pose ``horizon`` seconds ahead (batched).

        ``horizon / dt`` model steps; a fractional last step applies that fraction of the
        next increment (constant body twist within the step).

        Parameters
        ----------
        position : ndarray, shape (..., 3)
        quaternion : ndarray, shape (..., 4)
        history : ndarray, shape (..., L, 6)
            Increments, newest first.
        horizon : float
            [s], >= 0.

        Returns
        -------
        position, quaternion : ndarray, shapes (..., 3), (..., 4)
        """
        return self.predict_many(position, quaternion, history, (horizon,))[float(horizon)]

    def predict_many(self, position, quaternion, history, horizons) -> dict:
        """:meth:`predict` for several horizons in one pass of steps.

        Returns
        -------
        dict float -> (position (..., 3), quaternion (..., 4))
        """
        hz = sorted({float(v) for v in horizons})
        for v in hz:
            if not (np.isfinite(v) and v >= 0):
                raise InputError(f"horizon must be >= 0 seconds, got {v!r}")
        p, q, h = np.array(position, dtype=float), np.array(quaternion, dtype=float), history
        done, out = 0, {}
        for v in hz:
            m = v / self.dt
            n = int(np.floor(m + 1e-9))
            frac = m - n if m - n > 1e-9 else 0.0
            for _ in range(n - done):
                p, q, h = self.step(p, q, h)
            done = n
            out[v] = _apply(p, q, self.next_increment(h), frac) if frac > 0.0 else (p, q)
        return out

    def jacobians_step(self, quaternion, history):
        """Error-state Jacobians of one step (see the module docstring), unbatched.

        Parameters
        ----------
        quaternion : ndarray, shape (4,)
        history : ndarray, shape (L, 6)

        Returns
        -------
        J_next_state : ndarray, shape (6 + 6L, 6 + 6L)
            ``e' = J_next_state e`` (without noise).
        J_next_noise : ndarray, shape (6 + 6L, 6)
            How the increment noise ``n`` enters ``e'``.
        """
        q = np.ascontiguousarray(quaternion, dtype=float)
        h = np.ascontiguousarray(history, dtype=float).reshape(-1)
        _, top, jn = kernels_for(_source).twist_ar_top(q, h, self._a_cat())
        n = self.state_dim
        j = np.zeros((n, n))
        j[:12] = top
        j[12:, 6 : n - 6] = np.eye(n - 12)
        j_noise = np.zeros((n, 6))
        j_noise[:12] = jn
        return j, j_noise

    def _a_cat(self) -> np.ndarray:
        """``[A_0 ... A_{L-1}]``, shape (6, 6 L)."""
        return np.ascontiguousarray(np.concatenate(list(self.coefficients), axis=1))


@dataclass(frozen=True)
class TwistARResult:
    """Output of :func:`run_twist_ar`, row ``i`` belonging to input row ``i``.

    Attributes
    ----------
    position, quaternion : ndarray, shapes (N, 3), (N, 4)
        Filtered pose after measurement ``i``.
    history : ndarray, shape (N, L, 6)
        Filtered increments after measurement ``i``, newest first.
    covariance : ndarray, shape (N, 6, 6)
        Covariance of the filtered pose error ``(dt, dtheta)`` (``docs/conventions.md``).
    predictions : dict float -> (ndarray (N, 3), ndarray (N, 4))
        Mean pose predicted for ``t[i] + h`` from the state after measurement ``i``.
    nis : ndarray, shape (N,)
        Normalised innovation squared (NaN where the filter (re)started).
    restarts : int
        Times the filter started afresh (first sample, after gaps).
    status : ndarray of int8, shape (N,)
        :class:`~trackflow.filters.FilterStatus` of each measurement (initialised, accepted,
        gated or reset).
    """

    position: np.ndarray
    quaternion: np.ndarray
    history: np.ndarray = field(repr=False)
    covariance: np.ndarray = field(repr=False)
    predictions: dict = field(repr=False)
    nis: np.ndarray = field(repr=False)
    restarts: int = 0
    status: np.ndarray | None = field(default=None, repr=False)


def run_twist_ar(
    t,
    position,
    quaternion,
    model: TwistARModel,
    pos_sigma: float,
    ori_sigma: float,
    horizons: Sequence[float] = (),
    max_gap: float | None = None,
    gate: GatePolicy | None = None,
) -> TwistARResult:
    """Run the autoregressive-twist Kalman filter over a recording.

    Each measurement ``m`` model steps after the previous one (``m = round(interval / dt)``,
    at least 1) is preceded by ``m`` predictions; an interval longer than ``max_gap`` restarts
    the filter: pose from the measurement (covariance of the measurement), every history
    entry zero with covariance ``model.twist_covariance``. The update is the Joseph form (it
    stays symmetric positive semi-definite when the gain is not exactly optimal).

    Parameters
    ----------
    t : array_like, shape (N,)
        Strictly increasing times [s].
    position, quaternion : array_like, shapes (N, 3), (N, 4)
        Measured ``T_a_b`` [m], ``(x, y, z, w)``.
    model : TwistARModel
    pos_sigma, ori_sigma : float
        Measurement noise per position axis [m] and per rotation axis (``dtheta``) [rad].
    horizons : sequence of float
        Prediction horizons [s] (means only).
    max_gap : float, optional
        [s]; default none: the filter starts once, at the first sample.
    gate : GatePolicy, optional
        Innovation gate and reset policy shared by every filter family; default none: every
        measurement is integrated.

    Returns
    -------
    TwistARResult
    """
    t, pm, qm = _recording(t, position, quaternion)
    n_s = t.shape[0]
    for name, v in (("pos_sigma", pos_sigma), ("ori_sigma", ori_sigma)):
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"{name} must be finite and > 0, got {v!r}")
    hz = np.asarray(horizons, dtype=float).reshape(-1)
    if np.any(~np.isfinite(hz)) or np.any(hz < 0):
        raise InputError(f"horizons must be >= 0 seconds, got {hz.tolist()}")
    gap = np.inf if max_gap is None else float(max_gap)

    policy = gate if gate is not None else GatePolicy(gate_probability=None)
    r_diag = np.array([pos_sigma**2] * 3 + [ori_sigma**2] * 3)
    status = np.zeros(n_s, dtype=np.int8)
    out_p, out_q, out_h, out_c, nis, restarts = kernels_for(_source).twist_ar_run(
        frozen(t), frozen(pm), frozen(qm), frozen(model._a_cat()), frozen(model.noise),
        frozen(model.twist_covariance), frozen(r_diag), float(model.dt), gap,
        policy.threshold(6), policy.reset_after, status,
    )  # fmt: skip
    out_h = out_h.reshape(n_s, model.order, 6)
    preds = model.predict_many(out_p, out_q, out_h, hz) if hz.size else {}
    return TwistARResult(out_p, out_q, out_h, out_c, preds, nis, int(restarts), status)
