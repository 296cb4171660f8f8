"""Shared test helpers: perturbing poses on the manifold, finite differences, Monte Carlo.

Everything here follows the error convention of ``docs/conventions.md``: a pose ``(t, R)`` with
error ``e = (dt, dtheta)`` is the true pose ``t_true = t + dt``, ``R_true = R Exp(dtheta)``
(``dt`` in frame a, metres; ``dtheta`` on the right, radians). :func:`retract` applies such an
error and :func:`local` measures it, so ``local(T, retract(T, e)) == e``.

The helpers are deliberately written with the public ``Pose``/quaternion API only, so that a
test using them checks the library against the convention, not against its own Jacobians.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from trackflow import Pose
from trackflow.math import quat_conjugate, quat_exp, quat_log, quat_multiply

__all__ = [
    "FD_STEP",
    "EDGE_QUATERNIONS",
    "axis_angle_quaternion",
    "retract",
    "local",
    "numeric_jacobian",
    "random_quaternion",
    "random_pose",
    "random_covariance",
    "sample_errors",
    "sample_poses",
    "sample_covariance",
    "covariance_agreement",
]

#: Default central-difference step (metres or radians). Truncation error ~ step^2 * f''' and
#: rounding error ~ eps |f| / step are both ~1e-9 relative for poses up to 10 m.
FD_STEP = 1e-6


def axis_angle_quaternion(axis, angle: float) -> np.ndarray:
    """Unit quaternion ``(x, y, z, w)`` of a rotation by ``angle`` radians about ``axis``.

    Written with sin/cos directly (not ``quat_exp``) so edge-case inputs do not depend on the
    code under test.
    """
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    return np.concatenate([np.sin(0.5 * angle) * a, [np.cos(0.5 * angle)]])


def _edge_quaternions() -> dict[str, np.ndarray]:
    axis = np.array([1.0, -2.0, 0.5])
    q_rand = axis_angle_quaternion([0.3, 0.4, -0.8], 2.1)
    return {
        "identity": np.array([0.0, 0.0, 0.0, 1.0]),
        "1e-9rad": axis_angle_quaternion(axis, 1e-9),
        "pi": axis_angle_quaternion(axis, np.pi),
        "pi-1e-6": axis_angle_quaternion(axis, np.pi - 1e-6),
        "179.9999deg(w~0)": axis_angle_quaternion([0.0, 0.0, 1.0], np.radians(179.9999)),
        "generic": q_rand,
        "generic-negated(-q)": -q_rand,
        "w<0": -axis_angle_quaternion([0.0, 1.0, 0.0], 0.7),
    }


#: The curated edge-case rotations, in one place: name -> unit quaternion (x, y, z, w).
EDGE_QUATERNIONS: dict[str, np.ndarray] = _edge_quaternions()


def random_quaternion(rng: np.random.Generator, shape: tuple[int, ...] = ()) -> np.ndarray:
    """Uniformly distributed unit quaternions of shape ``shape + (4,)``."""
    q = rng.standard_normal(tuple(shape) + (4,))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def random_pose(rng: np.random.Generator, lever: float = 1.0) -> Pose:
    """A single pose with uniform random rotation and a translation of length ``lever`` metres."""
    d = rng.standard_normal(3)
    return Pose(lever * d / np.linalg.norm(d), random_quaternion(rng))


def retract(pose: Pose, error) -> Pose:
    """Apply the error ``e = (dt, dtheta)`` (shape (..., 6)): ``(t + dt, q * Exp(dtheta))``."""
    e = np.asarray(error, dtype=float)
    return Pose(pose.position + e[..., :3], quat_multiply(pose.quaternion, quat_exp(e[..., 3:])))


def local(pose0: Pose, pose1: Pose) -> np.ndarray:
    """The error taking ``pose0`` to ``pose1``: ``(t1 - t0, Log(q0^* q1))``, shape (..., 6)."""
    dt = pose1.position - pose0.position
    dth = quat_log(quat_multiply(quat_conjugate(pose0.quaternion), pose1.quaternion))
    return np.concatenate(np.broadcast_arrays(dt, dth), axis=-1)


def _perturb(x, delta):
    if isinstance(x, Pose):
        return retract(x, delta)
    return np.asarray(x, dtype=float) + delta


def _difference(y0, y1):
    if isinstance(y0, Pose):
        return local(y0, y1)
    return np.asarray(y1, dtype=float) - np.asarray(y0, dtype=float)


def numeric_jacobian(
    func: Callable, args: Sequence, index: int, step: float = FD_STEP
) -> np.ndarray:
    """Central-difference Jacobian of ``func(*args)`` with respect to ``args[index]``.

    A ``Pose`` argument is perturbed with :func:`retract` (6 columns), an array argument (a
    point) additively. A ``Pose`` result is measured with :func:`local` (6 rows), an array
    result by subtraction. Returns ``J[i, j] = d out_i / d in_j`` at zero error.
    """
    args = list(args)
    x0 = args[index]
    n = 6 if isinstance(x0, Pose) else np.asarray(x0).shape[-1]
    y0 = func(*args)
    cols = []
    for j in range(n):
        d = np.zeros(n)
        d[j] = step
        plus = list(args)
        minus = list(args)
        plus[index] = _perturb(x0, d)
        minus[index] = _perturb(x0, -d)
        e_plus = _difference(y0, func(*plus))
        e_minus = _difference(y0, func(*minus))
        cols.append((e_plus - e_minus) / (2.0 * step))
    return np.stack(cols, axis=-1)


def random_covariance(
    rng: np.random.Generator,
    sigma_position: float = 1e-3,
    sigma_rotation: float = np.radians(1.0),
    size: int = 6,
    spread: float = 0.5,
) -> np.ndarray:
    """A correlated covariance with standard deviations of roughly the given sizes.

    The first three coordinates have standard deviation ``sigma_position``, the rest
    ``sigma_rotation``. The correlation matrix is ``Q diag(l) Q^T`` (uniformly random
    rotation ``Q``, eigenvalues ``l`` uniform in ``[1 - spread, 1 + spread]``) scaled to a unit
    diagonal, so every coordinate is correlated with every other one (typically |rho| ~ 0.1-0.4)
    while no direction is much thinner than the sigmas say (condition number <= 3 for the default
    spread). ``spread`` close to 1 gives nearly degenerate, strongly correlated covariances.
    """
    if not 0.0 <= spread < 1.0:
        raise ValueError(f"spread must be in [0, 1), got {spread}")
    q, r = np.linalg.qr(rng.standard_normal((size, size)))
    q = q * np.sign(np.diag(r))
    k = (q * rng.uniform(1.0 - spread, 1.0 + spread, size)) @ q.T
    d = np.sqrt(np.diag(k))
    corr = k / np.outer(d, d)
    sig = np.full(size, sigma_rotation)
    sig[: min(3, size)] = sigma_position
    c = corr * np.outer(sig, sig)
    return 0.5 * (c + c.T)


def sample_errors(rng: np.random.Generator, covariance, n: int) -> np.ndarray:
    """``n`` zero-mean Gaussian samples (n, k) with the given (k, k) covariance."""
    c = np.asarray(covariance, dtype=float)
    w, v = np.linalg.eigh(c)
    root = v * np.sqrt(np.maximum(w, 0.0))
    return rng.standard_normal((n, c.shape[-1])) @ root.T


def sample_poses(rng: np.random.Generator, pose: Pose, covariance, n: int) -> Pose:
    """``n`` poses ``retract(pose, e)`` with ``e ~ N(0, covariance)``: a Pose batch (n,)."""
    return retract(pose, sample_errors(rng, covariance, n))


def sample_covariance(errors) -> np.ndarray:
    """Sample covariance (about the sample mean, ``N - 1`` normalisation) of errors (n, k)."""
    e = np.asarray(errors, dtype=float)
    e = e - e.mean(axis=0)
    return e.T @ e / (len(e) - 1)


def covariance_agreement(analytic, reference) -> tuple[float, np.ndarray]:
    """Compare an analytic covariance ``C`` with a reference (Monte Carlo) covariance ``M``.

    Returns
    -------
    frobenius : float
        ``||C - M||_F / ||M||_F``.
    ratios : ndarray (k,)
        Eigenvalues, ascending, of ``M^-1/2 C M^-1/2``: the ratio analytic/reference of the
        variance along each whitened direction (1 everywhere for a perfect match).
    """
    c = np.asarray(analytic, dtype=float)
    m = np.asarray(reference, dtype=float)
    frob = float(np.linalg.norm(c - m) / np.linalg.norm(m))
    w, v = np.linalg.eigh(m)
    inv_root = (v / np.sqrt(w)) @ v.T
    ratios = np.linalg.eigvalsh(inv_root @ c @ inv_root)
    return frob, ratios
