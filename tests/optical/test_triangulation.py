"""Triangulation: exactness, OpenCV agreement, covariance against seeded Monte Carlo."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from trackflow.optical import ring_rig, triangulate, triangulate_linear


def _scene(n=50, seed=0):
    rig = ring_rig(4)
    X = np.random.default_rng(seed).uniform([-0.6, -0.6, 0.4], [0.6, 0.6, 1.6], (n, 3))
    return rig, X, rig.project(X)


def test_noise_free_points_are_recovered_exactly():
    rig, X, uv = _scene()
    np.testing.assert_allclose(triangulate_linear(rig, uv), X, atol=1e-9)
    tri = triangulate(rig, uv)
    np.testing.assert_allclose(tri.X, X, atol=1e-12)
    assert tri.valid.all() and np.nanmax(tri.chi2) < 1e-12


def test_matches_opencv_linear_triangulation_for_two_views():
    cv2 = pytest.importorskip("cv2", reason="opencv-python-headless (dev extra) is the reference")
    rig, X, uv = _scene(20, seed=1)
    uv = uv + np.random.default_rng(1).normal(0, 0.3, uv.shape)
    mask = np.zeros(uv.shape[:2], bool)
    mask[:2] = True
    mine = triangulate_linear(rig, uv, mask)
    a, b = rig[0], rig[1]
    na, nb = a.normalize(uv[0]), b.normalize(uv[1])
    Pa = np.hstack([a.R_cam_world, a.t_cam_world[:, None]])
    Pb = np.hstack([b.R_cam_world, b.t_cam_world[:, None]])
    h = cv2.triangulatePoints(Pa, Pb, na.T, nb.T)
    np.testing.assert_allclose(mine, (h[:3] / h[3]).T, atol=1e-9)


def test_missing_views_and_single_views():
    rig, X, uv = _scene(10, seed=2)
    uv = uv.copy()
    uv[1:, 0] = np.nan  # point 0 seen once
    uv[2:, 1] = np.nan  # point 1 seen twice
    tri = triangulate(rig, uv)
    assert not tri.valid[0] and np.all(np.isnan(tri.X[0]))
    assert tri.valid[1:].all() and tri.n_views[1] == 2
    np.testing.assert_allclose(tri.X[1:], X[1:], atol=1e-10)


@pytest.mark.parametrize("views", [2, 4])
def test_covariance_matches_monte_carlo(views):
    rig, X, uv = _scene(3, seed=3)
    rng = np.random.default_rng(33)
    sigma, n = 0.1, 3000
    mask = np.zeros(uv.shape[:2], bool)
    mask[:views] = True
    ref = triangulate(rig, uv, mask, sigma_px=sigma)
    noisy = uv[None] + rng.normal(0, sigma, (n,) + uv.shape)
    # one batched call: stack the trials as points
    flat = np.moveaxis(noisy, 0, 2).reshape(len(rig), -1, 2)
    tri = triangulate(rig, flat, np.repeat(mask, n, axis=1), sigma_px=sigma)
    est = tri.X.reshape(3, n, 3)
    for i in range(3):
        err = est[i] - X[i]
        C_mc = np.cov(err.T)
        C = ref.covariance[i]
        # relative Frobenius error of 3000 samples is ~ sqrt(2/3000) ~ 3 %; allow 10 %
        assert np.linalg.norm(C_mc - C) / np.linalg.norm(C) < 0.1
        assert abs(err.mean(axis=0)).max() < 4 * np.sqrt(np.diag(C).max() / n)
        nees = np.einsum("ni,ij,nj->n", err, np.linalg.inv(C), err)
        assert chi2.ppf(0.001, 3 * n) / n < nees.mean() < chi2.ppf(0.999, 3 * n) / n
    dof = 2 * views - 3
    chi = tri.chi2.reshape(3, n)
    lo, hi = chi2.ppf([1e-5, 1 - 1e-5], dof * 3 * n) / (3 * n)
    assert lo < chi.mean() < hi


def test_bad_shapes_and_sigma():
    rig, X, uv = _scene(3)
    with pytest.raises(ValueError, match=r"\(4, N, 2\)"):
        triangulate(rig, uv[:2])
    with pytest.raises(ValueError, match="mask must have shape"):
        triangulate(rig, uv, np.ones((4, 2), bool))
    with pytest.raises(ValueError, match="sigma_px"):
        triangulate(rig, uv, sigma_px=0.0)
