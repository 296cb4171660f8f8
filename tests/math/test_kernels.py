"""The compiled (numba) and reference (NumPy) backends compute the same composition."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from trackflow import Pose, UncertainPose
from trackflow.math import get_backend, numba_available, set_backend, use_backend

needs_numba = pytest.mark.skipif(not numba_available(), reason="numba is not installed")


def _covs(rng, shape) -> np.ndarray:
    a = rng.normal(size=tuple(shape) + (6, 6))
    c = a @ np.swapaxes(a, -1, -2)
    s = np.array([1e-3] * 3 + [1e-2] * 3)
    return c * s[:, None] * s[None, :]


def _uncertain(rng, shape) -> UncertainPose:
    n = int(np.prod(shape))
    q = Rotation.random(n, random_state=rng).as_quat().reshape(tuple(shape) + (4,))
    p = rng.normal(size=tuple(shape) + (3,))
    return UncertainPose(Pose(p, q), _covs(rng, shape))


def _both(a, b, cross=None):
    out = {}
    for name in ("numpy", "numba"):
        with use_backend(name):
            c, J_c_a, J_c_b = a.compose(b, jacobians=True, cross_covariance=cross)
        out[name] = (c.position, c.quaternion, c.covariance, J_c_a, J_c_b)
    return out["numpy"], out["numba"]


def _assert_agree(ref, fast, shape):
    names = ("position", "quaternion", "covariance", "J_c_a", "J_c_b")
    for name, x, y in zip(names, ref, fast, strict=True):
        assert np.shape(x)[: len(shape)] == shape, name
        assert np.shape(x) == np.shape(y), name
        scale = max(1.0, float(np.max(np.abs(x))))
        np.testing.assert_allclose(y, x, rtol=0, atol=1e-12 * scale, err_msg=name)
    np.testing.assert_array_equal(fast[2], np.swapaxes(fast[2], -1, -2))


@needs_numba
def test_single(rng):
    a, b = _uncertain(rng, (1,))[0], _uncertain(rng, (1,))[0]
    ref, fast = _both(a, b)
    _assert_agree(ref, fast, ())


@needs_numba
@pytest.mark.parametrize("shape", [(1,), (50,), (3, 4)])
def test_batched(rng, shape):
    a, b = _uncertain(rng, shape), _uncertain(rng, shape)
    ref, fast = _both(a, b)
    _assert_agree(ref, fast, shape)


@needs_numba
def test_broadcast_one_vs_many(rng):
    one = _uncertain(rng, (1,))[0]
    many = _uncertain(rng, (20,))
    for a, b in ((one, many), (many, one)):
        ref, fast = _both(a, b)
        _assert_agree(ref, fast, (20,))
    # outer product through a singleton axis
    col = _uncertain(rng, (4, 1))
    row = _uncertain(rng, (5,))
    ref, fast = _both(col, row)
    _assert_agree(ref, fast, (4, 5))
    # a plain Pose (exact) on either side
    ref, fast = _both(many, Pose.identity())
    _assert_agree(ref, fast, (20,))


@needs_numba
@pytest.mark.parametrize("shape", [(), (30,)])
def test_cross_covariance(rng, shape):
    # a joint covariance of (e_a, e_b) so that the cross block is consistent
    n = int(np.prod(shape)) if shape else 1
    a = _uncertain(rng, (n,))
    b = _uncertain(rng, (n,))
    g = rng.normal(size=(n, 12, 12)) * 1e-2
    joint = g @ np.swapaxes(g, -1, -2)
    a = UncertainPose(a.pose, joint[:, :6, :6])
    b = UncertainPose(b.pose, joint[:, 6:, 6:])
    cross = joint[:, :6, 6:]
    if not shape:
        a, b, cross = a[0], b[0], cross[0]
    ref, fast = _both(a, b, cross)
    _assert_agree(ref, fast, shape)
    # the cross term matters: dropping it changes the result
    with use_backend("numba"):
        independent = a.compose(b).covariance
    assert np.max(np.abs(independent - fast[2])) > 1e-6
    # the cross-covariance may be a single matrix broadcast against a batch
    if shape:
        ref, fast = _both(a, b, cross[0])
        _assert_agree(ref, fast, shape)


@needs_numba
def test_use_backend_restores_previous():
    start = get_backend()
    with use_backend("numpy"):
        assert get_backend() == "numpy"
        with use_backend("numba"):
            assert get_backend() == "numba"
        assert get_backend() == "numpy"
    assert get_backend() == start
    # restored after an exception inside the block
    with pytest.raises(RuntimeError), use_backend("numpy" if start == "numba" else "numba"):
        raise RuntimeError("boom")
    assert get_backend() == start


def test_bad_backend_name():
    start = get_backend()
    with pytest.raises(ValueError, match=r"unknown backend 'cuda'"):
        set_backend("cuda")
    with pytest.raises(ValueError, match="unknown backend"), use_backend("Numba "):
        pass
    assert get_backend() == start


@needs_numba
def test_compose_compiles_one_batch_specialisation(rng):
    from trackflow.math import _kernels
    from trackflow.math._backend import kernels

    a, many = _uncertain(rng, (1,))[0], _uncertain(rng, (8,))
    g = rng.normal(size=(8, 12, 12)) * 1e-2
    cross = (g @ np.swapaxes(g, -1, -2))[:, :6, 6:]
    with use_backend("numba"):
        a @ many  # one side broadcast (a copy), the other exact shape (a read-only view)
        many @ a
        many @ many
        many.compose(many, cross_covariance=cross)
        many.compose(many, cross_covariance=cross[0])
    assert len(kernels(_kernels).compose_batch.signatures) == 1


@needs_numba
@pytest.mark.parametrize("name", ["kernels", "motion_kernels", "update_kernels"])
def test_kernels_named_for_inlining_are_kernels_and_compile_inlined(name):
    """A name in a source's ``KERNELS_INLINE`` that is not one of its ``KERNELS`` would
    silently inline nothing; the compiled copy marks the named ones, and only them."""
    import importlib

    from trackflow.math import kernels_for

    source = importlib.import_module(f"trackflow.filters.derivative.{name}")

    inline = set(source.KERNELS_INLINE)
    assert inline and inline <= set(source.KERNELS)
    with use_backend("numba"):
        compiled = kernels_for(source)
    for name in source.KERNELS:
        expected = "always" if name in inline else "never"
        assert getattr(compiled, name).targetoptions.get("inline", "never") == expected, name
