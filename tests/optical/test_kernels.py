"""The guided-step kernels (compiled under the numba backend) agree with the NumPy reference
implementations."""

from __future__ import annotations

import numpy as np

from trackflow.math import kernels_for
from trackflow.optical import _kernels, ring_rig
from trackflow.optical._kernels import pack_cameras
from trackflow.optical.triangulation import refine_points


def test_assignment_and_refinement_match_numpy():
    rng = np.random.default_rng(4)
    rig = ring_rig(4)
    X = rng.uniform([-0.5, -0.5, 0.5], [0.5, 0.5, 1.5], (30, 3))
    uv = rig.project(X) + rng.normal(0, 0.1, (4, 30, 2))
    blobs = [np.concatenate([u, rng.uniform(0, 1000, (5, 2))]) for u in uv]
    start = np.concatenate([[0], np.cumsum([len(b) for b in blobs])]).astype(np.int64)
    P, R, t = pack_cameras(rig)
    C = np.broadcast_to(np.eye(3) * 1e-8, (30, 3, 3)).copy()
    obs, claim = kernels_for(_kernels).guided_assign(
        P, R, t, X, C, np.concatenate(blobs), start, 0.01, 18.4
    )
    np.testing.assert_array_equal(obs, uv)  # every marker finds its own blob
    for c in range(4):
        np.testing.assert_array_equal(claim[start[c] : start[c] + 30], np.arange(30))
        assert np.all(claim[start[c] + 30 : start[c + 1]] == -1)
    X0 = X + rng.normal(0, 1e-4, X.shape)
    mask = np.ones((4, 30), bool)
    mask[2:, :5] = False
    obs[~mask] = np.nan
    Xk, cov, chi2, nv = kernels_for(_kernels).refine_points_packed(P, R, t, X0, obs, 0.01, 3)
    ref = refine_points(rig, X0, obs, mask, 0.1, iterations=3)
    np.testing.assert_allclose(Xk, ref.X, atol=1e-12)
    np.testing.assert_allclose(cov, ref.covariance, rtol=1e-8)
    np.testing.assert_allclose(chi2, ref.chi2, rtol=1e-6, atol=1e-12)
    np.testing.assert_array_equal(nv, ref.n_views)


def test_ambiguous_blobs_are_left_out():
    rig = ring_rig(2)
    P, R, t = pack_cameras(rig)
    X = np.array([[0.0, 0.0, 1.0], [0.3, 0.0, 1.0]])
    uv = rig.project(X)
    # camera 0: two blobs in marker 0's gate; camera 1: one blob in both markers' gates
    b0 = np.array([uv[0, 0] + [0.05, 0], uv[0, 0] - [0.05, 0], uv[0, 1]])
    b1 = np.array([uv[1, 0]])
    C = np.broadcast_to(np.eye(3) * 1e-8, (2, 3, 3)).copy()
    Xs = np.array([X[0], X[0] + [1e-5, 0, 0]])  # both predictions at one place in camera 1
    obs, claim = kernels_for(_kernels).guided_assign(
        P, R, t, Xs, C, np.concatenate([b0, b1]), np.array([0, 3, 4]), 0.01, 18.4
    )
    assert np.all(np.isnan(obs[1]))  # the shared blob is not given to either marker
    assert claim[3] == -1
