"""OpenCV calibration files: golden text, round trips with cv2.FileStorage, bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackflow.optical import (
    CalibrationFileError,
    read_opencv_calibration,
    ring_rig,
    write_opencv_calibration,
)

GOLDEN_YAML = """%YAML:1.0
---
image_width: 640
image_height: 480
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 5.2e+02, 0., 3.195e+02, 0., 5.25e+02, 2.395e+02, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ -0.25, 0.1, 1.e-03, -2.0000000000000001e-04, 0. ]
"""

GOLDEN_XML = """<?xml version="1.0"?>
<opencv_storage>
<M1 type_id="opencv-matrix">
  <rows>3</rows>
  <cols>3</cols>
  <dt>d</dt>
  <data>
    800. 0. 320. 0. 800. 240. 0. 0. 1.</data></M1>
<D1 type_id="opencv-matrix">
  <rows>1</rows>
  <cols>5</cols>
  <dt>d</dt>
  <data>
    -0.1 0.01 0. 0. 0.</data></D1>
<M2 type_id="opencv-matrix">
  <rows>3</rows>
  <cols>3</cols>
  <dt>d</dt>
  <data>
    810. 0. 322. 0. 811. 241. 0. 0. 1.</data></M2>
<D2 type_id="opencv-matrix">
  <rows>1</rows>
  <cols>4</cols>
  <dt>d</dt>
  <data>
    -0.11 0.02 0. 0.</data></D2>
<R type_id="opencv-matrix">
  <rows>3</rows>
  <cols>3</cols>
  <dt>d</dt>
  <data>
    0. 0. -1. 0. 1. 0. 1. 0. 0.</data></R>
<T type_id="opencv-matrix">
  <rows>3</rows>
  <cols>1</cols>
  <dt>d</dt>
  <data>
    -500. 0. 500.</data></T>
