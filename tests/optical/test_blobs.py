"""Blob detection: against scipy.ndimage / OpenCV, sub-pixel accuracy, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from trackflow.optical.blobs import detect_blobs
from trackflow.optical.render import FrameRenderer, RenderSettings


def _image(rng, shape=(120, 157), n=25):
    img = rng.integers(0, 10, shape).astype(np.uint8)
    for _ in range(n):
        y, x = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        h, w = rng.integers(1, 6, 2)
        img[y : y + h, x : x + w] = rng.integers(
            30, 255, (min(h, shape[0] - y), min(w, shape[1] - x))
        )
    return img


@pytest.mark.parametrize("seed", range(5))
def test_same_components_and_centroids_as_scipy(seed):
    img = _image(np.random.default_rng(seed))
    mine = detect_blobs(img, 20, background=5)
    lab, n = ndimage.label(img >= 20, structure=np.ones((3, 3)))
    w = np.where(lab > 0, img.astype(float) - 5, 0.0)
    ref = np.array(ndimage.center_of_mass(w, lab, range(1, n + 1)))[:, ::-1]
    area = ndimage.sum(np.ones_like(lab), lab, range(1, n + 1))
    assert len(mine) == n
    o1, o2 = np.lexsort(mine.uv.T[::-1]), np.lexsort(ref.T[::-1])
    np.testing.assert_allclose(mine.uv[o1], ref[o2], atol=1e-9)
    np.testing.assert_array_equal(np.sort(mine.area), np.sort(area.astype(int)))


def test_same_components_as_opencv():
    cv2 = pytest.importorskip("cv2", reason="opencv-python-headless (dev extra) is the reference")
    img = _image(np.random.default_rng(9), (480, 640), 200)
    mine = detect_blobs(img, 20, background=19.999)  # nearly unweighted
    n, _, stats, cent = cv2.connectedComponentsWithStats(
        (img >= 20).astype(np.uint8), connectivity=8
    )
    assert len(mine) == n - 1
    np.testing.assert_array_equal(np.sort(mine.area), np.sort(stats[1:, cv2.CC_STAT_AREA]))


def test_rendered_blob_centroids_are_subpixel_accurate():
    from trackflow.optical import ring_rig
    from trackflow.optical.models import random_model

    rig = ring_rig(1)
    m = random_model("M", 8, np.random.default_rng(0))
    from trackflow import Pose

    s = RenderSettings(sigma_px=0.0, mirror=None, static_ghosts=0, flicker_ghosts=0.0, dropout=0)
    r = FrameRenderer(rig, [m], {"M": lambda t: Pose([0, 0, 1.0], [0, 0, 0, 1.0])}, s, seed=3)
    fr = r.render(0.0)
    b = detect_blobs(fr.images[0], 20, 6)
    d = np.linalg.norm(b.uv[:, None] - fr.blob_uv[0][None], axis=-1).min(axis=1)
    assert len(b) == len(fr.blob_uv[0]) and np.all(d < 0.1)


def test_bad_images_and_thresholds():
    img = np.zeros((4, 4), np.uint8)
    with pytest.raises(ValueError, match="2-D"):
        detect_blobs(np.zeros((2, 2, 3)), 10)
    with pytest.raises(ValueError, match="below threshold"):
        detect_blobs(img, 10, background=10)
    with pytest.raises(ValueError, match="outside the range"):
        detect_blobs(img, 300)
    with pytest.raises(ValueError, match="numeric"):
        detect_blobs(np.zeros((2, 2), dtype=object), 10)
    with pytest.raises(ValueError, match="overexposed"):
        detect_blobs(np.tile(np.array([255, 0], np.uint8), (50, 50)), 10, max_runs=100)
    assert len(detect_blobs(img, 10)) == 0


@settings(max_examples=40, deadline=None)
@given(
    thr=st.integers(1, 255),
    width=st.sampled_from([16, 32, 48, 20]),
    seed=st.integers(0, 2**31),
)
def test_word_prefilter_finds_every_bright_pixel(thr, width, seed):
    """The 8-pixels-at-a-time pre-filter (widths that are multiples of 16) gives the same
    blobs as the generic path for every threshold."""
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, (9, width)).astype(np.uint8)
    a = detect_blobs(img, thr)
    b = detect_blobs(img.astype(np.uint16), thr)  # generic path
    np.testing.assert_array_equal(np.sort(a.area), np.sort(b.area))
    np.testing.assert_allclose(np.sort(a.flux), np.sort(b.flux))
