"""Pinhole camera and point / line-segment features: Jacobians vs finite differences,
segment covariances vs Monte Carlo, input validation."""

from __future__ import annotations

import numpy as np
import pytest

import trackflow.filters.quaternion_space.camera_features as cf
from trackflow import Pose
from trackflow.math import quat_exp, quat_multiply, quat_normalize


def _camera(rng) -> cf.PinholeCamera:
    pose = Pose(rng.normal(0, 0.1, 3), quat_exp(rng.normal(0, 0.1, 3)))
    return cf.PinholeCamera(700.0, 690.0, 320.0, 240.0, 640, 480, pose)


def _fd(f, x, eps=1e-6):
    cols = []
    for i in range(x.size):
        d = np.zeros_like(x)
        d[i] = eps
        cols.append((f(x + d) - f(x - d)) / (2 * eps))
    return np.stack(cols, axis=-1)


def test_from_sensor_gives_paper_camera():
    cam = cf.PinholeCamera.from_sensor(10.0, 8.8, 6.6, 640, 480)
    # 8.8 mm over 640 px and 6.6 mm over 480 px are the same 13.75 um pixel pitch.
    assert cam.fx == pytest.approx(10.0 / 0.01375)
    assert cam.fy == pytest.approx(cam.fx)
    assert (cam.cx, cam.cy) == (320.0, 240.0)


def test_project_matches_matrix_model_and_jacobian(rng):
    cam = _camera(rng)
    x_w = np.array([0.2, -0.1, 2.5])
    uv, J = cam.project(x_w)
    T_c_w = cam.pose.inverse().as_matrix()
    xc = T_c_w[:3, :3] @ x_w + T_c_w[:3, 3]
    K = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]])
    h = K @ xc
    np.testing.assert_allclose(uv, h[:2] / h[2], rtol=1e-12)
    J_fd = _fd(lambda x: cam.project(x)[0], x_w)
    np.testing.assert_allclose(J, J_fd, rtol=1e-6, atol=1e-6)


def test_segment_parameters_jacobian():
    a = np.array([100.0, 200.0])
    b = np.array([180.0, 150.0])
    y, J = cf.segment_parameters(a, b)
    np.testing.assert_allclose(y[:2], [140.0, 175.0])
    assert y[2] == pytest.approx(np.arctan2(-50.0, 80.0))
    J_fd = _fd(lambda x: cf.segment_parameters(x[:2], x[2:])[0], np.concatenate([a, b]))
    np.testing.assert_allclose(J, J_fd, rtol=1e-7, atol=1e-10)


def test_segment_covariance_matches_monte_carlo(rng):
    a = np.array([100.0, 200.0])
    b = np.array([220.0, 140.0])
    cov_e = cf.anisotropic_endpoint_covariance(a, b, 7.0, 1.0)
    # Along the segment the variance is 49, across it 1.
    t = (b - a) / np.linalg.norm(b - a)
    n = np.array([-t[1], t[0]])
    assert t @ cov_e @ t == pytest.approx(49.0)
    assert n @ cov_e @ n == pytest.approx(1.0)
    assert t @ cov_e @ n == pytest.approx(0.0, abs=1e-12)
    C = cf.segment_covariance(a, b, cov_e, cov_e)
    L = np.linalg.cholesky(cov_e)
    m = 200_000
    ea = a + rng.standard_normal((m, 2)) @ L.T
    eb = b + rng.standard_normal((m, 2)) @ L.T
    y, _ = cf.segment_parameters(ea, eb)
    C_mc = np.cov(y.T)
    # Mid-point: independent of the linearisation; angle: first order, small (1/134 rad).
    np.testing.assert_allclose(C_mc[:2, :2], C[:2, :2], rtol=0.02, atol=0.02)
    assert C_mc[2, 2] == pytest.approx(C[2, 2], rel=0.05)
    # Closed form of the reduced mid-point covariance for equal end-point covariances.
    np.testing.assert_allclose(C[:2, :2], cov_e / 2.0, rtol=1e-12)
    assert C[2, 2] == pytest.approx(2.0 / np.sum((b - a) ** 2), rel=1e-12)


def _observation(rng, cam):
    pts = rng.uniform(-0.3, 0.3, (4, 3))
    segs = rng.uniform(-0.3, 0.3, (3, 2, 3))
    pc = np.array([np.diag([1.0, 2.0])] * 4)
    sc = np.array([np.diag([4.0, 1.0, 1e-4])] * 3)
    return cf.CameraObservation(
        cam,
        point_model=pts,
        point_meas=np.full((4, 2), 300.0),
        point_cov=pc,
        segment_model=segs,
        segment_meas=np.tile([300.0, 200.0, 0.3], (3, 1)),
        segment_cov=sc,
    )


