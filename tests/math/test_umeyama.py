"""trackflow.math.umeyama: the one weighted point-set fit (T_a_b maps points of b onto a)."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.math import Pose, numba_available, quat_exp, quat_to_matrix, umeyama, use_backend


def _seeded(seed=0, m=12):
    rng = np.random.default_rng(seed)
    pts_b = rng.normal(size=(m, 3))
    T_a_b = Pose(rng.normal(size=3), quat_exp(rng.normal(size=3)))
    return rng, pts_b, T_a_b


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_recovers_a_seeded_transform_exactly(seed):
    rng, pts_b, T_a_b = _seeded(seed)
    pts_a = T_a_b.transform_points(pts_b)
    fit = umeyama(pts_a, pts_b)
    np.testing.assert_allclose(fit.rotation, T_a_b.rotation_matrix, rtol=0, atol=1e-13)
    np.testing.assert_allclose(fit.translation, T_a_b.position, rtol=0, atol=1e-13)
    assert fit.scale == 1.0 and fit.residual < 1e-13 and not fit.reflected
    np.testing.assert_allclose(fit.apply(pts_b), pts_a, rtol=0, atol=1e-13)
    # with a scale, and with arbitrary positive weights: the same transform
    s = np.exp(rng.normal())
    fit = umeyama(s * pts_a, pts_b, rng.uniform(0.1, 2.0, len(pts_b)), with_scale=True)
    assert fit.scale == pytest.approx(s, rel=1e-13)
    np.testing.assert_allclose(fit.rotation, T_a_b.rotation_matrix, rtol=0, atol=1e-13)
    np.testing.assert_allclose(fit.translation, s * T_a_b.position, rtol=0, atol=1e-12)


def test_reflection_gives_the_best_proper_rotation_and_says_so():
    _, pts_b, T_a_b = _seeded(3)
    mirrored = T_a_b.transform_points(pts_b * np.array([1.0, 1.0, -1.0]))
    fit = umeyama(mirrored, pts_b)
    assert fit.reflected
    assert np.linalg.det(fit.rotation) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(fit.rotation @ fit.rotation.T, np.eye(3), atol=1e-12)
    assert fit.residual > 0.1  # no proper rotation maps a mirror image
    # the same points without the mirror: no reflection
    assert not umeyama(T_a_b.transform_points(pts_b), pts_b).reflected


def test_weights_are_respected():
    rng, pts_b, T_a_b = _seeded(4)
    pts_a = T_a_b.transform_points(pts_b)
    pts_a[0] += [5.0, -3.0, 1.0]  # a gross outlier
    w = np.ones(len(pts_b))
    assert not np.allclose(umeyama(pts_a, pts_b, w).translation, T_a_b.position, atol=1e-3)
    w[0] = 0.0
    fit = umeyama(pts_a, pts_b, w)
    np.testing.assert_allclose(fit.rotation, T_a_b.rotation_matrix, rtol=0, atol=1e-13)
    np.testing.assert_allclose(fit.translation, T_a_b.position, rtol=0, atol=1e-13)
    assert fit.residual < 1e-13  # the outlier's zero weight keeps it out of the residual too
    # integer weights are the same as repeating points
    noisy = T_a_b.transform_points(pts_b) + rng.normal(0, 0.01, pts_b.shape)
    k = rng.integers(1, 4, len(pts_b))
    a, b = umeyama(noisy, pts_b, k), umeyama(np.repeat(noisy, k, 0), np.repeat(pts_b, k, 0))
    np.testing.assert_allclose(a.rotation, b.rotation, rtol=0, atol=1e-13)
    np.testing.assert_allclose(a.translation, b.translation, rtol=0, atol=1e-13)
    assert a.residual == pytest.approx(b.residual, rel=1e-12)
    r = noisy - a.apply(pts_b)
    assert a.residual == pytest.approx(np.sqrt(np.sum(k * np.sum(r * r, 1)) / k.sum()), rel=1e-12)


def test_batches_are_independent_fits():
    rng = np.random.default_rng(5)
    pts_b = rng.normal(size=(4, 6, 3))
    q = quat_exp(rng.normal(size=(4, 3)))
    pts_a = np.einsum("tij,tmj->tmi", quat_to_matrix(q), pts_b) + rng.normal(size=(4, 1, 3))
    pts_a += rng.normal(0, 0.01, pts_a.shape)
    batch = umeyama(pts_a, pts_b, with_scale=True)
    for i in range(4):
        one = umeyama(pts_a[i], pts_b[i], with_scale=True)
        np.testing.assert_allclose(batch.rotation[i], one.rotation, rtol=0, atol=1e-14)
        np.testing.assert_allclose(batch.translation[i], one.translation, rtol=0, atol=1e-14)
        assert batch.scale[i] == pytest.approx(one.scale, rel=1e-14)
        assert batch.residual[i] == pytest.approx(one.residual, rel=1e-12)


def test_rotation_only_fit_of_directions():
    rng = np.random.default_rng(6)
    v = rng.normal(size=(5, 3))
    R = quat_to_matrix(quat_exp(rng.normal(size=3)))
    fit = umeyama(v @ R.T + 3.0, v, with_translation=False)  # an offset it must not absorb
    assert fit.residual > 1.0 and np.all(fit.translation == 0.0)
    fit = umeyama(v @ R.T, v, with_translation=False)
    np.testing.assert_allclose(fit.rotation, R, rtol=0, atol=1e-13)


def test_bad_input():
    line = np.outer(np.arange(5.0), [1.0, 2.0, 0.5])
    with pytest.raises(ValueError, match="collinear"):
        umeyama(line, line)
    fit = umeyama(line, line, allow_collinear=True)  # a fit, its rotation about the line free
    np.testing.assert_allclose(fit.apply(line), line, atol=1e-12)
    with pytest.raises(ValueError, match="M >= 3"):
        umeyama(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="same shape"):
        umeyama(np.zeros((4, 3)), np.zeros((5, 3)))
    with pytest.raises(ValueError, match="weights"):
        umeyama(line, line, -np.ones(5), allow_collinear=True)


@pytest.mark.skipif(not numba_available(), reason="numba not installed")
def test_compiled_fit_equals_the_reference():
    rng, pts_b, T_a_b = _seeded(8)
    pts_a = 1.3 * T_a_b.transform_points(pts_b) + rng.normal(0, 0.01, pts_b.shape)
    w = rng.uniform(0.5, 1.5, len(pts_b))
    fits = {}
    for backend in ("numpy", "numba"):
        with use_backend(backend):
            fits[backend] = umeyama(pts_a, pts_b, w, with_scale=True)
    a, b = fits["numpy"], fits["numba"]
    np.testing.assert_allclose(a.rotation, b.rotation, rtol=0, atol=1e-14)
    np.testing.assert_allclose(a.translation, b.translation, rtol=0, atol=1e-14)
    assert a.scale == pytest.approx(b.scale, rel=1e-14)
    assert a.residual == pytest.approx(b.residual, rel=1e-12)
