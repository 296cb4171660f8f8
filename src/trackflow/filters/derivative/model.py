"""Motion models: how many derivatives a pose filter estimates and how fast they wander."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from trackflow.math import kernels_for

from ...errors import InputError
from . import kernels as _source
from . import update_kernels as _update

__all__ = ["MotionModel", "FORMULATIONS"]

FORMULATIONS = ("error_state", "additive")
_KINDS = {"white_noise": 0, "thesis": 1}


def _additive(formulation: str) -> int:
    if formulation not in FORMULATIONS:
        raise InputError(f"unknown formulation {formulation!r}; use one of {FORMULATIONS}")
    return int(formulation == "additive")


class MotionModel:
    """Motion model of one spatial relationship (thesis section 6.3.1).

    Parameters
    ----------
    n_dp, n_do : int
        Number of position / orientation derivatives in the state: ``-1`` = that part is not
        estimated, ``0`` = pose only (static or slowly drifting), ``1`` = velocity,
        ``2`` = acceleration, any order. Position derivatives are in frame ``a`` (m/s^k), the
        angular ones in the body frame ``b`` (rad/s^k, ``q_new = q Exp(w dt)``).
    noise : sequence of float, optional
        One process-noise value per derivative level: position levels ``0..n_dp`` followed by
        orientation levels ``0..n_do`` (length ``(n_dp + 1) + (n_do + 1)``, parts with ``-1``
        omitted). The default is 1 on the highest level of each part and 0 elsewhere.
    kind : {"white_noise", "thesis"}
        ``"white_noise"`` (default, physically derived): level ``l`` is driven by continuous
        white noise of spectral density ``noise[l]^2``; integrating it exactly over ``dt``
        gives ``Q_ij = sum_l s_l^2 dt^(2l-i-j+1) / ((l-i)! (l-j)! (2l-i-j+1))``, e.g. Ude's
        eq. 23 for a white acceleration (``a dt^3/3, a dt^2/2, a dt``). Units: level ``l`` in
        (unit/s^l)/sqrt(s). ``"thesis"``: the diagonal ``Q = diag((q_l dt)^2)`` of the thesis's
        eq. 6.21, units (unit/s^l)/s. Each value applies to all three axes; the rotation level
        is in radians (the thesis's quaternion-component noise is half of it).

    Examples
    --------
    >>> m = MotionModel(n_dp=2, n_do=1, noise=(0, 0, 1.0, 0, 2.0))
    >>> m.state_size, m.error_size
    (16, 15)
    """

    __slots__ = ("_n_dp", "_n_do", "_noise", "_kind", "_sig_p", "_sig_o")

    def __init__(
        self,
        n_dp: int = 2,
        n_do: int = 1,
        noise: Sequence[float] | None = None,
        kind: str = "white_noise",
    ):
        for name, v in (("n_dp", n_dp), ("n_do", n_do)):
            if not isinstance(v, (int, np.integer)) or v < -1:
                raise InputError(f"{name} must be an integer >= -1, got {v!r}")
        if n_dp < 0 and n_do < 0:
            raise InputError("a motion model needs position or orientation (n_dp, n_do both -1)")
        if kind not in _KINDS:
            raise InputError(f"unknown process-noise kind {kind!r}; use one of {tuple(_KINDS)}")
        npl, nol = n_dp + 1, n_do + 1
        if noise is None:
            sig_p = np.zeros(npl)
            sig_o = np.zeros(nol)
            if npl:
                sig_p[-1] = 1.0
            if nol:
                sig_o[-1] = 1.0
        else:
            v = np.asarray(noise, dtype=float).reshape(-1)
            if v.size != npl + nol:
                raise InputError(
                    f"noise needs {npl + nol} values ({npl} position levels, {nol} orientation "
                    f"levels) for n_dp={n_dp}, n_do={n_do}; got {v.size}"
                )
            if not np.all(np.isfinite(v)) or np.any(v < 0):
                raise InputError(f"noise values must be finite and >= 0, got {v.tolist()}")
            sig_p, sig_o = v[:npl].copy(), v[npl:].copy()
        self._n_dp = int(n_dp)
        self._n_do = int(n_do)
        self._kind = kind
        self._sig_p = np.ascontiguousarray(sig_p if npl else np.zeros(1))
        self._sig_o = np.ascontiguousarray(sig_o if nol else np.zeros(1))
        self._noise = tuple(float(s) for s in np.concatenate([sig_p, sig_o]))

    @classmethod
    def static(cls) -> MotionModel:
        """Pose only, zero process noise: the filter is a recursive least-squares estimator."""
        return cls(0, 0, noise=(0.0, 0.0), kind="white_noise")

    # -- attributes ---------------------------------------------------------------------------
    @property
    def n_dp(self) -> int:
        """Number of position derivatives (-1 = position not estimated)."""
        return self._n_dp

    @property
    def n_do(self) -> int:
        """Number of orientation derivatives (-1 = orientation not estimated)."""
        return self._n_do

    @property
    def noise(self) -> tuple[float, ...]:
        """Process noise per level: position levels then orientation levels."""
        return self._noise

    @property
    def kind(self) -> str:
        """``"white_noise"`` or ``"thesis"``."""
        return self._kind

    @property
    def state_size(self) -> int:
        """Length of the nominal state vector, ``7 + 3 (n_dp + n_do)`` with both parts."""
        return kernels_for(_source).dims(self._n_dp, self._n_do, 1)[2]

    @property
    def error_size(self) -> int:
        """Size of the error-state covariance, ``3 (n_dp + 1) + 3 (n_do + 1)``."""
        return kernels_for(_source).dims(self._n_dp, self._n_do, 0)[3]

    def __repr__(self) -> str:
        return (
            f"MotionModel(n_dp={self._n_dp}, n_do={self._n_do}, noise={self._noise}, "
            f"kind={self._kind!r})"
        )

    def __eq__(self, other) -> bool:
        if not isinstance(other, MotionModel):
            return NotImplemented
        return (self._n_dp, self._n_do, self._noise, self._kind) == (
            other._n_dp,
            other._n_do,
            other._noise,
            other._kind,
        )

    def __hash__(self) -> int:
        return hash((self._n_dp, self._n_do, self._noise, self._kind))

    # -- parameter tuple for the kernels -----------------------------------------------------
    def kernel_params(self, formulation: str) -> tuple:
        """The model as the derivative-model kernels take it: ``(n_dp, n_do, additive, kind,
        sigma_p, sigma_o)``: derivative orders of position and orientation (-1: not
        estimated), ``additive`` 1 for the ``"additive"`` formulation (0 for
        ``"error_state"``), the noise kind's code and the noise densities (arrays) of the
        position and orientation chains.

        Raises
        ------
        ValueError
            If ``formulation`` is not one of :data:`FORMULATIONS`.
        """
        return (
            self._n_dp,
            self._n_do,
            _additive(formulation),
            _KINDS[self._kind],
            self._sig_p,
            self._sig_o,
        )

    # -- maths (NumPy or compiled backend) -----------------------------------------------------
    def initial_state(self) -> np.ndarray:
        """Nominal state at rest at the origin: zeros with the identity quaternion."""
        x = np.zeros(self.state_size)
        if self._n_do >= 0:
            x[3 * (self._n_dp + 1) + 3] = 1.0
        return x

    def _check_state(self, x) -> np.ndarray:
        x = np.ascontiguousarray(x, dtype=float)
        if x.shape != (self.state_size,) or not np.all(np.isfinite(x)):
            raise InputError(f"state must be finite with shape ({self.state_size},), got {x.shape}")
        return x

    def transition(self, x, dt: float, formulation: str = "error_state"):
        """Predict the nominal state over ``dt`` seconds.

        Returns
        -------
        x_new : ndarray (state_size,)
        J_new_old : ndarray (n, n)
            Jacobian of the covariance coordinates (``n = error_size`` for
            ``"error_state"``: ``t_true = t + dt``, ``R_true = R Exp(dtheta)``, derivatives
            additive; ``n = state_size`` for ``"additive"``: ``x_true = x + dx``).
        """
        n_dp, n_do, add, _, _, _ = self.kernel_params(formulation)
        return kernels_for(_source).transition(self._check_state(x), float(dt), n_dp, n_do, add)

    def process_noise(self, dt: float, x=None, formulation: str = "error_state") -> np.ndarray:
        """Process-noise covariance ``Q(dt)`` in the covariance coordinates of ``formulation``.

        ``x`` (the nominal state) is needed only by the additive formulation, whose quaternion
        block depends on ``q``.
        """
        n_dp, n_do, add, kind, sp, so = self.kernel_params(formulation)
        x = self.initial_state() if x is None else self._check_state(x)
        if not (math.isfinite(dt) and dt >= 0):
            raise InputError(f"dt must be finite and >= 0, got {dt}")
        return kernels_for(_source).process_noise(x, float(dt), n_dp, n_do, add, kind, sp, so)

    def retract(self, x, delta, formulation: str = "error_state") -> np.ndarray:
        """``x [+] delta``: apply a covariance-coordinate correction (quaternion re-normalised)."""
        n_dp, n_do, add, _, _, _ = self.kernel_params(formulation)
        out = self._check_state(x).copy()
        kernels_for(_source).inject(
            out,
            np.ascontiguousarray(delta, dtype=float),
            n_dp,
            n_do,
            add,
            0.0,
            np.empty(4),
            np.empty(4),
        )
        return out

    def local(self, x1, x0, formulation: str = "error_state") -> np.ndarray:
        """``x1 [-] x0`` in the covariance coordinates (``Log(q0^* q1)`` for the error state)."""
        n_dp, n_do, add, _, _, _ = self.kernel_params(formulation)
        return kernels_for(_source).local(
            self._check_state(x1), self._check_state(x0), n_dp, n_do, add
        )

    def residual(
        self,
        x,
        position_level: int,
        orientation_level: int,
        z_position=None,
        z_orientation=None,
        formulation: str = "error_state",
    ):
        """Innovation ``y = z - h(x)`` and Jacobian ``H`` of a measurement (thesis 6.2.3, 6.3.2).

        ``position_level`` / ``orientation_level`` are the measured derivative levels
        (``-1`` = not measured). The orientation residual is ``Log(q^* z_q)`` (error state,
        ``H = I``) or ``z_q - q/|q|`` with the normalisation Jacobian of eq. 6.23 (additive).

        Returns
        -------
        y : ndarray (m,)
        H : ndarray (m, n)
            With ``z = h(x [+] e) + v`` the innovation is ``y ~ H e + v`` to first order.
        """
        n_dp, n_do, add, _, _, _ = self.kernel_params(formulation)
        zp = np.zeros(3) if z_position is None else np.ascontiguousarray(z_position, dtype=float)
        zo = (
            np.array([0.0, 0.0, 0.0, 1.0])
            if z_orientation is None
            else np.ascontiguousarray(z_orientation, dtype=float)
        )
        if zo.shape == (3,):
            zo = np.concatenate([zo, [0.0]])
        return kernels_for(_update).residual(
            self._check_state(x), n_dp, n_do, add, position_level, orientation_level, zp, zo
        )
