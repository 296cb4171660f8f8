"""Camera model: projection against OpenCV, Jacobians against finite differences, undistortion."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.optical import Camera, CameraRig, ring_rig

cv2 = pytest.importorskip("cv2", reason="opencv-python-headless (dev extra) is the reference")

DISTS = [
    (-0.12, 0.08, 0.0005, -0.0003),
    (-0.12, 0.08, 0.0005, -0.0003, -0.01),
    (0.3, -0.1, 0.001, 0.002, 0.02, 0.35, -0.05, 0.01),
]


def _camera(dist, skew=0.0) -> Camera:
    K = np.array([[1180.0, skew, 640.3], [0.0, 1195.0, 505.1], [0.0, 0.0, 1.0]])
    return Camera.looking_at(K, dist, (1280, 1024), (2.0, -1.5, 2.2), (0.1, 0.2, 0.9))


def _points(rng, n=200):
    return rng.uniform([-0.8, -0.8, 0.2], [0.8, 0.8, 1.8], (n, 3))


@pytest.mark.parametrize("dist", DISTS)
def test_projection_matches_opencv(dist):
    cam = _camera(dist)
    X = _points(np.random.default_rng(1))
    rvec, _ = cv2.Rodrigues(cam.R_cam_world)
    ref, _ = cv2.projectPoints(X, rvec, cam.t_cam_world, cam.K, np.asarray(dist))
    np.testing.assert_allclose(cam.project(X), ref[:, 0], atol=1e-9)


@pytest.mark.parametrize("dist", DISTS)
def test_projection_jacobian_matches_finite_differences(dist):
    cam = _camera(dist, skew=0.7)
    X = _points(np.random.default_rng(2), 30)
    _, J = cam.project(X, jacobian=True)
    h = 1e-6
    J_fd = np.stack(
        [(cam.project(X + h * e) - cam.project(X - h * e)) / (2 * h) for e in np.eye(3)], axis=-1
    )
    np.testing.assert_allclose(J, J_fd, rtol=1e-6, atol=1e-3)


@pytest.mark.parametrize("dist", DISTS)
def test_normalize_inverts_distortion_like_opencv(dist):
    cam = _camera(dist)
    rng = np.random.default_rng(3)
    uv = rng.uniform([0, 0], [1279, 1023], (300, 2))
    xn = cam.normalize(uv)
    ref = cv2.undistortPointsIter(
        uv[:, None],
        cam.K,
        np.asarray(dist),
        None,
        None,
        (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-14),
    )[:, 0]
    ok = np.all(np.isfinite(xn), axis=1)
    assert ok.mean() > 0.95
    np.testing.assert_allclose(xn[ok], ref[ok], atol=1e-7)
    # round trip through the projection
    rays = np.concatenate([xn[ok], np.ones((ok.sum(), 1))], axis=1)
    X = (rays - cam.t_cam_world) @ cam.R_cam_world  # points on the rays (z_cam = 1)
    np.testing.assert_allclose(cam.project(X), uv[ok], atol=1e-6)


def test_points_behind_the_camera_are_nan_and_outside_the_image():
    cam = _camera(DISTS[1])
    behind = cam.center + 2.0 * (cam.center - np.array([0.1, 0.2, 0.9]))
    uv = cam.project(behind[None])
    assert np.all(np.isnan(uv))
    assert not cam.in_image(uv)[0]


def test_pose_of_the_camera_is_the_inverse_extrinsics():
    cam = _camera(DISTS[0])
    X = _points(np.random.default_rng(4), 5)
    Xc = X @ cam.R_cam_world.T + cam.t_cam_world
    np.testing.assert_allclose(cam.T_world_cam.transform_points(Xc), X, atol=1e-12)


def test_ring_rig_sees_the_volume():
    rig = ring_rig()
    X = np.array([[0.0, 0.0, 1.0], [0.5, -0.5, 1.5]])
    assert rig.visible(X).all()
    uv, J = rig.project(X, jacobian=True)
    assert uv.shape == (4, 2, 2) and J.shape == (4, 2, 2, 3)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"K": np.eye(2)}, "K must be"),
        ({"K": np.diag([-1.0, 1.0, 1.0])}, "upper triangular"),
        ({"dist": [0.1, 0.2, 0.3]}, "4, 5 or 8"),
        ({"dist": [0.1, np.nan, 0, 0]}, "4, 5 or 8"),
        ({"R_cam_world": np.diag([1.0, 1.0, -1.0])}, "not a rotation"),
        ({"size": (0, 480)}, "image size"),
        ({"t_cam_world": [0, 0]}, "t must be"),
    ],
)
def test_bad_camera_parameters_are_rejected(kwargs, match):
    args = {
        "K": np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]),
        "dist": [0, 0, 0, 0],
        "size": (640, 480),
        "R_cam_world": np.eye(3),
        "t_cam_world": np.zeros(3),
    } | kwargs
    with pytest.raises(ValueError, match=match):
        Camera(**args)


def test_rig_rejects_duplicate_names_and_bad_shapes():
    cam = _camera(DISTS[0])
    with pytest.raises(ValueError, match="unique"):
        CameraRig([cam, cam])
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        cam.project(np.zeros((4, 2)))
