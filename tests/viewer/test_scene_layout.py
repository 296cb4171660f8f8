"""The readable scene's geometry without a browser (issue 29): the camera's projection and
framing, the floor grid's metric scale, labels laid out without overlaps, the default anchor
frame, the ghost's own magnification, rejections and refused pulls counted apart."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from trackflow.errors import InputError
from trackflow.math import Pose, UncertainPose, quat_exp
from trackflow.viewer.camera import Camera, body_glyph_points, frame_points
from trackflow.viewer.decor import format_length, grid_spec, nice_step, path_segments
from trackflow.viewer.edges import EdgeLayout, default_anchor
from trackflow.viewer.graph_panel import EdgeStatus, render_panel, split_counts
from trackflow.viewer.labels import LabelSpec, box_size, layout_labels, overlaps


def test_the_camera_projects_like_a_pinhole():
    cam = Camera.looking_at([0.0, -2.0, 0.0], [0.0, 0.0, 0.0], fov=np.radians(90), width=800,
                            height=600)  # fmt: skip
    uv, depth = cam.project([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(depth, 2.0)
    np.testing.assert_allclose(uv[0], [400, 300])
    # focal length 300 px at 90 degrees over 600 px: 1 m at 2 m is 150 px, right and up
    np.testing.assert_allclose(uv[1], [550, 300])
    np.testing.assert_allclose(uv[2], [400, 150])
    # the world offset that moves a point at depth 2 by (10, -20) px
    off = cam.world_offset(2.0, 10.0, -20.0)
    uv2, _ = cam.project(off)
    np.testing.assert_allclose(uv2[0], [410, 280], atol=1e-9)
    hit = cam.on_plane(400, 450, -1.0)  # below the centre: the floor 1 m down
    np.testing.assert_allclose(hit, [0.0, 0.0, -1.0], atol=1e-9)
    with pytest.raises(InputError):
        Camera.looking_at([0, 0, 0], [0, 0, 0])


@pytest.mark.parametrize("length", [0.02, 0.3, 2.0])
def test_framing_makes_the_body_cover_the_asked_part_of_the_canvas(length):
    q = quat_exp(np.array([0.3, -0.5, 1.1]))
    pts = body_glyph_points([1.0, 2.0, 1.5], q, length)
    pos, look = frame_points(pts, coverage=0.14, centre=pts[0])
    cam = Camera.looking_at(pos, look, fov=np.radians(45))
    uv, depth = cam.project(pts)
    assert (depth > 0).all()
    span = uv.max(axis=0) - uv.min(axis=0)
    assert 0.10 <= span[0] * span[1] / (cam.width * cam.height) <= 0.15
    assert (uv >= 0).all() and (uv[:, 0] <= cam.width).all() and (uv[:, 1] <= cam.height).all()
    assert uv[0, 0] < 0.5 * cam.width  # left of the middle: the panel covers the right


def test_the_grid_has_a_round_metric_scale_on_the_floor():
    assert [nice_step(x) for x in (0.03, 0.1, 0.19, 0.21, 4.0)] == [0.05, 0.1, 0.2, 0.5, 5.0]
    assert format_length(0.2) == "20 cm" and format_length(1.0) == "1 m"
    g = grid_spec([-1.7, -1.4, 0.9], [2.0, 1.2, 1.9])  # TUM-VI room1
    assert (g.cell, g.section) == (0.2, 1.0) and g.text == "grid 20 cm cells, 1 m lines"
    assert g.center[2] == 0.0  # the room's floor
    assert g.width >= 3.7 * 1.5 and g.height >= 2.6 * 1.5  # the data and a margin
    assert np.allclose(np.array([g.width, g.height]) % g.section, 0.0)
    under = grid_spec([0, 0, -0.5], [0.2, 0.2, 0.0])  # data below z = 0: under the data
    assert under.center[2] == -0.5
    np.testing.assert_allclose(g.mark([0.33, 0.18, 1.2]), [0.4, 0.2, 0.0])


def test_the_path_is_decimated_and_broken_at_gaps():
    p = np.cumsum(np.ones((10001, 3)), axis=0)
    assert len(path_segments(p, max_points=1000)) <= 1000
    p[5] = np.nan
    seg = path_segments(p[:10])
    assert len(seg) == 7 and np.isfinite(seg).all()


def test_labels_at_one_point_are_stacked_without_overlap():
    cam = Camera.looking_at([2.0, -2.0, 1.5], [0.0, 0.0, 0.0])
    here = np.zeros(3)
    specs = [
        LabelSpec("head", "head", here), LabelSpec("art", "art", here),
        LabelSpec("headcam", "headcam", here), LabelSpec("W", "frame W", here, "frame"),
        LabelSpec("hidden", "hidden", here, visible=False),
    ]  # fmt: skip
    placed = layout_labels(specs, cam)
    assert set(placed) == {"head", "art", "headcam", "W"}
    boxes = [p.box for p in placed.values()]
    for i in range(len(boxes)):
        for j in range(i):
            assert not overlaps(boxes[i], boxes[j]), (boxes[i], boxes[j])
    # each label is drawn where its box is: its world position projects into the box centre
    for p in placed.values():
        uv, _ = cam.project(p.position)
        assert abs(uv[0, 0] - (p.box[0] + p.box[2]) / 2) < 1e-6
        assert abs(uv[0, 1] - (p.box[1] + p.box[3]) / 2) < 1e-6
    # a body label above its point, a frame label (smaller) below it
    uv0, _ = cam.project(here)
    assert placed["head"].box[3] < uv0[0, 1] < placed["W"].box[1]
    assert box_size("frame W", 0.85)[1] < box_size("frame W")[1]


def test_the_default_anchor_is_the_room():
    def e(s, t):
        return EdgeLayout(f"{s}{t}", s, t, False)

    fusion = [e("A", "H"), e("H", "W"), e("W", "A")]  # a cycle: W is named like the room
    assert default_anchor(["A", "H", "W"], fusion, near="W") == "W"
    demo = [e("P", "A"), e("A", "T"), e("T", "C"), e("C", "M")]  # P is the graph's root
    assert default_anchor(["P", "A", "T", "C", "M"], demo, near="P") == "P"
    live = [e("room", "head"), e("room", "tool")]  # not the query's source, the head
    assert default_anchor(["room", "head", "tool"], live, near="head") == "room"
    # two graphs: the one holding the query's source
    two = [e("world", "x"), e("B", "y")]
    assert default_anchor(["world", "x", "B", "y"], two, near="y") == "B"


def test_rejections_and_refused_pulls_are_counted_apart():
    counts = {"filter rejected update": 2, "stale": 40, "no data yet": 3, "prediction failed": 1}
    rejected, pulls = split_counts(counts)
    assert rejected == {"filter rejected update": 2, "prediction failed": 1}
    assert pulls == {"stale": 40, "no data yet": 3}
    html = render_panel(["A", "T"], [EdgeStatus("art", "A", "T", "stale", rejections=counts)])
    assert "<th>stale pulls</th>" in html
    assert '">3</td>' in html and '">43</td>' in html


def test_the_ghost_has_its_own_magnification():
    from trackflow.io import PoseStream
    from trackflow.viewer.recording import RecordingTrack, auto_ghost_magnify, auto_magnify

    t = np.arange(0.0, 8.0, 0.01)
    pos = np.stack([np.sin(t), np.cos(0.7 * t), 1 + 0.2 * np.sin(2 * t)], axis=1)
    pos += np.random.default_rng(3).normal(0, 2e-4, pos.shape)
    q = quat_exp(np.stack([0.3 * np.sin(t), 0 * t, t], axis=1))
    track = RecordingTrack.from_stream(
        PoseStream("world", "body", np.round(t * 1e9).astype(np.int64), pos, q)
    )
    L = 0.15
    filt = auto_magnify(track, 2.0, axes_length=L)
    ghost = auto_ghost_magnify(track, 0.1, L)
    assert filt >= 10 * ghost  # sub-millimetre filter error, centimetre prediction error
    # the ghost's median ellipsoid, magnified, stays within a quarter of the axes length
    c = track.predicted(0.1).covariance[:, :3, :3]
    r = np.median(np.sqrt(np.linalg.eigvalsh(c)[:, -1]))
    assert r * ghost <= 0.25 * L < r * ghost * 10
    assert auto_ghost_magnify(track, 0.0, L) == 1.0
    pose = UncertainPose(Pose(pos[0], q[0]), np.eye(6) * 1e-6)
    assert pose.covariance.shape == (6, 6)


def test_the_command_line_names_a_bad_anchor(tmp_path, capsys):
    from trackflow.cli.main import main

    root = Path(__file__).resolve().parents[2]
    shot = str(tmp_path / "x.png")
    setup = str(root / "examples" / "live_demo.yaml")
    assert main(["view", setup, "--anchor", "nowhere", "--snapshot", shot]) == 1
    err = capsys.readouterr().err
    assert "nowhere" in err and "room" in err  # the frames it could have been
    rec = tmp_path / "rec.tum"
    rec.write_text("0 0 0 0 0 0 0 1\n0.01 0 0 0 0 0 0 1\n0.02 0 0 0 0 0 0 1\n")
    assert main(["view", str(rec), "--anchor", "world", "--snapshot", shot]) == 1
    assert "--anchor applies to a setup" in capsys.readouterr().err
