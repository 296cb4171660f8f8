"""OpenCV calibration files (``cv::FileStorage`` YAML or XML) to and from camera rigs.

Three layouts are read, chosen by the keys present:

* multi-camera (what opencv_contrib's ``multicalib`` writes): ``nCameras`` and, per camera
  ``i``, ``camera_matrix_i`` (3x3), ``camera_distortion_i`` (1xN) and ``camera_pose_i`` (4x4,
  ``x_cam_i = P x_world``; camera 0 usually the identity), plus optional ``image_width_i`` /
  ``image_height_i`` (or one ``image_width`` / ``image_height`` for all);
* stereo (what OpenCV's ``stereo_calib`` sample writes to ``intrinsics.yml`` and
  ``extrinsics.yml``; pass both files): ``M1, D1, M2, D2, R, T`` with ``x_cam2 = R x_cam1 + T``,
  the world being camera 1;
* one camera (OpenCV's ``calibration`` sample): ``camera_matrix``, ``distortion_coefficients``,
  ``image_width``, ``image_height``, optional extrinsics ``rvec`` / ``tvec``.

Translations are in the calibration's unit; ``unit_m`` scales them to metres (0.001 for mm).
YAML files are read by :func:`trackflow.yamlfile.parse_yaml` (a key given twice is refused).
Mistakes raise :class:`CalibrationFileError` (a :class:`trackflow.errors.ConfigError`) naming the
file, the line (YAML) and the key.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from ..yamlfile import line_of, parse_yaml
from .camera import Camera, CameraRig

__all__ = ["CalibrationFileError", "read_opencv_calibration", "write_opencv_calibration"]


class CalibrationFileError(ConfigError):
    """A calibration file that cannot be read: names the file, line (if known) and key."""


class _Mat:
    """A parsed ``opencv-matrix`` node and the line it started on."""

    def __init__(self, array: np.ndarray, line: int):
        self.array, self.line = array, line


def _matrix_from_fields(fields: dict, where: str) -> np.ndarray:
    try:
        rows, cols = int(fields["rows"]), int(fields["cols"])
        data = fields["data"]
    except (KeyError, TypeError, ValueError) as e:
        raise CalibrationFileError(f"{where}: an opencv-matrix needs rows, cols and data") from e
    if isinstance(data, str):
        data = data.split()
    if not isinstance(data, list):
        data = [data]
    try:
        values = np.array([float(v) for v in data], dtype=float)
    except (TypeError, ValueError) as e:
        raise CalibrationFileError(f"{where}: matrix data is not numeric") from e
    if rows < 0 or cols < 0 or values.size != rows * cols:
        raise CalibrationFileError(f"{where}: matrix of {rows}x{cols} has {values.size} values")
    return values.reshape(rows, cols)


def _construct_matrix(loader, node) -> _Mat:
    """OpenCV's ``!!opencv-matrix`` tag."""
    line = node.start_mark.line + 1
    fields = loader.construct_mapping(node, deep=True)
    return _Mat(_matrix_from_fields(fields, f"{loader.source}:{line}"), line)


_TAGS = {"tag:yaml.org,2002:opencv-matrix": _construct_matrix}


def _read_yaml(path: Path, text: str) -> dict:
    # OpenCV writes the non-standard directive "%YAML:1.0"; YAML 1.1 parsers need "%YAML 1.1"
    lines = text.splitlines()
    if lines and lines[0].startswith("%YAML"):
        lines[0] = ""  # keep the line numbers
    try:
        doc = parse_yaml("\n".join(lines), path, _TAGS)
    except CalibrationFileError:
        raise
    except ConfigError as e:
        raise CalibrationFileError(
            f"not a valid OpenCV YAML file: {e.reason}", path, e.line
        ) from None
    if not isinstance(doc, dict):
        raise CalibrationFileError(f"{path}: the top level must be a mapping of named values")
    return doc


def _xml_value(node: ET.Element, where: str):
    if node.get("type_id") == "opencv-matrix":
        fields = {child.tag: (child.text or "").strip() for child in node}
        return _Mat(_matrix_from_fields(fields, where), 0)
    text = (node.text or "").strip()
    if len(node):
        return {child.tag: _xml_value(child, f"{where}/{child.tag}") for child in node}
    for conv in (int, float):
        try:
            return conv(text)
        except ValueError:
            pass
    return text


