"""Autoregressive-twist Kalman filter (``trackflow.filters.twist_ar``).

The motion model is a vector autoregression (VAR) of body-frame pose increments
``xi = (u, w)``; the filter state is the pose and the last ``L`` increments. Checked here:

* the step Jacobians against central differences of ``model.step`` on the error state
  ``e = (dt, dtheta, dxi_0 .. dxi_{L-1})`` (conventions of ``docs/conventions.md``), for both
  kernel backends, at the curated edge rotations, a zero history and a near-pi increment;
* the one-step covariance ``J P J^T + G Q G^T`` against a seeded Monte Carlo;
* :meth:`TwistARModel.fit` recovers a known VAR (also across timestamp gaps and, robustly,
  with position spikes) within bars derived from the least-squares standard errors;
* noise-free prediction reproduces the simulated trajectory, fractional horizons follow the
  documented constant-twist rule;
* the filter is consistent (NEES / NIS in chi-square bands over 30 seeded runs), both backends
  agree, dropped frames are repeated predictions (against a plain full-matrix reference
  filter written here) and long gaps restart;
* bad input raises ``ValueError`` naming the problem.

Trajectories are simulated independently of the module: increments by the VAR recursion here,
poses integrated with ``scipy.spatial.transform.Rotation``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import block_diag, solve_discrete_lyapunov
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from trackflow.filters import FilterStatus, GatePolicy
from trackflow.filters.twist_ar import TwistARModel, run_twist_ar
from trackflow.math import (
    numba_available,
    quat_conjugate,
    quat_exp,
    quat_log,
    quat_multiply,
    quat_rotate,
    use_backend,
)

_MATH_TESTS = str(Path(__file__).resolve().parents[1] / "math")
if _MATH_TESTS not in sys.path:
    sys.path.insert(0, _MATH_TESTS)
from _helpers import (  # noqa: E402
    EDGE_QUATERNIONS,
    covariance_agreement,
    random_covariance,
    random_quaternion,
    sample_covariance,
    sample_errors,
)

BACKENDS = ["numpy", *(["numba"] if numba_available() else [])]
DT = 0.01


# -- independent helpers -----------------------------------------------------------------------


def companion_radius(a: np.ndarray) -> float:
    """Largest eigenvalue modulus of the VAR companion matrix of ``a`` (L, 6, 6)."""
    order = a.shape[0]
    comp = np.zeros((6 * order, 6 * order))
    comp[:6] = np.concatenate(list(a), axis=1)
    comp[6:, :-6] = np.eye(6 * order - 6)
    return float(np.max(np.abs(np.linalg.eigvals(comp))))


def stable_coefficients(rng, order: int, radius: float) -> np.ndarray:
    """Random ``A_j`` scaled so the companion spectral radius is exactly ``radius``.

    ``A_j -> s^(j+1) A_j`` multiplies every companion eigenvalue by ``s``.
    """
    a = rng.standard_normal((order, 6, 6)) / np.sqrt(6.0)
    s = radius / companion_radius(a)
    return a * (s ** np.arange(1, order + 1))[:, None, None]


def stationary_twist_covariance(a: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Marginal covariance of one increment of the stationary VAR."""
    order = a.shape[0]
    comp = np.zeros((6 * order, 6 * order))
    comp[:6] = np.concatenate(list(a), axis=1)
    comp[6:, :-6] = np.eye(6 * order - 6)
    big_q = np.zeros_like(comp)
    big_q[:6, :6] = q
    c = solve_discrete_lyapunov(comp, big_q)[:6, :6]
    return 0.5 * (c + c.T)


def var_increments(rng, a, q, n, history=None, warmup=200):
    """``n`` increments of the VAR ``xi_{k+1} = sum_j A_j xi_{k-j} + n_k`` (after a warm-up).

    Returns ``(xi (n, 6), history (L, 6))``: ``history`` (newest first) precedes ``xi[0]``.
    """
    order = a.shape[0]
    a_cat = np.concatenate(list(a), axis=1)
    h = np.zeros(6 * order) if history is None else np.asarray(history, float).reshape(-1)
    noise = sample_errors(rng, q, warmup + n)
    out = np.empty((warmup + n, 6))
    for k in range(warmup + n):
        xi = a_cat @ h + noise[k]
        h = np.concatenate([xi, h[:-6]])
        out[k] = xi
    if warmup:
        pre = out[warmup - order : warmup][::-1]
    else:
        pre = np.asarray(history, float).reshape(order, 6)
    return out[warmup:], pre.copy()


