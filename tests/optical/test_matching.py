"""Epipolar correspondence and identification of bodies among ghosts, with and without the
filter's prediction."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow import Pose, UncertainPose
from trackflow.math import quat_exp
from trackflow.optical import ring_rig
from trackflow.optical.correspondence import match_epipolar
from trackflow.optical.matching import identify, pose_nis
from trackflow.optical.models import MarkerModel, model_separation, random_model, similar_model

POSES = {
    "A": Pose([0.4, 0.0, 1.0], quat_exp(np.array([0.3, 0.2, 1.0]))),
    "B": Pose([-0.3, 0.3, 1.2], quat_exp(np.array([-0.3, 0.5, 2.0]))),
    "C": Pose([-0.1, -0.4, 0.8], quat_exp(np.array([1.0, 0.2, 0.1]))),
}


def _models(seed=0, n=12):
    rng = np.random.default_rng(seed)
    a = random_model("A", n, rng)
    return [a, similar_model(a, "B", rng, n_moved=2, shift=0.02), random_model("C", n, rng)]


def _blobs(rig, X, rng, sigma=0.1, ghosts=4):
    uv = rig.project(X)
    out = []
    for c, cam in enumerate(rig):
        b = uv[c] + rng.normal(0, sigma, uv[c].shape)
        b = b[cam.in_image(b)]
        b = np.concatenate([b, rng.uniform([0, 0], cam.size, (ghosts, 2))])
        out.append(b[rng.permutation(len(b))])
    return out


def test_similar_model_is_separated_by_its_moved_markers():
    a, b, c = _models()
    assert model_separation(a, a) == 0.0
    assert 0.005 < model_separation(b, a) <= 0.05
    assert model_separation(c, a) > model_separation(b, a) * 0.5


def test_bodies_are_found_among_ghosts_and_mirror_images():
    rng = np.random.default_rng(1)
    rig = ring_rig(4)
    models = _models()
    X = [POSES[m.name].transform_points(m.points) for m in models]
    keep = [rng.random(len(x)) > 0.15 for x in X]  # missing markers
    pts = np.concatenate([x[k] for x, k in zip(X, keep)])
    mirror = pts * np.array([-1.0, 1.0, 1.0]) + np.array([-3.0, 0, 0])  # reflected in x = -1.5
    cand = match_epipolar(rig, _blobs(rig, np.concatenate([pts, mirror]), rng), sigma_px=0.1)
    found = identify(cand, models)
    assert set(found) == {"A", "B", "C"}
    for name, m in found.items():
        err = np.linalg.norm(m.fit.pose.position - POSES[name].position)
        assert err < 1e-3
        # every matched point is a true marker of that body
        truth = POSES[name].transform_points(m.model.points)
        used = m.points >= 0
        assert np.all(np.linalg.norm(cand.X[m.points[used]] - truth[used], axis=1) < 2e-3)


def test_similar_bodies_without_their_distinguishing_markers_need_the_prediction():
    rng = np.random.default_rng(2)
    rig = ring_rig(4)
    a, b, _ = _models()
    moved = np.flatnonzero(np.linalg.norm(a.points - b.points, axis=1) > 1e-9)
    common = np.setdiff1d(np.arange(len(a)), moved)
    # only B is in view, and only with the markers it shares with A
    X = POSES["B"].transform_points(b.points[common])
    cand = match_epipolar(rig, _blobs(rig, X, rng, ghosts=0), sigma_px=0.1)
    assert identify(cand, [a, b]) == {}  # ambiguous: no identity is guessed
    C = np.diag([1e-6] * 3 + [1e-4] * 3)
    far = Pose(POSES["B"].position + [0.5, 0, 0], POSES["B"].quaternion)
    preds = {"B": UncertainPose(POSES["B"], C), "A": UncertainPose(far, C)}
    found = identify(cand, [a, b], predictions=preds)
    assert set(found) == {"B"}
    assert pose_nis(preds["B"], found["B"].fit.pose) < 20


def test_two_view_points_on_one_epipolar_line_are_returned_as_alternatives():
    rig = ring_rig(2, radius=2.0)
    a = rig[0]
    # two points on one ray of camera a: their images in a coincide, in b they differ
    ray = a.rays(np.array([[640.0, 512.0]]))[0]
    X = a.center + np.outer([2.4, 2.9], ray)
    uv = rig.project(X)
    blobs = [uv[0][:1], uv[1]]  # camera a sees one merged blob
    cand = match_epipolar(rig, blobs, sigma_px=0.1)
    assert len(cand) == 2 and np.all(cand.group == cand.group[0]) and cand.group[0] >= 0
    d = np.linalg.norm(cand.X[:, None] - X[None], axis=-1).min(axis=1)
    assert np.all(d < 1e-6)


def test_bad_input():
    rig = ring_rig(2)
    with pytest.raises(ValueError, match="one blob array per camera"):
        match_epipolar(rig, [np.zeros((0, 2))])
    a, b, _ = _models()
    cand = match_epipolar(rig, [np.zeros((0, 2)), np.zeros((0, 2))])
    assert len(cand) == 0 and identify(cand, [a]) == {}
    with pytest.raises(ValueError, match="unique"):
        identify(cand, [a, a])
    with pytest.raises(ValueError, match="unknown models"):
        identify(cand, [a], predictions={"Z": UncertainPose(Pose.identity(), np.eye(6))})
    with pytest.raises(ValueError, match="collinear"):
        MarkerModel("L", [[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0]])
    with pytest.raises(ValueError, match="closer than the marker diameter"):
        MarkerModel("D", [[0, 0, 0], [0.005, 0, 0], [0, 0.1, 0]])
    with pytest.raises(ValueError, match="markers_mm or markers_m"):
        MarkerModel.from_dict({"name": "X"})