</opencv_storage>
"""


def test_golden_single_camera_yaml(tmp_path):
    p = tmp_path / "camera.yml"
    p.write_text(GOLDEN_YAML)
    rig = read_opencv_calibration(p)
    (cam,) = rig
    assert cam.size == (640, 480)
    np.testing.assert_array_equal(cam.K, [[520.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])
    np.testing.assert_array_equal(cam.dist, [-0.25, 0.1, 1e-3, -2.0000000000000001e-04, 0.0])
    np.testing.assert_array_equal(cam.R_cam_world, np.eye(3))


def test_golden_stereo_xml_in_millimetres(tmp_path):
    p = tmp_path / "stereo.xml"
    p.write_text(GOLDEN_XML)
    rig = read_opencv_calibration(p, image_size=(640, 480), unit_m=1e-3)
    a, b = rig
    np.testing.assert_array_equal(b.R_cam_world, [[0, 0, -1], [0, 1, 0], [1, 0, 0]])
    np.testing.assert_allclose(b.t_cam_world, [-0.5, 0.0, 0.5])
    np.testing.assert_allclose(b.center, [-0.5, 0.0, -0.5])  # -R^T T
    assert a.dist.size == 5 and b.dist.size == 4 and b.size == (640, 480)


cv2 = pytest.importorskip("cv2", reason="opencv-python-headless (dev extra) is the reference")


@pytest.mark.parametrize("ext", [".yml", ".xml"])
def test_files_written_by_opencv_are_read(tmp_path, ext):
    rig = ring_rig(3)
    p = str(tmp_path / f"multi{ext}")
    fs = cv2.FileStorage(p, cv2.FILE_STORAGE_WRITE)
    fs.write("nCameras", len(rig))
    for i, c in enumerate(rig):
        P = np.eye(4)
        P[:3, :3], P[:3, 3] = c.R_cam_world, c.t_cam_world
        fs.write(f"camera_matrix_{i}", c.K)
        fs.write(f"camera_distortion_{i}", c.dist.reshape(1, -1))
        fs.write(f"camera_pose_{i}", P)
    fs.write("image_width", 1280)
    fs.write("image_height", 1024)
    fs.release()
    back = read_opencv_calibration(p)
    assert len(back) == len(rig)
    for c, d in zip(rig, back, strict=True):
        np.testing.assert_array_equal(c.K, d.K)
        np.testing.assert_array_equal(c.dist, d.dist)
        np.testing.assert_array_equal(c.R_cam_world, d.R_cam_world)
        np.testing.assert_array_equal(c.t_cam_world, d.t_cam_world)
        assert d.size == (1280, 1024)


@pytest.mark.parametrize("ext", [".yml", ".xml"])
def test_files_written_here_are_read_by_opencv_and_back(tmp_path, ext):
    rig = ring_rig(4)
    p = tmp_path / f"rig{ext}"
    write_opencv_calibration(p, rig)
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    assert int(fs.getNode("nCameras").real()) == 4
    for i, c in enumerate(rig):
        np.testing.assert_array_equal(fs.getNode(f"camera_matrix_{i}").mat(), c.K)
        pose = fs.getNode(f"camera_pose_{i}").mat()
        np.testing.assert_array_equal(pose[:3, :3], c.R_cam_world)
        np.testing.assert_array_equal(pose[:3, 3], c.t_cam_world)
        np.testing.assert_array_equal(pose[3], [0, 0, 0, 1])
    assert fs.getNode("camera_matrix_4").empty()  # four cameras, no more
    fs.release()
    back = read_opencv_calibration(p)
    assert len(back) == len(rig)
    for c, d in zip(rig, back, strict=True):
        np.testing.assert_array_equal(c.dist, d.dist)
        np.testing.assert_array_equal(c.R_cam_world, d.R_cam_world)


@settings(max_examples=30, deadline=None)
@given(
    f=st.floats(100, 5000),
    k=st.lists(st.floats(-1, 1), min_size=5, max_size=5),
    mm=st.booleans(),
)
def test_round_trip_is_exact(tmp_path_factory, f, k, mm):
    rig = ring_rig(2, focal_px=f, dist=k)
    p = tmp_path_factory.mktemp("rt") / "rig.yaml"
    unit = 1e-3 if mm else 1.0
    write_opencv_calibration(p, rig, unit_m=unit)
    back = read_opencv_calibration(p, unit_m=unit)
    assert len(back) == len(rig)
    for c, d in zip(rig, back, strict=True):
        np.testing.assert_array_equal(c.K, d.K)
        np.testing.assert_array_equal(c.dist, d.dist)
        np.testing.assert_array_equal(c.R_cam_world, d.R_cam_world)
        np.testing.assert_allclose(c.t_cam_world, d.t_cam_world, rtol=1e-15)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("%YAML:1.0\n---\nfoo: 1\n", "no camera found"),
        ("%YAML:1.0\n---\ncamera_matrix: [1, 2\n", "not a valid OpenCV YAML"),
        (
            "%YAML:1.0\n---\nimage_width: 2\nimage_height: 2\n"
            "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [1, 2]\n",
            r":5: matrix of 3x3 has 2 values",
        ),
        (
            "%YAML:1.0\n---\nimage_width: 2\nimage_height: 2\n"
            "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
            "   data: [1, 0, 1, 0, 1, 1, 0, 0, 1]\n",
            "missing key 'distortion_coefficients'",
        ),
        (
            "%YAML:1.0\n---\nimage_width: 2\nimage_height: 2\n"
            "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
            "   data: [1, 0, 1, 0, 1, 1, 0, 0, 1]\n"
            "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 3\n   dt: d\n"
            "   data: [0, 0, 0]\n",
            r":10: distortion_coefficients: expected a matrix",
        ),
        ("%YAML:1.0\n---\nnCameras: 1.5\n", "nCameras: expected an integer"),
        ("<opencv_storage><nCameras>1</nCameras>", "not a valid OpenCV XML"),
        ("<?xml version='1.0'?><foo/>", "root element"),
        (
            "%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
            "   data: [1, 0, 1, 0, 1, 1, 0, 0, 1]\n"
            "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 4\n   dt: d\n"
            "   data: [0, 0, 0, 0]\n",
            "no image size",
        ),
    ],
)
def test_bad_files_name_the_problem(tmp_path, text, match):
    p = tmp_path / ("bad.xml" if text.startswith("<") else "bad.yml")
    p.write_text(text)
    with pytest.raises(CalibrationFileError, match=match) as e:
        read_opencv_calibration(p)
    assert str(p) in str(e.value)


def test_missing_file_and_bad_arguments(tmp_path):
    with pytest.raises(CalibrationFileError, match="cannot read"):
        read_opencv_calibration(tmp_path / "nope.yml")
    with pytest.raises(CalibrationFileError, match="at least one file"):
        read_opencv_calibration()
    with pytest.raises(CalibrationFileError, match=r"\.yml, \.yaml or \.xml"):
        write_opencv_calibration(tmp_path / "rig.txt", ring_rig(1))


@settings(max_examples=60, deadline=None)
@given(junk=st.text(max_size=200))
def test_fuzzed_text_gives_a_typed_error_or_a_rig(tmp_path_factory, junk):
    p = tmp_path_factory.mktemp("fz") / "f.yml"
    p.write_text("%YAML:1.0\n---\n" + junk)
    try:
        read_opencv_calibration(p, image_size=(10, 10))
    except CalibrationFileError:
        pass


def test_calibration_duplicate_key_is_refused_with_its_line(tmp_path):
    p = tmp_path / "dup.yml"
    p.write_text("%YAML:1.0\n---\nimage_width: 2\nimage_height: 2\nimage_width: 3\n")
    with pytest.raises(CalibrationFileError, match="duplicate key 'image_width'") as e:
        read_opencv_calibration(p)
    assert f"{p}:5" in str(e.value)


def test_a_bad_calibration_value_reports_its_line(tmp_path):
    p = tmp_path / "bad.yml"
    p.write_text("%YAML:1.0\n---\n\nnCameras: 1.5\n")
    with pytest.raises(CalibrationFileError, match="expected an integer") as e:
        read_opencv_calibration(p)
    assert f"{p}:4: nCameras" in str(e.value)


def _optical_file(tmp_path, body: str):
    from trackflow.optical import load_optical_setup

    ex = Path(__file__).resolve().parents[2] / "src" / "trackflow" / "examples"
    p = tmp_path / "optical.yaml"
    p.write_text(
        f"setup: {ex / 'optical_setup.yaml'}\ncalibration: {ex / 'optical_cameras.yml'}\n" + body
    )
    return p, load_optical_setup


def test_optical_setup_duplicate_key_is_refused_with_its_line(tmp_path):
    p, load = _optical_file(tmp_path, "models: []\nbodies: {}\nmodels: []\n")
    with pytest.raises(ValueError, match="duplicate key 'models'") as e:
        load(p)
    assert str(e.value).startswith(f"{p}:5: ")


def test_a_bad_optical_value_reports_its_line(tmp_path):
    p, load = _optical_file(tmp_path, "bodies: {tracker_wand: wand}\n\nmodels: 5\n")
    with pytest.raises(ValueError, match="must be a list") as e:
        load(p)
    assert str(e.value).startswith(f"{p}:5: models: ")