def _read_xml(path: Path, text: str) -> dict:
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise CalibrationFileError(f"{path}: not a valid OpenCV XML file: {e}") from e
    if root.tag != "opencv_storage":
        raise CalibrationFileError(f"{path}: the root element must be <opencv_storage>")
    return {child.tag: _xml_value(child, f"{path}: <{child.tag}>") for child in root}


def _read_any(path: Path) -> dict:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise CalibrationFileError(f"{path}: cannot read: {e}") from e
    head = text.lstrip()[:64]
    if head.startswith(("<?xml", "<opencv_storage")):
        return _read_xml(path, text)
    return _read_yaml(path, text)


class _Doc:
    """Merged key/value view of one or more files, remembering where each key came from."""

    def __init__(self, paths: list[Path]):
        self.values: dict = {}
        self.origin: dict = {}
        self.lines: dict = {}
        for p in paths:
            doc = _read_any(p)
            for k, v in doc.items():
                self.values[k] = v
                self.origin[k] = p
                self.lines[k] = line_of(doc, k)
        self.files = ", ".join(str(p) for p in paths)

    def where(self, key: str) -> str:
        v = self.values.get(key)
        line = getattr(v, "line", 0) or self.lines.get(key, 0)
        src = self.origin.get(key, self.files)
        return f"{src}" + (f":{line}" if line else "") + f": {key}"

    def has(self, key: str) -> bool:
        return key in self.values

    def matrix(self, key: str, shapes: tuple) -> np.ndarray:
        if key not in self.values:
            raise CalibrationFileError(f"{self.files}: missing key {key!r}")
        v = self.values[key]
        a = v.array if isinstance(v, _Mat) else np.atleast_2d(np.asarray(v, dtype=float))
        for shape in shapes:
            if a.size == int(np.prod(shape)) and (a.shape == shape or 1 in a.shape):
                a = a.reshape(shape)
                if not np.all(np.isfinite(a)):
                    raise CalibrationFileError(f"{self.where(key)}: non-finite values")
                return a
        raise CalibrationFileError(
            f"{self.where(key)}: expected a matrix of shape "
            + " or ".join(str(s) for s in shapes)
            + f", got {a.shape}"
        )

    def integer(self, key: str, default=None) -> int:
        if key not in self.values:
            if default is None:
                raise CalibrationFileError(f"{self.files}: missing key {key!r}")
            return default
        v = self.values[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or int(v) != v:
            raise CalibrationFileError(f"{self.where(key)}: expected an integer, got {v!r}")
        return int(v)


_DIST_SHAPES = ((1, 4), (1, 5), (1, 8))


def _size(doc: _Doc, suffix: str, image_size) -> tuple[int, int]:
    for w_key, h_key in (
        (f"image_width{suffix}", f"image_height{suffix}"),
        ("image_width", "image_height"),
    ):
        if doc.has(w_key) and doc.has(h_key):
            return doc.integer(w_key), doc.integer(h_key)
    if doc.has("imageSize"):
        w, h = doc.matrix("imageSize", ((1, 2), (2, 1))).reshape(2)
        return int(w), int(h)
    if image_size is None:
        raise CalibrationFileError(
            f"{doc.files}: no image size (image_width/image_height); pass image_size="
        )
    return int(image_size[0]), int(image_size[1])


def _camera(doc, K_key, D_key, R, t, size, name, unit_m) -> Camera:
    K = doc.matrix(K_key, ((3, 3),))
    D = doc.matrix(D_key, _DIST_SHAPES).reshape(-1)
    try:
        return Camera(K, D, size, R, np.asarray(t, dtype=float) * unit_m, name)
    except ValueError as e:
        raise CalibrationFileError(f"{doc.where(K_key)}: {e}") from e


def _rodrigues(rvec: np.ndarray) -> np.ndarray:
    from ..math import quat_exp, quat_to_matrix

    return quat_to_matrix(quat_exp(rvec.reshape(3)))


def read_opencv_calibration(*paths, image_size=None, unit_m: float = 1.0) -> CameraRig:
    """Read a rig from OpenCV calibration files (YAML or XML; several are merged).

    Parameters
    ----------
    *paths : str or Path
        One file, or e.g. ``intrinsics.yml`` and ``extrinsics.yml`` of ``stereo_calib``.
    image_size : (int, int), optional
        ``(width, height)`` when the files do not store it.
    unit_m : float
        Metres per unit of the stored translations (1 for metres, 0.001 for millimetres).

    Returns
    -------
    CameraRig
        Extrinsics ``x_cam = R x_world + t`` in metres.

    Raises
    ------
    CalibrationFileError
        Unreadable file, missing or malformed key (named with file and line).
    """
    if not paths:
        raise CalibrationFileError("read_opencv_calibration needs at least one file")
    if not unit_m > 0:
        raise CalibrationFileError(f"unit_m must be > 0, got {unit_m}")
    doc = _Doc([Path(p) for p in paths])
    if doc.has("nCameras"):
        n = doc.integer("nCameras")
        if n < 1:
            raise CalibrationFileError(f"{doc.where('nCameras')}: need at least one camera")
        cams = []
        for i in range(n):
            P = doc.matrix(f"camera_pose_{i}", ((4, 4), (3, 4)))
            cams.append(
                _camera(
                    doc,
                    f"camera_matrix_{i}",
                    f"camera_distortion_{i}",
                    P[:3, :3],
                    P[:3, 3],
                    _size(doc, f"_{i}", image_size),
                    f"cam{i}",
                    unit_m,
                )
            )
        return CameraRig(cams)
    if doc.has("M1") and doc.has("M2"):
        size = _size(doc, "", image_size)
        R = doc.matrix("R", ((3, 3),))
        T = doc.matrix("T", ((3, 1), (1, 3))).reshape(3)
        c1 = _camera(doc, "M1", "D1", np.eye(3), np.zeros(3), size, "cam0", unit_m)
        c2 = _camera(doc, "M2", "D2", R, T, size, "cam1", unit_m)
        return CameraRig([c1, c2])
    if doc.has("camera_matrix"):
        R, t = np.eye(3), np.zeros(3)
        if doc.has("rvec") or doc.has("tvec"):
            R = _rodrigues(doc.matrix("rvec", ((3, 1), (1, 3))))
            t = doc.matrix("tvec", ((3, 1), (1, 3))).reshape(3)
        D_key = "distortion_coefficients"
        cam = _camera(doc, "camera_matrix", D_key, R, t, _size(doc, "", image_size), "cam0", unit_m)
        return CameraRig([cam])
    raise CalibrationFileError(
        f"{doc.files}: no camera found (expected nCameras, M1/M2 or camera_matrix keys)"
    )


# -- writing ------------------------------------------------------------------------------------
def _fmt(v: float) -> str:
    return repr(float(v))


def _yaml_matrix(name: str, a: np.ndarray) -> str:
    data = ", ".join(_fmt(v) for v in a.reshape(-1))
    return (
        f"{name}: !!opencv-matrix\n   rows: {a.shape[0]}\n   cols: {a.shape[1]}\n"
        f"   dt: d\n   data: [ {data} ]\n"
    )


def _xml_matrix(name: str, a: np.ndarray) -> str:
    data = " ".join(_fmt(v) for v in a.reshape(-1))
    return (
        f'<{name} type_id="opencv-matrix">\n  <rows>{a.shape[0]}</rows>\n'
        f"  <cols>{a.shape[1]}</cols>\n  <dt>d</dt>\n  <data>\n    {data}</data></{name}>\n"
    )


def write_opencv_calibration(path, rig: CameraRig, unit_m: float = 1.0) -> None:
    """Write ``rig`` in the multi-camera layout, YAML (``.yml``/``.yaml``) or XML (``.xml``),
    readable by ``cv::FileStorage`` and :func:`read_opencv_calibration`.

    Translations are written in units of ``unit_m`` metres.
    """
    path = Path(path)
    xml = path.suffix.lower() == ".xml"
    if not xml and path.suffix.lower() not in (".yml", ".yaml"):
        raise CalibrationFileError(f"{path}: use a .yml, .yaml or .xml file name")
    mat = _xml_matrix if xml else _yaml_matrix

    def scalar(k, v):
        return f"<{k}>{v}</{k}>\n" if xml else f"{k}: {v}\n"

    parts = [scalar("nCameras", len(rig))]
    for i, c in enumerate(rig):
        P = np.eye(4)
        P[:3, :3] = c.R_cam_world
        P[:3, 3] = c.t_cam_world / unit_m
        parts += [
            scalar(f"image_width_{i}", c.size[0]),
            scalar(f"image_height_{i}", c.size[1]),
            mat(f"camera_matrix_{i}", c.K),
            mat(f"camera_distortion_{i}", c.dist.reshape(1, -1)),
            mat(f"camera_pose_{i}", P),
        ]
    body = "".join(parts)
    if xml:
        text = f'<?xml version="1.0"?>\n<opencv_storage>\n{body}</opencv_storage>\n'
    else:
        text = "%YAML:1.0\n---\n" + body
    path.write_text(text, encoding="utf-8")
