"""Error-glyph geometry and the graph panel, without a browser."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackflow.math import Pose, UncertainPose, quat_exp, quat_to_matrix
from trackflow.viewer import (
    COLOURS,
    EdgeStatus,
    classify,
    orientation_glyphs,
    position_glyph,
    render_panel,
    stable_axes,
)


def _random_cov(rng, scale=1e-3):
    a = rng.normal(size=(6, 6)) * scale
    return a @ a.T + np.eye(6) * 1e-9


def test_position_glyph_reproduces_the_covariance():
    rng = np.random.default_rng(1)
    c = _random_cov(rng)
    pose = UncertainPose(Pose([0.1, 0.2, 0.3], quat_exp(np.array([0.1, -0.2, 0.3]))), c)
    for sigma in (1.0, 2.0, 3.0):
        e = position_glyph(pose, sigma)
        # axes * diag(radii^2) * axes^T == sigma^2 * position block
        rebuilt = e.axes @ np.diag(e.radii**2) @ e.axes.T
        np.testing.assert_allclose(rebuilt, sigma**2 * c[:3, :3], atol=1e-15)
        assert np.linalg.det(e.axes) == pytest.approx(1.0)
        np.testing.assert_allclose(e.center, [0.1, 0.2, 0.3])
        # the viser quaternion (w, x, y, z) is the rotation of the axes
        w, x, y, z = e.wxyz
        np.testing.assert_allclose(quat_to_matrix(np.array([x, y, z, w])), e.axes, atol=1e-12)


def test_four_times_the_covariance_doubles_every_radius():
    rng = np.random.default_rng(2)
    c = _random_cov(rng)
    pose = UncertainPose(Pose.identity(), c)
    big = UncertainPose(Pose.identity(), 4 * c)
    np.testing.assert_allclose(position_glyph(big).radii, 2 * position_glyph(pose).radii)


def test_axis_ellipsoids_are_flat_along_their_axis_and_sit_at_the_tips():
    rng = np.random.default_rng(3)
    q = quat_exp(np.array([0.4, 0.1, -0.7]))
    pose = UncertainPose(Pose([1.0, 0.0, 0.0], q), _random_cov(rng, 1e-2))
    r = quat_to_matrix(q)
    for k, e in enumerate(orientation_glyphs(pose, 2.0, length=0.2)):
        np.testing.assert_allclose(e.center, [1.0, 0.0, 0.0] + 0.2 * r[:, k], atol=1e-12)
        # the smallest semi-axis is (numerically) zero and points along body axis k
        j = int(np.argmin(e.radii))
        assert e.radii[j] < 1e-7 * e.radii.max()
        assert abs(e.axes[:, j] @ r[:, k]) == pytest.approx(1.0, abs=1e-9)


def test_axis_ellipsoid_matches_monte_carlo_tip_scatter():
    rng = np.random.default_rng(4)
    c = np.diag([0, 0, 0, 4e-4, 1e-3, 2e-4])  # small rotations: the linearisation holds
    pose = UncertainPose(Pose.identity(), c)
    tips = orientation_glyphs(pose, 1.0, length=1.0)
    d = rng.multivariate_normal(np.zeros(3), c[3:, 3:], 20_000)
    rot = quat_to_matrix(quat_exp(d))  # (N, 3, 3)
    for k in range(3):
        moved = rot[:, :, k]  # the rotated unit axis k
        cov_mc = np.cov((moved - np.eye(3)[k]).T)
        rebuilt = tips[k].axes @ np.diag(tips[k].radii ** 2) @ tips[k].axes.T
        np.testing.assert_allclose(rebuilt, cov_mc, atol=5e-5)


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_stable_axes_follow_the_previous_order(seed):
    rng = np.random.default_rng(seed)
    a = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    a *= np.sign(np.linalg.det(a))
    radii = np.sort(rng.uniform(0.1, 1.0, 3))
    perm = rng.permutation(3)
    signs = rng.choice([-1.0, 1.0], 3)
    r2, a2 = stable_axes(radii[perm], a[:, perm] * signs, a)
    np.testing.assert_allclose(r2, radii)
    assert np.linalg.det(a2) > 0
    # every axis points as before (up to the one flip that keeps the frame right-handed)
    np.testing.assert_allclose(np.abs(np.sum(a2 * a, axis=0)), 1.0, atol=1e-12)


def test_classify_states():
    kw = dict(static=False, used=True, rate_hz=60.0, gated_recently=False)
    assert classify(**{**kw, "age_s": 0.01}) == "live"
    assert classify(**{**kw, "age_s": 0.3}) == "stale"
    assert classify(**{**kw, "age_s": None}) == "stale"
    assert classify(**{**kw, "age_s": 0.01, "gated_recently": True}) == "gated"
    assert classify(**{**kw, "age_s": 0.01, "used": False}) == "unused"
    assert classify(**{**kw, "age_s": None, "static": True}) == "static"
    # a slow sensor is stale only after three of its periods
    assert classify(**{**kw, "age_s": 0.5, "rate_hz": 2.0}) == "live"


def test_panel_colours_each_edge_by_state_and_marks_the_path():
    edges = [
        EdgeStatus("art", "A", "T", "live", 60.0, 20.0, 0.0, {}, on_path=True),
        EdgeStatus("cam", "C", "M", "stale", 30.0, 50.0, 30.0, {"stale": 3}),
        EdgeStatus("q", "P", "X", "no path"),
    ]
    html = render_panel(["A", "T", "C", "M", "P", "X"], edges)
    assert f'stroke="{COLOURS["live"]}"' in html
    assert f'stroke="{COLOURS["stale"]}"' in html
    assert f'stroke="{COLOURS["no path"]}"' in html
    assert 'stroke="#ffe14d"' in html  # the highlighted path (only art is on it)
    assert html.count('stroke="#ffe14d"') == 1
    assert "<svg" in html and "</table>" in html