def integrate(xi, p0, q0):
    """Poses ``0..n``: pose ``k+1`` = pose ``k`` moved by ``xi[k]`` in its body frame."""
    rot = Rotation.from_quat(q0)
    inc = Rotation.from_rotvec(xi[:, 3:]).as_quat()
    quats = [rot.as_quat()]
    for k in range(xi.shape[0]):
        rot = rot * Rotation.from_quat(inc[k])
        quats.append(rot.as_quat())
    quats = np.array(quats)
    steps = Rotation.from_quat(quats[:-1]).apply(xi[:, :3])
    pos = np.vstack([p0, p0 + np.cumsum(steps, axis=0)])
    return pos, quats


def histories(pre, xi):
    """History (L, 6) newest first at every pose ``0..n`` of :func:`integrate`."""
    order = pre.shape[0]
    seq = np.vstack([pre[::-1], xi])  # oldest first; pose k has seq[k + L - 1] as newest
    return np.stack([seq[k : k + order][::-1] for k in range(xi.shape[0] + 1)])


def angle_between(q0, q1):
    """Rotation angle between unit quaternions (sign-agnostic), radians."""
    r = quat_multiply(quat_conjugate(q0), q1)
    return 2.0 * np.arctan2(np.linalg.norm(r[..., :3], axis=-1), np.abs(r[..., 3]))


def pose_error(p0, q0, p1, q1):
    """``(t1 - t0, Log(q0^* q1))``: the error taking pose 0 to pose 1."""
    return np.concatenate([p1 - p0, quat_log(quat_multiply(quat_conjugate(q0), q1))], axis=-1)


def state_error(s0, s1):
    """Error-state difference ``(dt, dtheta, dxi...)`` taking state ``s0`` to ``s1``."""
    p0, q0, h0 = s0
    p1, q1, h1 = s1
    dh = (h1 - h0).reshape(*h1.shape[:-2], -1)
    return np.concatenate([pose_error(p0, q0, p1, q1), dh], axis=-1)


def retract_state(state, e):
    """``(t + dt, q Exp(dtheta), history + dxi)``, batched over ``e``'s leading axes."""
    p, q, h = state
    e = np.asarray(e, dtype=float)
    return (
        p + e[..., :3],
        quat_multiply(q, quat_exp(e[..., 3:6])),
        h + e[..., 6:].reshape(*e.shape[:-1], *h.shape),
    )


def step_with_noise(model, state, noise):
    """One step with ``noise`` added to the new increment, the module's conventions written out:
    ``t' = t + R u``, ``q' = q Exp(w)``, history shifted."""
    p, q, h = state
    xi = model.next_increment(h) + noise
    p1 = p + quat_rotate(q, xi[..., :3])
    q1 = quat_multiply(q, quat_exp(xi[..., 3:]))
    h1 = np.concatenate([xi[..., None, :], h[..., :-1, :]], axis=-2)
    return p1, q1, h1


def central_difference(func, n, step=1e-6):
    cols = []
    for j in range(n):
        d = np.zeros(n)
        d[j] = step
        cols.append((func(d) - func(-d)) / (2.0 * step))
    return np.stack(cols, axis=1)


def measure(rng, pos, quats, pos_sigma, ori_sigma):
    zp = pos + pos_sigma * rng.standard_normal(pos.shape)
    zq = quat_multiply(quats, quat_exp(ori_sigma * rng.standard_normal(pos.shape)))
    return zp, zq


# -- 1. Jacobians against finite differences -------------------------------------------------


def _history(kind, rng, a):
    order = a.shape[0]
    if kind == "zero":
        return np.zeros((order, 6))
    h = np.concatenate(
        [rng.uniform(-5e-3, 5e-3, (order, 3)), rng.uniform(-0.17, 0.17, (order, 3))], axis=1
    )
    if kind == "random":
        return h
    # near-pi: scale the history so that the *next* increment turns by pi - 1e-3 (that is
    # where J_r(w) and Exp(-w) enter the Jacobian)
    w = np.einsum("jab,jb->a", a, h)[3:]
    return h * (np.pi - 1e-3) / np.linalg.norm(w)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("order", [1, 2, 3])
@pytest.mark.parametrize("kind", ["random", "zero", "near-pi"])
def test_step_jacobians_match_finite_differences(backend, order, kind):
    rng = np.random.default_rng(100 * order + len(kind))
    a = stable_coefficients(rng, order, 0.9)
    model = TwistARModel(DT, a, 1e-6 * np.eye(6))
    h = _history(kind, rng, a)
    if kind == "near-pi":
        assert abs(np.linalg.norm(model.next_increment(h)[3:]) - (np.pi - 1e-3)) < 1e-9
    n = model.state_dim
    p = np.array([0.4, -1.1, 2.3])
    for name, q in EDGE_QUATERNIONS.items():
        state = (p, q, h)
        with use_backend(backend):
            j_state, j_noise = model.jacobians_step(q, h)
        assert j_state.shape == (n, n) and j_noise.shape == (n, 6)
        ref = model.step(*state)

        def moved(e, state=state, ref=ref):
            return state_error(ref, model.step(*retract_state(state, e)))

        def noisy(d, state=state, ref=ref):
            return state_error(ref, step_with_noise(model, state, d))

        fd_state = central_difference(moved, n)
        fd_noise = central_difference(noisy, 6)
        tol = 1e-6 * max(1.0, np.max(np.abs(fd_state)))
        np.testing.assert_allclose(
            j_state, fd_state, rtol=0, atol=tol, err_msg=f"J_next_state at {name}"
        )
        np.testing.assert_allclose(
            j_noise, fd_noise, rtol=0, atol=1e-6, err_msg=f"J_next_noise at {name}"
        )


