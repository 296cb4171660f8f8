"""Absolute orientation: closed form, Gauss-Newton, 6x6 covariance against seeded Monte Carlo."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from trackflow import Pose
from trackflow.math import (
    quat_conjugate,
    quat_exp,
    quat_log,
    quat_multiply,
    quat_to_matrix,
    umeyama,
)
from trackflow.optical import fit_pose


def _body(rng, m=6):
    return rng.uniform(-0.08, 0.08, (m, 3))


def _truth():
    return Pose([0.3, -0.2, 1.1], quat_exp(np.array([0.4, -1.0, 0.7])))


def _error(est: Pose, true: Pose) -> np.ndarray:
    """(dt, dtheta) with t_true = t + dt, R_true = R Exp(dtheta)."""
    dq = quat_multiply(quat_conjugate(est.quaternion), true.quaternion)
    return np.concatenate([true.position - est.position, quat_log(dq)], axis=-1)


def test_umeyama_recovers_an_exact_pose():
    rng = np.random.default_rng(0)
    m = _body(rng)
    T = _truth()
    fit = umeyama(T.transform_points(m), m)
    R, t = fit.rotation, fit.translation
    np.testing.assert_allclose(R, T.rotation_matrix, atol=1e-12)
    np.testing.assert_allclose(t, T.position, atol=1e-12)


def test_umeyama_never_returns_a_reflection():
    rng = np.random.default_rng(1)
    m = _body(rng, 4)
    mirrored = m * np.array([1.0, 1.0, -1.0])
    R = umeyama(mirrored, m).rotation
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_covariance_matches_monte_carlo_with_anisotropic_points():
    rng = np.random.default_rng(2)
    m = _body(rng, 5)
    T = _truth()
    x = T.transform_points(m)
    # elongated point covariances (depth-like), different per point
    C = np.empty((len(m), 3, 3))
    for i in range(len(m)):
        A = rng.normal(size=(3, 3))
        Q, _ = np.linalg.qr(A)
        C[i] = Q @ np.diag([0.2e-3, 0.2e-3, 1.0e-3]) ** 2 @ Q.T
    ref = fit_pose(m, x, C)
    np.testing.assert_allclose(ref.pose.position, T.position, atol=1e-12)
    n = 1200
    L = np.linalg.cholesky(C)
    errs = np.empty((n, 6))
    chis = np.empty(n)
    for k in range(n):
        noisy = x + np.einsum("mij,mj->mi", L, rng.normal(size=(len(m), 3)))
        fit = fit_pose(m, noisy, C)
        errs[k] = _error(fit.pose.pose, T)
        chis[k] = fit.chi2
    P = ref.pose.covariance
    C_mc = np.cov(errs.T)
    # compare in the whitened space: the MC covariance should be the identity (6x6)
    Li = np.linalg.inv(np.linalg.cholesky(P))
    W = Li @ C_mc @ Li.T
    assert np.abs(W - np.eye(6)).max() < 0.15
    nees = np.einsum("ni,ij,nj->n", errs, np.linalg.inv(P), errs)
    assert chi2.ppf(0.001, 6 * n) / n < nees.mean() < chi2.ppf(0.999, 6 * n) / n
    dof = 3 * len(m) - 6
    assert chi2.ppf(0.001, dof * n) / n < chis.mean() < chi2.ppf(0.999, dof * n) / n


def test_rotation_error_is_on_the_right():
    """A marker far out on the body's x axis pins rotation about the body's y/z axes; with the
    error on the right the covariance is small in those body axes whatever R is."""
    m = np.array([[0.0, 0, 0], [0.5, 0, 0], [0, 0.02, 0], [0, 0, 0.02]])
    C = np.broadcast_to(np.eye(3) * 1e-8, (4, 3, 3))
    for q in (np.array([0, 0, 0, 1.0]), quat_exp(np.array([0.3, 1.2, -0.4]))):
        T = Pose([0, 0, 1.0], q)
        P = fit_pose(m, T.transform_points(m), C).pose.covariance
        assert P[4, 4] < 0.1 * P[3, 3] and P[5, 5] < 0.1 * P[3, 3]


def test_bad_input():
    m = np.zeros((3, 3))
    with pytest.raises(ValueError, match="collinear"):
        line = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]])
        umeyama(line, line)
    with pytest.raises(ValueError, match="M >= 3"):
        umeyama(m[:2], m[:2])
    with pytest.raises(ValueError, match="must agree"):
        fit_pose(m, m, np.eye(3))
    with pytest.raises(ValueError, match="finite"):
        fit_pose(m + np.nan, m, np.broadcast_to(np.eye(3), (3, 3, 3)))
    assert quat_to_matrix(np.array([0, 0, 0, 1.0])).shape == (3, 3)
