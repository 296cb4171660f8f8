"""The seed papers' filters behind the dataflow's pose-filter protocol.

The dataflow (:class:`trackflow.dataflow.KalmanFilter`) builds one filter per sensor with
``filter_factory(motion, history_s)`` and talks to it through the protocol of
:class:`trackflow.filters.PoseKalmanFilter`:

* ``update_pose(t, z) -> bool``: integrate a pose ``T_a_b`` measured at ``t`` [s]; ``False``
  for a counted rejection;
* ``predict(t) -> UncertainPose``: the pose at any time after the first measurement (future:
  prediction; past, within ``history``: from stored estimates), ``ValueError`` when it cannot;
* ``stats`` (dict of counters), ``initialized``, ``time`` (newest integrated measurement),
  ``reset()``.

Two adapters give the seed filters that protocol:

* :class:`RelativeMotionPoseFilter` wraps :class:`RelativeMotionEKF` (Dorfmueller-Ulhaas, seed
  000). That filter estimates only the motion ``(omega, v, a)``; its pose at a measurement time is
  the measured pose itself. ``predict(t)`` after the newest measurement is the paper's F4
  (:meth:`RelativeMotionEKF.predicted_pose`); in the past it interpolates the two stored measured
  poses around ``t`` (lerp / slerp, :meth:`UncertainPose.interpolate`; the measurements are
  independent, so the first-order covariance of the interpolation is exact for the
  interpolated quantity; the model error of a straight interpolation is not included).
* :class:`QuaternionSpacePoseFilter` wraps :class:`QuaternionSpaceFilter` (Ude, seed 003). A
  pose measurement enters the adjustment of eq. 24 *directly* as a term of the least-squares
  criterion, ``|W_z (p - z_p, Log(q z_q^-1))|^2`` with ``W_z^T W_z = C_z^-1`` (world-frame
  rotation error, the filter's own parameterisation), next to the prediction prior; Gauss-Newton
  on the manifold then minimises it as it would image features. This is exact for a pose
  sensor (no virtual cameras or marker model whose geometry would re-shape the noise).
  ``predict(t)`` after the newest measurement is the constant-velocity prediction (eqs. 11-23);
  in the past it interpolates the two stored filtered poses around ``t`` with a covariance that
  bounds every correlation between them (see :func:`_interpolate`).

Both adapters gate each pose measurement against the prediction at its time with the
chi-square test on the 6-dof NIS (as ``PoseKalmanFilter`` does, ``gate_probability``), re-start
after ``reset_after`` consecutive gated measurements, and count everything in ``stats``:
``updates``, ``rejected_gate``, ``rejected_old`` (time not after the newest measurement: the
seed filters are strictly sequential, so out-of-order measurements are refused, not inserted),
``rejected_invalid`` (non-finite time, pose or covariance, or a failed update), ``resets``; the
quaternion-space adapter also counts ``unconverged`` (accepted adjustments whose Gauss-Newton
iteration hit ``max_iterations`` before the stopping rule of eq. 29).

Conventions (``docs/conventions.md``): poses ``T_a_b`` with ``x_a = R x_b + t``; every covariance
given or returned is over ``(dt, dtheta)`` with ``t_true = t + dt`` (frame a) and
``R_true = R Exp(dtheta)`` (frame b, radians).

Process noise from a :class:`trackflow.graph.MotionSpec`: both seed filters are
constant-velocity models driven by white linear / angular acceleration of spectral densities
``q_a`` [m^2/s^3] and ``q_alpha`` [rad^2/s^3]. A scalar or ``(position, orientation)`` motion
noise ``(s_p, s_o)`` means ``q_a = s_p^2``, ``q_alpha = s_o^2`` (exactly what it means to
:class:`MotionModel` for ``n_dp = n_do = 1``); a full per-level tuple uses its velocity-level
entries. The factories take explicit ``q_a`` / ``q_alpha`` instead. A static motion has no
seed-filter counterpart: the factories then return the dataflow's default filter (a
``PoseKalmanFilter`` with a static model, the recursive least-squares estimator).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable

import numpy as np

from trackflow.math import (
    UncertainPose,
    quat_conjugate,
    quat_log,
    quat_multiply,
    quat_to_matrix,
    so3_right_jacobian_inverse,
)

from ._kalman import chi2_gate
from .manifold_gn import QuaternionSpaceFilter, QuaternionSpaceState
from .relative_motion import RelativeMotionEKF, RelativeMotionState, process_noise

__all__ = [
    "QuaternionSpacePoseFilter",
    "RelativeMotionPoseFilter",
    "constant_velocity_densities",
    "quaternion_space_factory",
    "relative_motion_factory",
]

# Added to the diagonal of a pose measurement's covariance before whitening it (m^2, rad^2):
# lets exact poses (zero covariance) in without changing any realistic covariance (>= 1e-10).
_VARIANCE_FLOOR = 1e-14


def constant_velocity_densities(motion) -> tuple[float, float]:
    """``(q_a, q_alpha)`` [m^2/s^3, rad^2/s^3] of a constant-velocity model from a MotionSpec.

    Scalar ``s`` -> ``(s^2, s^2)``; pair ``(s_p, s_o)`` -> ``(s_p^2, s_o^2)``; a full tuple of
    ``(n_dp + 1) + (n_do + 1)`` per-level values -> its velocity-level entries squared.
    """
    noise = motion.noise
    if isinstance(noise, (int, float)):
        noise = (float(noise), float(noise))
    noise = tuple(float(v) for v in noise)
    if len(noise) == 2:
        s_p, s_o = noise
    elif len(noise) == motion.n_dp + motion.n_do + 2 and motion.n_dp >= 1 and motion.n_do >= 1:
        s_p, s_o = noise[1], noise[motion.n_dp + 2]
    else:
        raise ValueError(
            f"motion noise {noise} cannot drive a constant-velocity seed filter: give a scalar, "
            "a (position, orientation) pair, or per-level values with n_dp, n_do >= 1"
        )
    if not (math.isfinite(s_p) and math.isfinite(s_o) and s_p >= 0 and s_o >= 0):
        raise ValueError(f"motion noise must be finite and >= 0, got {noise}")
    return s_p * s_p, s_o * s_o


def _valid(t: float, z: UncertainPose) -> bool:
    """Finite time, position, quaternion and covariance (the types are checked by the caller)."""
    return bool(
        math.isfinite(t)
        and np.all(np.isfinite(z.position))
        and np.all(np.isfinite(z.quaternion))
        and np.all(np.isfinite(z.covariance))
    )


def _check_pose(z) -> None:
    if not isinstance(z, UncertainPose) or z.shape != ():
        raise ValueError("update_pose needs a single UncertainPose")


def _interpolate(a: UncertainPose, b: UncertainPose, s: float, correlated: bool) -> UncertainPose:
    """Pose between two stored estimates, ``s`` in [0, 1] (lerp of position, slerp of rotation).

    ``J_s_a``, ``J_s_b`` are the interpolation Jacobians of :meth:`UncertainPose.interpolate`
    (errors ``(dt, dtheta)``, ``t_true = t + dt``, ``R_true = R Exp(dtheta)``).

    * ``correlated=False`` (independent end points, e.g. two measurements):
      ``C = J_s_a C_a J_s_a^T + J_s_b C_b J_s_b^T``.
    * ``correlated=True`` (successive filter estimates, whose cross-covariance is not kept):
      ``C = J_s_a C_a J_s_a^T / (1 - s) + J_s_b C_b J_s_b^T / s``, an upper bound (in the PSD
      order) of the covariance of ``J_s_a e_a + J_s_b e_b`` for *any* correlation of ``e_a`` and
      ``e_b``, since ``(x + y)(x + y)^T <= (1 + k) x x^T + (1 + 1/k) y y^T`` for ``k > 0``
      (here ``k = s / (1 - s)``). At the end points it is the stored covariance.
    """
    if s <= 0.0:
        return a
    if s >= 1.0:
        return b
    out, J_s_a, J_s_b = a.interpolate(b, s, jacobians=True)
    if not correlated:
        return out
    ca = J_s_a @ a.covariance @ J_s_a.T
    cb = J_s_b @ b.covariance @ J_s_b.T
    c = ca / (1.0 - s) + cb / s
    return UncertainPose(out.pose, 0.5 * (c + c.T))


class _History:
    """Time-ordered ``(t, UncertainPose)`` estimates covering at least ``span`` seconds."""

    def __init__(self, span: float):
        self.span = float(span)
        self.times: list[float] = []
        self.poses: list[UncertainPose] = []

    def add(self, t: float, pose: UncertainPose) -> None:
        if self.times and t == self.times[-1]:  # a second measurement at the same time
            self.poses[-1] = pose
        else:
            self.times.append(t)
            self.poses.append(pose)
        horizon = t - self.span
        n = 0  # keep one estimate at or before the horizon, so the whole window interpolates
        while n + 1 < len(self.times) and self.times[n + 1] <= horizon:
            n += 1
        if n:
            del self.times[:n]
            del self.poses[:n]

    def at(self, t: float, correlated: bool) -> UncertainPose:
        if not self.times or t < self.times[0]:
            oldest = f"{self.times[0]:.6f} s" if self.times else "none"
            raise ValueError(
                f"t={t:.6f} s is older than the stored history (oldest estimate: {oldest}; "
                f"history={self.span} s)"
            )
        i = bisect.bisect_right(self.times, t) - 1
        if i == len(self.times) - 1:
            return self.poses[i]
        t0, t1 = self.times[i], self.times[i + 1]
        return _interpolate(self.poses[i], self.poses[i + 1], (t - t0) / (t1 - t0), correlated)


class _GatedFilter:
    """Validation, ordering, gating, resets and counters shared by both adapters."""

    _extra_counters: tuple[str, ...] = ()

    def __init__(self, history: float, gate_probability: float | None, reset_after: int):
        if not (math.isfinite(history) and history >= 0):
            raise ValueError(f"history must be finite and >= 0 seconds, got {history}")
        if gate_probability is not None and not (0.0 < gate_probability <= 1.0):
            raise ValueError(f"gate_probability must be in (0, 1] or None, got {gate_probability}")
        if int(reset_after) < 1:
            raise ValueError(f"reset_after must be >= 1, got {reset_after}")
        self._history_s = float(history)
        self._gate = chi2_gate(gate_probability, 6)
        self._reset_after = int(reset_after)
        self.reset()

    def reset(self) -> None:
        """Forget everything: state, history and statistics."""
        self._t: float | None = None
        self._gated_run = 0
        self._hist = _History(self._history_s)
        self._counts = dict.fromkeys(
            ("updates", "rejected_gate", "rejected_old", "rejected_invalid", "resets")
            + self._extra_counters,
            0,
        )
        self._restart()

    @property
    def initialized(self) -> bool:
        """Whether at least one measurement has been integrated."""
        return self._t is not None

    @property
    def time(self) -> float | None:
        """Time [s] of the newest integrated measurement, ``None`` before the first."""
        return self._t

    @property
    def stats(self) -> dict:
        """Counters (module docstring): ``updates``, ``rejected_gate``, ``rejected_old``,
        ``rejected_invalid``, ``resets`` (and adapter-specific ones)."""
        return dict(self._counts)

    def update_pose(self, t: float, measurement: UncertainPose) -> bool:
        """Integrate the pose ``T_a_b`` measured at ``t`` [s].

        ``measurement.covariance`` (6x6) is over ``(dt, dtheta)``, ``t_true = t + dt``,
        ``R_true = R Exp(dtheta)``.

        Returns
        -------
        bool
            ``True`` if integrated; ``False`` for a counted rejection (gate, not after the
            newest measurement, non-finite input or a failed update).

        Raises
        ------
        ValueError
            If ``measurement`` is not a single ``UncertainPose``.
        """
        _check_pose(measurement)
        t = float(t)
        if not _valid(t, measurement):
            self._counts["rejected_invalid"] += 1
            return False
        if self._t is not None and not self._accepts_time(t):
            self._counts["rejected_old"] += 1
            return False
        try:
            if self._t is None or self._gated_run >= self._reset_after:
                if self._t is not None:
                    self._counts["resets"] += 1
                    self._hist = _History(self._history_s)
                    self._restart()
                estimate = self._first(t, measurement)
                self._gated_run = 0
            else:
                nis = self._nis(t, measurement)
                if not nis <= self._gate:  # NaN NIS fails too
                    self._gated_run += 1
                    self._counts["rejected_gate"] += 1
                    return False
                estimate = self._step(t, measurement)
                self._gated_run = 0
        except (ValueError, np.linalg.LinAlgError):
            self._counts["rejected_invalid"] += 1
            return False
        self._t = t
        self._hist.add(t, estimate)
        self._counts["updates"] += 1
        return True

    def predict(self, t: float) -> UncertainPose:
        """Pose ``T_a_b`` at ``t`` [s] with its 6x6 covariance over ``(dt, dtheta)``
        (``t_true = t + dt``, ``R_true = R Exp(dtheta)``).

        ``t`` at or after :attr:`time`: the seed filter's motion-model prediction. Earlier
        ``t`` (within ``history``): interpolated between the stored estimates around it (module
        docstring).

        Raises
        ------
        ValueError
            Before the first measurement, for a non-finite ``t`` or one older than the history.
        """
        if self._t is None:
            raise ValueError("the filter has no measurement yet; cannot predict")
        t = float(t)
        if not math.isfinite(t):
            raise ValueError(f"prediction time must be finite, got {t}")
        if t >= self._t:
            return self._forward(t)
        return self._hist.at(t, self._correlated)

    @staticmethod
    def _innovation_nis(r: np.ndarray, S: np.ndarray) -> float:
        S = 0.5 * (S + S.T)
        return float(r @ np.linalg.solve(S, r))


class RelativeMotionPoseFilter(_GatedFilter):
    """:class:`RelativeMotionEKF` with the dataflow's pose-filter protocol (module docstring).

    Parameters
    ----------
    q_a : float
        White linear-acceleration density [m^2/s^3]: the velocity random walk of
        :func:`relative_motion.process_noise` gets ``velocity_sigma = sqrt(q_a)``.
    q_alpha : float
        White angular-acceleration density [rad^2/s^3] (``omega_sigma = sqrt(q_alpha)``).
    history : float
        Seconds of measured poses kept for past queries.
    origin : {"body", "world"}
        Motion origin of the EKF (``"body"`` keeps ``v`` the body's velocity far from the world
        origin; the paper uses ``"world"``).
    gate_probability : float or None
        Chi-square gate on the 6-dof NIS of the measurement against the F4 prediction from the
        previous pose (``None`` disables).
    reset_after : int
        Consecutive gated measurements after which the next one re-starts the filter.
    velocity_prior_sigma, omega_prior_sigma : float
        Prior standard deviations of ``v`` [m/s] and ``omega`` [rad/s] (mean zero).

    Notes
    -----
    The acceleration state of eq. 9 is held at zero (prior variance 1e-12, no random walk):
    a constant-velocity model like the other filters of the dataflow. The EKF's per-frame
    process noise is rebuilt for each interval from its length (variance ``sigma^2 dt``).
    """

    def __init__(
        self,
        q_a: float,
        q_alpha: float,
        *,
        history: float = 1.0,
        origin: str = "body",
        gate_probability: float | None = 0.999,
        reset_after: int = 10,
        velocity_prior_sigma: float = 10.0,
        omega_prior_sigma: float = 10.0,
    ):
        if not (q_a >= 0 and q_alpha >= 0 and math.isfinite(q_a) and math.isfinite(q_alpha)):
            raise ValueError(f"q_a and q_alpha must be finite and >= 0, got {q_a}, {q_alpha}")
        if origin not in ("body", "world"):
            raise ValueError(f"origin must be 'body' or 'world', got {origin!r}")
        self._sigmas = (math.sqrt(q_alpha), math.sqrt(q_a))
        self._origin = origin
        var = [omega_prior_sigma**2] * 3 + [velocity_prior_sigma**2] * 3 + [1e-12] * 3
        self._prior = RelativeMotionState(np.zeros(9), np.diag(var))
        self.ekf: RelativeMotionEKF
        super().__init__(history, gate_probability, reset_after)

    _correlated = False  # past queries interpolate independent measurements

    def _restart(self) -> None:
        self.ekf = RelativeMotionEKF(self._prior, np.zeros((9, 9)), origin=self._origin)

    def _accepts_time(self, t: float) -> bool:
        return t > self._t  # the EKF needs a positive interval

    def _first(self, t: float, z: UncertainPose) -> UncertainPose:
        self.ekf.step(t, z)
        return z

    def _nis(self, t: float, z: UncertainPose) -> float:
        pred = self.ekf.predicted_pose(t - self._t)
        r = np.concatenate(
            [
                z.position - pred.position,
                quat_log(quat_multiply(quat_conjugate(pred.quaternion), z.quaternion)),
            ]
        )  # (dt, dtheta) of z relative to the prediction, trackflow convention
        return self._innovation_nis(r, pred.covariance + z.covariance)

    def _step(self, t: float, z: UncertainPose) -> UncertainPose:
        dt = t - self._t
        self.ekf.Q = process_noise(dt, self._sigmas[0], self._sigmas[1], 0.0)
        self.ekf.step(t, z)
        if not np.all(np.isfinite(self.ekf.state.covariance)):
            raise ValueError("non-finite EKF state")
        return z  # the EKF has no pose state: its pose at time t is the measurement

    def _forward(self, t: float) -> UncertainPose:
        return self.ekf.predicted_pose(t - self._t)


class _PoseTerm:
    """A pose measurement as a term of Ude's least-squares criterion (eq. 24).

    Offers the one method :func:`manifold_gn.adjust_state` asks of an observation,
    ``whitened_residual(p, q) -> (h, J_h_pose)``: ``h = W_z (p - z_p, Log(q z_q^-1))`` with
    ``W_z^T W_z = C_z^-1``, ``C_z`` the measurement covariance over the filter's error
    ``(e_p, e_phi)`` (``p_true = p + e_p``, ``q_true = Exp(e_phi) q``, world frame): from
    trackflow's ``(dt, dtheta)``, ``e_phi = R dtheta``, ``C_z = T C T^T``, ``T = diag(I, R)``.
    ``J_h_pose`` is over ``(dp, dphi)`` of ``p + dp``, ``Exp(dphi) q``:
    ``d Log(Exp(dphi) q z_q^-1) / d dphi = J_l^-1(Log(q z_q^-1))``.
    """

    size = 6

    def __init__(self, z: UncertainPose):
        self.position = z.position
        self.quaternion = z.quaternion
        self.covariance = self.world_covariance(z)
        L = np.linalg.cholesky(self.covariance + _VARIANCE_FLOOR * np.eye(6))
        self.whitening = np.linalg.solve(L, np.eye(6))

    @staticmethod
    def world_covariance(z: UncertainPose) -> np.ndarray:
        """``C_z = T C T^T`` with ``T = diag(I, R)`` (trackflow -> world-frame rotation error)."""
        T = np.eye(6)
        T[3:, 3:] = quat_to_matrix(z.quaternion)
        c = T @ z.covariance @ T.T
        return 0.5 * (c + c.T)

    def residual(self, position, quaternion) -> tuple[np.ndarray, np.ndarray]:
        """Unwhitened ``r = (p - z_p, Log(q z_q^-1))`` and ``J_r_pose`` (6, 6)."""
        phi = quat_log(quat_multiply(np.asarray(quaternion), quat_conjugate(self.quaternion)))
        r = np.concatenate([np.asarray(position) - self.position, phi])
        J = np.eye(6)
        J[3:, 3:] = so3_right_jacobian_inverse(-phi)  # J_l^-1(phi) = J_r^-1(-phi)
        return r, J

    def whitened_residual(self, position, quaternion) -> tuple[np.ndarray, np.ndarray]:
        r, J = self.residual(position, quaternion)
        return self.whitening @ r, self.whitening @ J


class QuaternionSpacePoseFilter(_GatedFilter):
    """:class:`QuaternionSpaceFilter` with the dataflow's pose-filter protocol.

    Each pose measurement is one term of the least-squares criterion of eq. 24, adjusted with
    the prediction prior by Gauss-Newton on the manifold (module docstring, :class:`_PoseTerm`).

    Parameters
    ----------
    q_a, q_alpha : float
        White linear / angular acceleration densities: Ude's ``a`` [m^2/s^3] and ``alpha``
        [rad^2/s^3] (eq. 23).
    history : float
        Seconds of filtered poses kept for past queries.
    gate_probability : float or None
        Chi-square gate on the 6-dof NIS of the measurement against the prediction.
    reset_after : int
        Consecutive gated measurements after which the next one re-initialises the filter.
    velocity_variance, angular_velocity_variance : float
        Initial variances of the zero velocities [(m/s)^2, (rad/s)^2] (the paper: 1e8; the
        default 1e2 matches the pose KF's prior of 10 m/s and 10 rad/s).
    method, gradient_tolerance, max_iterations
        Options of :class:`QuaternionSpaceFilter` (Gauss-Newton or Levenberg-Marquardt).

    Attributes
    ----------
    state : QuaternionSpaceState or None
        The filtered state at :attr:`time` (``(p, q, v, w)`` with 12x12 covariance).
    """

    _extra_counters = ("unconverged",)
    _correlated = True  # successive filtered states are correlated (cross-covariance not kept)

    def __init__(
        self,
        q_a: float,
        q_alpha: float,
        *,
        history: float = 1.0,
        gate_probability: float | None = 0.999,
        reset_after: int = 10,
        velocity_variance: float = 1e2,
        angular_velocity_variance: float = 1e2,
        method: str = "gauss_newton",
        gradient_tolerance: float = 1e-6,
        max_iterations: int = 20,
    ):
        self.filter = QuaternionSpaceFilter(
            a=q_a,
            alpha=q_alpha,
            method=method,
            gradient_tolerance=gradient_tolerance,
            max_iterations=max_iterations,
        )
        if not (velocity_variance > 0 and angular_velocity_variance > 0):
            raise ValueError("initial velocity variances must be > 0")
        self._init_var = (float(velocity_variance), float(angular_velocity_variance))
        self.state: QuaternionSpaceState | None = None
        super().__init__(history, gate_probability, reset_after)

    def _restart(self) -> None:
        self.state = None

    def _accepts_time(self, t: float) -> bool:
        return t >= self._t  # a second pose at the same time is fused (prediction over 0 s)

    def _first(self, t: float, z: UncertainPose) -> UncertainPose:
        self.state = self.filter.initial_state(
            t, z.position, z.quaternion, _PoseTerm.world_covariance(z), *self._init_var
        )
        return self.state.uncertain_pose()

    def _nis(self, t: float, z: UncertainPose) -> float:
        pred = self.filter.predict(self.state, t)
        term = _PoseTerm(z)
        r, _ = term.residual(pred.position, pred.quaternion)
        return self._innovation_nis(-r, pred.covariance[:6, :6] + term.covariance)

    def _step(self, t: float, z: UncertainPose) -> UncertainPose:
        pred = self.filter.predict(self.state, t)
        state, report = self.filter.update(pred, [_PoseTerm(z)])
        if not report.converged:
            self._counts["unconverged"] += 1
        self.state = state
        return state.uncertain_pose()

    def _forward(self, t: float) -> UncertainPose:
        return self.filter.predict(self.state, t).uncertain_pose()


def _static_filter(motion, history_s: float):
    from trackflow.dataflow import make_filter  # lazy: the dataflow imports the filters

    return make_filter(motion, history_s)


def relative_motion_factory(
    q_a: float | None = None, q_alpha: float | None = None, **options
) -> Callable:
    """A ``filter_factory(motion, history_s)`` building :class:`RelativeMotionPoseFilter`.

    ``q_a`` / ``q_alpha`` default to :func:`constant_velocity_densities` of each relationship's
    MotionSpec; ``options`` go to the constructor. Static motions get the default dataflow
    filter. Build one factory and pass the same object to every plan, so that networks can
    share a sensor's filter (they compare factories by identity).
    """

    def factory(motion, history_s: float):
        if motion.static:
            return _static_filter(motion, history_s)
        qa, qal = constant_velocity_densities(motion)
        return RelativeMotionPoseFilter(
            qa if q_a is None else q_a,
            qal if q_alpha is None else q_alpha,
            history=history_s,
            **options,
        )

    return factory


def quaternion_space_factory(
    q_a: float | None = None, q_alpha: float | None = None, **options
) -> Callable:
    """A ``filter_factory(motion, history_s)`` building :class:`QuaternionSpacePoseFilter`
    (same rules as :func:`relative_motion_factory`)."""

    def factory(motion, history_s: float):
        if motion.static:
            return _static_filter(motion, history_s)
        qa, qal = constant_velocity_densities(motion)
        return QuaternionSpacePoseFilter(
            qa if q_a is None else q_a,
            qal if q_alpha is None else q_alpha,
            history=history_s,
            **options,
        )

    return factory