def test_feature_pose_jacobian_vs_finite_differences(rng):
    cam = _camera(rng)
    obs = _observation(rng, cam)
    p = np.array([0.1, 0.05, 3.0])
    q = quat_normalize(rng.normal(size=4))

    def g(delta):
        return obs.predict(p + delta[:3], quat_multiply(quat_exp(delta[3:]), q))[0]

    y, J = obs.predict(p, q)
    assert y.shape == (obs.size,) == (4 * 2 + 3 * 3,)
    J_fd = _fd(g, np.zeros(6))
    np.testing.assert_allclose(J, J_fd, rtol=1e-5, atol=1e-5 * np.abs(J).max())

    def h(delta):
        return obs.whitened_residual(p + delta[:3], quat_multiply(quat_exp(delta[3:]), q))[0]

    _, Jh = obs.whitened_residual(p, q)
    np.testing.assert_allclose(Jh, _fd(h, np.zeros(6)), rtol=1e-5, atol=1e-5 * np.abs(Jh).max())


def test_whitened_residual_is_zero_on_truth_and_ignores_endpoint_order(rng):
    cam = _camera(rng)
    p = np.array([0.0, 0.0, 3.0])
    q = quat_exp(np.array([0.1, 0.2, 0.3]))
    segs = rng.uniform(-0.3, 0.3, (3, 2, 3))
    probe = cf.CameraObservation(
        cam,
        segment_model=segs,
        segment_meas=np.zeros((3, 3)),
        segment_cov=np.tile(np.eye(3), (3, 1, 1)),
    )
    y, _ = probe.predict(p, q)
    y = y.reshape(3, 3)
    flipped = y.copy()
    flipped[:, 2] = flipped[:, 2] + np.pi  # same segment, end-points swapped
    for meas in (y, flipped):
        obs = cf.CameraObservation(
            cam, segment_model=segs, segment_meas=meas, segment_cov=np.tile(np.eye(3), (3, 1, 1))
        )
        h, _ = obs.whitened_residual(p, q)
        np.testing.assert_allclose(h, 0.0, atol=1e-9)


def test_whitening_uses_feature_covariance(rng):
    cam = cf.PinholeCamera(700.0, 700.0, 320.0, 240.0, 640, 480)
    cov = np.array([[4.0, 1.0], [1.0, 9.0]])
    obs = cf.CameraObservation(
        cam,
        point_model=np.zeros((1, 3)),
        point_meas=np.array([[330.0, 250.0]]),
        point_cov=cov[None],
    )
    h, _ = obs.whitened_residual(np.array([0.0, 0.0, 2.0]), np.array([0.0, 0, 0, 1]))
    r = np.array([320.0 - 330.0, 240.0 - 250.0])
    assert h @ h == pytest.approx(r @ np.linalg.solve(cov, r))


def test_bad_input_raises():
    cam = cf.PinholeCamera(700.0, 700.0, 320.0, 240.0, 640, 480)
    with pytest.raises(ValueError, match="in front"):
        cam.project(np.array([0.0, 0.0, -1.0]))
    with pytest.raises(ValueError, match="positive focal"):
        cf.PinholeCamera(-1.0, 700.0, 320.0, 240.0, 640, 480)
    with pytest.raises(ValueError, match="not positive definite"):
        cf.CameraObservation(
            cam,
            point_model=np.zeros((1, 3)),
            point_meas=np.zeros((1, 2)),
            point_cov=np.array([[[1.0, 2.0], [2.0, 1.0]]]),
        )
    with pytest.raises(ValueError, match="counts differ"):
        cf.CameraObservation(
            cam,
            point_model=np.zeros((2, 3)),
            point_meas=np.zeros((1, 2)),
            point_cov=np.zeros((1, 2, 2)) + np.eye(2),
        )
    with pytest.raises(ValueError, match="zero length"):
        cf.segment_parameters(np.ones(2), np.ones(2))
    with pytest.raises(ValueError, match="NaN"):
        cf.CameraObservation(
            cam,
            point_model=np.full((1, 3), np.nan),
            point_meas=np.zeros((1, 2)),
            point_cov=np.eye(2)[None],
        )