# -- 2. one-step covariance against Monte Carlo --------------------------------------------------


@pytest.mark.parametrize("backend", BACKENDS)
def test_one_step_covariance_matches_monte_carlo(backend):
    """``J P J^T + G Q G^T`` vs the sample covariance of 2e4 stepped, retracted errors.

    Fast increments (~5 cm, ~0.3 rad per step) so the cross terms ``-R [u]x dtheta`` and
    ``Exp(-w)`` matter at the few-percent level; errors of mm / mrad keep the linearisation
    exact to ~1e-3. Sampling error of the covariance with 2e4 samples in 18 dimensions is
    ~1-3 % per whitened direction (Marchenko-Pastur edges ~ 1 +- 0.06).
    """
    rng = np.random.default_rng(7)
    order = 2
    a = stable_coefficients(rng, order, 0.9)
    h = np.concatenate(
        [rng.uniform(-0.05, 0.05, (order, 3)), rng.uniform(-0.3, 0.3, (order, 3))], axis=1
    )
    h *= 0.3 / np.linalg.norm(np.einsum("jab,jb->a", a, h)[3:])  # next increment: 0.3 rad
    noise = random_covariance(rng, 1e-3, 2e-3)
    model = TwistARModel(DT, a, noise)
    assert np.linalg.norm(model.next_increment(h)[3:]) == pytest.approx(0.3)
    n = model.state_dim
    sig = np.tile([1e-3] * 3 + [3e-3] * 3, n // 6)
    p_cov = random_covariance(rng, 1.0, 1.0, size=n) * np.outer(sig, sig)
    state = (np.array([1.0, 0.2, -0.5]), random_quaternion(rng), h)
    with use_backend(backend):
        j_state, j_noise = model.jacobians_step(state[1], h)
    analytic = j_state @ p_cov @ j_state.T + j_noise @ noise @ j_noise.T

    m = 20_000
    e = sample_errors(rng, p_cov, m)
    nz = sample_errors(rng, noise, m)
    stepped = step_with_noise(model, retract_state(state, e), nz)
    ref = model.step(*state)
    errors = state_error(tuple(np.broadcast_to(x, (m, *x.shape)) for x in ref), stepped)
    frob, ratios = covariance_agreement(analytic, sample_covariance(errors))
    assert frob < 0.05, f"Frobenius relative error {frob:.3f}"
    assert 0.9 < ratios[0] and ratios[-1] < 1.1, f"whitened variance ratios {ratios}"
    # the same bars reject the propagation without the pose cross terms
    j_bad = j_state.copy()
    j_bad[:3, 3:6] = 0.0
    _, ratios_bad = covariance_agreement(
        j_bad @ p_cov @ j_bad.T + j_noise @ noise @ j_noise.T, sample_covariance(errors)
    )
    assert ratios_bad[0] < 0.9 or ratios_bad[-1] > 1.1


# -- 3. fitting --------------------------------------------------------------------------------


def design(xi, order):
    """Regressors and targets of the true increments (for the standard errors)."""
    rows = np.arange(order - 1, xi.shape[0] - 1)
    x = np.concatenate([xi[rows - j] for j in range(order)], axis=1)
    return x, xi[rows + 1]


@pytest.fixture(scope="module")
def fit_data():
    """A long stationary L = 2 recording (2e4 samples) and its true model."""
    rng = np.random.default_rng(33)
    order = 2
    a = stable_coefficients(rng, order, 0.85)
    q = random_covariance(rng, 5e-4, 3e-3)
    xi, _ = var_increments(rng, a, q, 20_000)
    pos, quats = integrate(xi, np.array([0.1, 0.2, 1.5]), random_quaternion(rng))
    x, _ = design(xi, order)
    # OLS standard errors: cov(vec A) = Q (x) (X^T X)^-1
    xtx_inv = np.linalg.inv(x.T @ x)
    se = np.sqrt(np.outer(np.diag(q), np.diag(xtx_inv)))  # (6, 6 L): [a, 6 j + b]
    se = se.reshape(6, order, 6).transpose(1, 0, 2)
    t = DT * np.arange(pos.shape[0])
    return {"a": a, "q": q, "t": t, "pos": pos, "quats": quats, "se": se}


def z_score(fitted: TwistARModel, data) -> float:
    """Largest coefficient error in units of its least-squares standard error."""
    return float(np.max(np.abs(fitted.coefficients - data["a"]) / data["se"]))


def test_fit_recovers_coefficients_and_noise(fit_data):
    """72 coefficients, each within 5 standard errors (a 5-sigma miss somewhere has
    probability ~4e-5); noise within 5 % (sampling error of a variance ~ sqrt(2/N) = 1 %)."""
    d = fit_data
    fitted = TwistARModel.fit(d["t"], d["pos"], d["quats"], order=2)
    assert fitted.order == 2
    assert fitted.dt == pytest.approx(DT)
    assert z_score(fitted, d) < 5.0
    # the bar is informative: half the coefficients are known to better than 15 %
    assert np.median(d["se"] / np.abs(d["a"])) < 0.15
    sd = np.sqrt(np.diag(d["q"]))
    rel = (fitted.noise - d["q"]) / np.outer(sd, sd)
    assert np.max(np.abs(rel)) < 0.05, rel
    assert fitted.spectral_radius() == pytest.approx(0.85, abs=0.03)
    plain = TwistARModel.fit(d["t"], d["pos"], d["quats"], order=2, robust=False)
    assert z_score(plain, d) < 5.0


def _jump(pos, quats, k, rng):
    """Move poses ``k..`` by a rigid transform (body increments after ``k`` are unchanged)."""
    rj = Rotation.from_rotvec(rng.normal(0.0, 0.5, 3))
    pos = pos.copy()
    quats = quats.copy()
    pos[k:] = rj.apply(pos[k:]) + rng.normal(0.0, 0.3, 3)
    quats[k:] = (rj * Rotation.from_quat(quats[k:])).as_quat()
    return pos, quats


def test_fit_skips_windows_across_gaps(fit_data):
    d = fit_data
    rng = np.random.default_rng(5)
    t, pos, quats = d["t"].copy(), d["pos"], d["quats"]
    for k in (3_000, 9_000, 15_500):
        t[k:] += 0.37  # a long gap before sample k ...
        pos, quats = _jump(pos, quats, k, rng)  # ... during which the body moved on
    fitted = TwistARModel.fit(t, pos, quats, order=2, robust=False)
    assert z_score(fitted, d) < 5.0
    # the same poses with the gaps hidden (regular times) pull the fit far off
    hidden = TwistARModel.fit(d["t"], pos, quats, order=2, robust=False)
    assert z_score(hidden, d) > 20.0


def _spiky(data, seed=11, fraction=0.01, size=0.05):
    """The recording with ``fraction`` of the positions displaced by ``size`` metres."""
    rng = np.random.default_rng(seed)
    pos = data["pos"].copy()
    idx = rng.choice(pos.shape[0], int(fraction * pos.shape[0]), replace=False)
    spike = rng.standard_normal((idx.size, 3))
    pos[idx] += size * spike / np.linalg.norm(spike, axis=1, keepdims=True)
    return pos


def test_position_spikes_pull_the_plain_fit(fit_data):
    """The spike scenario below is a real test: least squares is pulled far off by it."""
    d = fit_data
    plain = TwistARModel.fit(d["t"], _spiky(d), d["quats"], order=2, robust=False)
    assert z_score(plain, d) > 20.0


def test_fit_robust_to_position_spikes(fit_data):
    """``robust=True`` stays within 8 standard errors (the clean fit: ~3); plain is 4x worse."""
    d = fit_data
    pos = _spiky(d)
    robust = TwistARModel.fit(d["t"], pos, d["quats"], order=2, robust=True)
    plain = TwistARModel.fit(d["t"], pos, d["quats"], order=2, robust=False)
    z_robust, z_plain = z_score(robust, d), z_score(plain, d)
    assert z_robust < 8.0, f"robust fit {z_robust:.1f} standard errors off (plain {z_plain:.1f})"
    assert z_plain > 4.0 * z_robust


# -- 4. prediction -----------------------------------------------------------------------------


def test_predict_reproduces_noise_free_trajectory():
    rng = np.random.default_rng(21)
    order = 2
    a = stable_coefficients(rng, order, 0.97)
    pre = np.concatenate([rng.uniform(-3e-3, 3e-3, (order, 3)), rng.normal(0, 0.05, (order, 3))], 1)
    xi, pre = var_increments(rng, a, np.zeros((6, 6)), 40, history=pre, warmup=0)
    pos, quats = integrate(xi, np.array([0.3, -0.2, 1.0]), random_quaternion(rng))
    hist = histories(pre, xi)
    model = TwistARModel(DT, a, np.zeros((6, 6)), twist_covariance=np.eye(6))
    k = 5
    for m in range(12):
        p, q = model.predict(pos[k], quats[k], hist[k], m * DT)
        np.testing.assert_allclose(p, pos[k + m], rtol=0, atol=1e-9)
        assert angle_between(q, quats[k + m]) < 1e-9
    # batched: every sample at once, 3 steps ahead
    p, q = model.predict(pos[:-3], quats[:-3], hist[:-3], 3 * DT)
    np.testing.assert_allclose(p, pos[3:], rtol=0, atol=1e-9)
    assert np.max(angle_between(q, quats[3:])) < 1e-9
    # fractional horizon: the fraction f of the next increment at constant body twist
    for m, f in ((0, 0.25), (2, 0.5), (4, 0.9)):
        p, q = model.predict(pos[k], quats[k], hist[k], (m + f) * DT)
        nxt = xi[k + m]  # the increment taking pose k+m to pose k+m+1
        r = Rotation.from_quat(quats[k + m])
        np.testing.assert_allclose(p, pos[k + m] + r.apply(f * nxt[:3]), rtol=0, atol=1e-9)
        q_ref = (r * Rotation.from_rotvec(f * nxt[3:])).as_quat()
        assert angle_between(q, q_ref) < 1e-9
        # hence between the neighbouring samples, in proportion f
        d0 = np.linalg.norm(p - pos[k + m])
        d1 = np.linalg.norm(p - pos[k + m + 1])
        assert d0 == pytest.approx(f * np.linalg.norm(nxt[:3]), rel=1e-9)
        assert d1 == pytest.approx((1 - f) * np.linalg.norm(nxt[:3]), rel=1e-9)
        assert angle_between(q, quats[k + m]) == pytest.approx(f * np.linalg.norm(nxt[3:]))
        assert angle_between(q, quats[k + m + 1]) == pytest.approx(
            (1 - f) * np.linalg.norm(nxt[3:])
        )


# -- 5. filter consistency ----------------------------------------------------------------------


# one backend (numba when installed); test_backends_agree shows both give the same numbers
@pytest.mark.parametrize("backend", BACKENDS[-1:])
def test_filter_nees_and_nis_in_chi_square_band(backend):
    runs, steps, burn = 30, 200, 50
    pos_sigma, ori_sigma = 1e-3, 2e-3
    rng0 = np.random.default_rng(55)
    a = stable_coefficients(rng0, 2, 0.9)
    q = random_covariance(rng0, 3e-4, 2e-3)
    model = TwistARModel(DT, a, q, twist_covariance=stationary_twist_covariance(a, q))
    t = DT * np.arange(steps)
    nees = np.empty((runs, steps))
    nis = np.empty((runs, steps))
    for r in range(runs):
        rng = np.random.default_rng(1000 + r)
        xi, _ = var_increments(rng, a, q, steps - 1)
        pos, quats = integrate(xi, rng.normal(0.0, 0.5, 3), random_quaternion(rng))
        zp, zq = measure(rng, pos, quats, pos_sigma, ori_sigma)
        with use_backend(backend):
            res = run_twist_ar(t, zp, zq, model, pos_sigma, ori_sigma)
        e = pose_error(res.position, res.quaternion, pos, quats)
        nees[r] = np.einsum("ki,ki->k", e, np.linalg.solve(res.covariance, e[..., None])[..., 0])
        nis[r] = res.nis
    assert np.all(np.isnan(nis[:, 0])) and np.all(np.isfinite(nis[:, 1:]))
    lo, hi = chi2.ppf([0.025, 0.975], 6 * runs) / runs
    for name, val in (("NEES", nees), ("NIS", nis)):
        per_step = val[:, burn:].mean(axis=0)
        assert lo < per_step.mean() < hi, (
            f"{name} mean {per_step.mean():.2f} not in [{lo:.2f}, {hi:.2f}]"
        )
        inside = np.mean((per_step > lo) & (per_step < hi))
        assert inside > 0.85, f"{name}: only {inside:.0%} of steps in [{lo:.2f}, {hi:.2f}]"


# -- 6./7. backends, dropped frames, gaps -------------------------------------------------------


def simulated_recording(seed, n, pos_sigma=1e-3, ori_sigma=2e-3, order=2):
    """A model, its simulated trajectory at ``k dt`` and noisy measurements of it."""
    rng = np.random.default_rng(seed)
    a = stable_coefficients(rng, order, 0.9)
    q = random_covariance(rng, 3e-4, 2e-3)
    model = TwistARModel(DT, a, q, twist_covariance=stationary_twist_covariance(a, q))
    xi, _ = var_increments(rng, a, q, n - 1)
    pos, quats = integrate(xi, rng.normal(0.0, 0.5, 3), random_quaternion(rng))
    zp, zq = measure(rng, pos, quats, pos_sigma, ori_sigma)
    return model, pos, quats, zp, zq


def reference_filter(t, pm, qm, model, pos_sigma, ori_sigma, max_gap):
    """The filter written out with full matrices: ``m = round(interval / dt)`` predictions
    ``P <- F P F^T + G Q G^T`` with ``model.jacobians_step`` and ``model.step``, then the
    textbook Kalman update (the Joseph form equals it for the optimal gain)."""
    order, n = model.order, model.state_dim
    r = np.diag([pos_sigma**2] * 3 + [ori_sigma**2] * 3)
    hm = np.hstack([np.eye(6), np.zeros((6, n - 6))])
    out = {"p": [], "q": [], "h": [], "c": [], "nis": []}
    restarts = 0
    for k in range(len(t)):
        if k == 0 or t[k] - t[k - 1] > max_gap:
            p, q = pm[k].copy(), qm[k] / np.linalg.norm(qm[k])
            h = np.zeros((order, 6))
            cov = block_diag(r, *[model.twist_covariance] * order)
            restarts += 1
            nis = np.nan
        else:
            for _ in range(max(1, round((t[k] - t[k - 1]) / model.dt))):
                f, g = model.jacobians_step(q, h)
                cov = f @ cov @ f.T + g @ model.noise @ g.T
                p, q, h = model.step(p, q, h)
            y = pose_error(p, q, pm[k], qm[k])
            s = hm @ cov @ hm.T + r
            gain = cov @ hm.T @ np.linalg.inv(s)
            nis = y @ np.linalg.solve(s, y)
            dx = gain @ y
            p = p + dx[:3]
            q = quat_multiply(q, quat_exp(dx[3:6]))
            h = h + dx[6:].reshape(order, 6)
            cov = (np.eye(n) - gain @ hm) @ cov
            cov = 0.5 * (cov + cov.T)
        for key, v in (("p", p), ("q", q), ("h", h), ("c", cov[:6, :6]), ("nis", nis)):
            out[key].append(v)
    return {key: np.array(v) for key, v in out.items()}, restarts


def assert_results_equal(res, ref, what):
    np.testing.assert_allclose(res.position, ref["p"], rtol=0, atol=1e-9, err_msg=what)
    assert np.max(angle_between(res.quaternion, ref["q"])) < 1e-9, what
    hs = np.max(np.abs(ref["h"]))
    np.testing.assert_allclose(res.history, ref["h"], rtol=0, atol=1e-9 * hs, err_msg=what)
    cs = np.max(np.abs(ref["c"]))
    np.testing.assert_allclose(res.covariance, ref["c"], rtol=1e-9, atol=1e-9 * cs, err_msg=what)
    np.testing.assert_allclose(res.nis, ref["nis"], rtol=1e-8, atol=1e-9, err_msg=what)


@pytest.mark.skipif(not numba_available(), reason="numba is not installed")
def test_backends_agree():
    model, _, _, zp, zq = simulated_recording(61, 200)
    t = DT * np.arange(200)
    t[120:] += 1.0  # a gap longer than max_gap: the filter restarts there
    results = {}
    for backend in ("numpy", "numba"):
        with use_backend(backend):
            results[backend] = run_twist_ar(
                t, zp, zq, model, 1e-3, 2e-3, horizons=(0.0, 0.025, 0.05), max_gap=0.5
            )
    a, b = results["numpy"], results["numba"]
    assert a.restarts == b.restarts == 2
    assert np.isnan(a.nis[120]) and np.isnan(b.nis[120])
    ref = {"p": a.position, "q": a.quaternion, "h": a.history, "c": a.covariance, "nis": a.nis}
    assert_results_equal(b, ref, "numba vs numpy")
    assert set(a.predictions) == set(b.predictions) == {0.0, 0.025, 0.05}
    for hz in a.predictions:
        np.testing.assert_allclose(a.predictions[hz][0], b.predictions[hz][0], atol=1e-9)
        assert np.max(angle_between(a.predictions[hz][1], b.predictions[hz][1])) < 1e-9
    np.testing.assert_array_equal(a.predictions[0.0][0], a.position)


@pytest.mark.parametrize("backend", BACKENDS)
def test_dropped_frames_are_repeated_predictions_and_gaps_restart(backend):
    """Against the full-matrix reference: jittered intervals (rounded to one step), dropped
    frames (2 and 3 steps), and a gap beyond ``max_gap`` (a restart)."""
    n = 90
    model, _, _, zp, zq = simulated_recording(62, n)
    rng = np.random.default_rng(3)
    grid = np.arange(n, dtype=float)
    grid[60:] += 30.0  # 0.3 s gap
    keep = np.setdiff1d(np.arange(n), [20, 40, 41, 75])
    t = DT * (grid + rng.uniform(-0.1, 0.1, n))[keep]
    zp, zq = zp[keep], zq[keep]
    intervals = np.round(np.diff(t) / DT).astype(int)
    assert {1, 2, 3, 31} <= set(intervals.tolist())
    ref, ref_restarts = reference_filter(t, zp, zq, model, 1e-3, 2e-3, max_gap=0.2)
    with use_backend(backend):
        res = run_twist_ar(t, zp, zq, model, 1e-3, 2e-3, max_gap=0.2)
    assert res.restarts == ref_restarts == 2
    assert_results_equal(res, ref, backend)
    # without max_gap the filter never restarts after the first sample
    with use_backend(backend):
        res = run_twist_ar(t, zp, zq, model, 1e-3, 2e-3)
    assert res.restarts == 1
    assert np.all(np.isfinite(res.nis[1:]))


@pytest.mark.parametrize("backend", BACKENDS)
def test_dropped_frame_lands_on_the_trajectory(backend):
    """Nearly exact data of the model: after dropping frames the filtered pose is still on the
    trajectory and the innovation is ordinary (a missing prediction would miss by a whole
    increment, > 100 sigma)."""
    n = 60
    rng = np.random.default_rng(71)
    a = stable_coefficients(rng, 2, 0.95)
    q = 1e-12 * np.eye(6)
    pre = np.concatenate([rng.uniform(-3e-3, 3e-3, (2, 3)), rng.normal(0, 0.03, (2, 3))], 1)
    xi, _ = var_increments(rng, a, q, n - 1, history=pre, warmup=0)
    pos, quats = integrate(xi, np.zeros(3), random_quaternion(rng))
    sigma = 1e-6
    zp, zq = measure(rng, pos, quats, sigma, sigma)
    model = TwistARModel(DT, a, q, twist_covariance=np.diag([1e-5] * 3 + [1e-3] * 3))
    keep = np.setdiff1d(np.arange(n), [40, 50, 51])
    with use_backend(backend):
        res = run_twist_ar(DT * keep, zp[keep], zq[keep], model, sigma, sigma)
    after = np.searchsorted(keep, [41, 52])
    assert np.max(res.nis[after]) < chi2.ppf(0.9999, 6)
    np.testing.assert_allclose(res.position[after], pos[[41, 52]], rtol=0, atol=1e-5)
    assert np.max(angle_between(res.quaternion[after], quats[[41, 52]])) < 1e-5
    assert np.min(np.linalg.norm(xi[[40, 50, 51], :3], axis=1)) > 1e-4  # a miss would show


# -- 8. bad input ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_case():
    rng = np.random.default_rng(81)
    model = TwistARModel(DT, stable_coefficients(rng, 2, 0.8), 1e-6 * np.eye(6))
    n = 10
    t = DT * np.arange(n)
    p = rng.normal(size=(n, 3))
    q = random_quaternion(rng, (n,))
    return model, t, p, q


def test_run_rejects_bad_input(small_case):
    model, t, p, q = small_case

    def run(**kw):
        args = {"t": t, "position": p, "quaternion": q, "model": model}
        args.update(pos_sigma=1e-3, ori_sigma=1e-3)
        args.update(kw)
        return run_twist_ar(**args)

    run()  # the valid case runs
    shape = r"positions \(N, 3\), quaternions \(N, 4\)"
    cases = [
        ({"position": p[:, :2]}, shape),
        ({"quaternion": q[:, :3]}, shape),
        ({"t": t[:-1]}, shape),
        ({"position": p[:-1]}, shape),
        ({"t": t[::-1].copy()}, "increase strictly"),
        ({"t": np.r_[t[:5], t[4:9]]}, r"increase strictly \(sample 5\)"),
        ({"t": np.where(np.arange(10) == 3, np.nan, t)}, "finite"),
        ({"position": np.where(np.arange(30).reshape(10, 3) == 7, np.nan, p)}, "finite"),
        ({"quaternion": np.where(np.arange(40).reshape(10, 4) == 7, np.inf, q)}, "finite"),
        ({"pos_sigma": 0.0}, "pos_sigma"),
        ({"pos_sigma": -1e-3}, "pos_sigma"),
        ({"pos_sigma": np.nan}, "pos_sigma"),
        ({"ori_sigma": 0.0}, "ori_sigma"),
        ({"horizons": (0.1, -0.01)}, "horizons"),
        ({"horizons": (np.nan,)}, "horizons"),
    ]
    for kw, pattern in cases:
        with pytest.raises(ValueError, match=pattern):
            run(**kw)


def test_model_rejects_bad_parameters():
    rng = np.random.default_rng(82)
    a = stable_coefficients(rng, 2, 0.8)
    q = random_covariance(rng, 1e-3, 1e-3)
    TwistARModel(DT, a, q, twist_covariance=100 * q)  # valid
    skew = q.copy()
    skew[0, 1] += 1e-4
    not_psd = q - 2 * np.max(np.linalg.eigvalsh(q)) * np.outer(np.eye(6)[0], np.eye(6)[0])
    cases = [
        ({"coefficients": a[:, :, :5]}, r"coefficients must have shape \(L, 6, 6\)"),
        ({"coefficients": a[0]}, r"coefficients must have shape \(L, 6, 6\)"),
        ({"coefficients": np.zeros((0, 6, 6))}, r"coefficients must have shape \(L, 6, 6\)"),
        ({"coefficients": np.where(a == a[1, 2, 3], np.nan, a)}, "coefficients must be finite"),
        ({"noise": q[:5, :5]}, r"noise must have shape \(6, 6\)"),
        ({"noise": skew}, "noise must be symmetric"),
        ({"noise": not_psd}, "noise must be positive semi-definite"),
        ({"twist_covariance": skew}, "twist_covariance must be symmetric"),
        ({"twist_covariance": np.eye(5)}, "twist_covariance must have shape"),
        ({"dt": 0.0}, "dt must be a positive"),
        ({"dt": -DT}, "dt must be a positive"),
        ({"dt": np.nan}, "dt must be a positive"),
    ]
    for kw, pattern in cases:
        args = {"dt": DT, "coefficients": a, "noise": q, **kw}
        with pytest.raises(ValueError, match=pattern):
            TwistARModel(**args)


def test_fit_and_predict_reject_bad_input(fit_data, small_case):
    d = fit_data
    t, p, q = d["t"][:500], d["pos"][:500], d["quats"][:500]
    TwistARModel.fit(t, p, q, order=2)  # valid
    with pytest.raises(ValueError, match="order must be >= 1"):
        TwistARModel.fit(t, p, q, order=0)
    with pytest.raises(ValueError, match="too few regular samples"):
        TwistARModel.fit(t[:40], p[:40], q[:40], order=2)
    # plenty of samples, but every second interval is a dropped frame: no regular windows
    irregular = DT * np.cumsum(np.tile([1.0, 2.0], 250))
    with pytest.raises(ValueError, match="too few regular samples"):
        TwistARModel.fit(irregular, p, q, order=2, dt=DT)
    with pytest.raises(ValueError, match=r"positions \(N, 3\)"):
        TwistARModel.fit(t, p[:, :2], q, order=2)
    with pytest.raises(ValueError, match=r"quaternions \(N, 4\)"):
        TwistARModel.fit(t[:-1], p, q, order=2)
    with pytest.raises(ValueError, match="increase strictly"):
        TwistARModel.fit(t[::-1].copy(), p, q, order=2)
    with pytest.raises(ValueError, match="dt must be a positive"):
        TwistARModel.fit(t, p, q, order=2, dt=-DT)
    model, _, pp, qq = small_case
    h = np.zeros((2, 6))
    for bad in (-0.01, np.nan, np.inf):
        with pytest.raises(ValueError, match="horizon must be >= 0"):
            model.predict(pp[0], qq[0], h, bad)


def test_fit_names_non_finite_input(fit_data):
    d = fit_data
    p = d["pos"][:500].copy()
    p[100, 1] = np.nan
    with pytest.raises(ValueError, match="(position|input|sample).*finite|finite.*position"):
        TwistARModel.fit(d["t"][:500], p, d["quats"][:500], order=2)


@pytest.mark.parametrize("backend", BACKENDS)
def test_gate_rejects_outliers_and_resets_after_a_run(backend):
    """The shared gate policy (``trackflow.filters.gating``) in the twist-AR loop: an outlier
    is gated and leaves the state as if it never came; ``reset_after`` consecutive outliers
    re-initialise the filter from the next one; no gate (the default) integrates everything."""
    model, _, _, zp, zq = simulated_recording(62, 300)
    t = DT * np.arange(300)
    bad = zp.copy()
    bad[100] += 0.5  # one 50 cm outlier
    bad[200:203] += 0.5  # three in a row
    policy = GatePolicy(gate_probability=0.999, reset_after=3)
    with use_backend(backend):
        clean = run_twist_ar(t[:100], zp[:100], zq[:100], model, 1e-3, 2e-3)
        gated = run_twist_ar(t, bad, zq, model, 1e-3, 2e-3, gate=policy)
        plain = run_twist_ar(t, bad, zq, model, 1e-3, 2e-3)
    st = gated.status
    assert st[0] == FilterStatus.INITIALIZED
    assert st[100] == FilterStatus.GATED
    assert st[200:203].tolist() == [int(FilterStatus.GATED)] * 3
    assert st[203] == FilterStatus.RESET
    others = np.setdiff1d(np.arange(1, 300), [100, 200, 201, 202, 203])
    assert np.all(st[others] == int(FilterStatus.ACCEPTED))
    # the gated sample's output is the prediction: the clean run's prediction to that time
    np.testing.assert_allclose(gated.position[:100], clean.position, atol=1e-12)
    assert np.linalg.norm(gated.position[100] - zp[100]) < 0.05
    assert np.linalg.norm(plain.position[100] - zp[100]) > 0.05  # without the gate: pulled
    assert np.all(plain.status[1:] == int(FilterStatus.ACCEPTED))
    assert gated.restarts == plain.restarts == 1
