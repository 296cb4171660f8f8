"""The optical tracker as a dataflow sensor, and optical setups in YAML.

:class:`OpticalRun` runs one :class:`~trackflow.optical.pipeline.OpticalTracker` over a
sequence of frames (lazily, in order, once for all bodies); :class:`OpticalBodySensor` is the
source component of one measured edge ``T_world_body``: a
:class:`trackflow.dataflow.RecordingPlayer` whose samples are the tracker's measured poses,
each with the covariance the pipeline propagated from the pixel noise. Frames the body is not
measured in are counted rejections (``"not measured"``).

An optical setup file names a trackflow setup (frames, sensors, queries; see
``docs/dataflow.md``), the cameras' OpenCV calibration, the marker models, which setup sensor
measures which body, and where the frames come from (rendered from real recordings when no
cameras are attached)::

    setup: optical_setup.yaml          # trackflow setup, relative to this file
    calibration: optical_cameras.yml   # OpenCV FileStorage (YAML or XML)
    calibration_unit_m: 1.0
    models:
      - {name: wand, markers_mm: [[0, 0, 0], [60, 0, 0], ...]}
    bodies: {tracker_wand: wand}       # setup sensor -> marker model
    tracker: {sigma_px: 0.1}           # TrackerConfig fields
    render:                            # RenderSettings fields, plus frames and trajectories
      rate_hz: 120
      start_s: 5.0
      duration_s: 10.0
      seed: 1
      trajectories:
        wand: {recording: ../shared/data/ar_table/table_01.txt, center: [0, 0, 1],
               detrend_s: 4.0}
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Protocol

import numpy as np

from ..dataflow import Component, Measurement, RecordingPlayer, Setup, load_setup
from ..errors import ConfigError, InputError
from ..filters import MotionModel
from ..yamlfile import line_of, read_yaml
from .calibration import read_opencv_calibration
from .camera import CameraRig
from .models import MarkerModel
from .pipeline import FrameResult, OpticalTracker, TrackerConfig
from .render import Cylinder, FrameRenderer, RenderSettings, trajectory_from_stream

__all__ = [
    "FrameSource",
    "OpticalBodySensor",
    "OpticalRun",
    "OpticalSetup",
    "RenderedFrames",
    "load_optical_setup",
]


class FrameSource(Protocol):
    """Synchronised frames of a camera rig: ``t_ns`` (N,) exposure times [ns] and
    ``images(i) -> list of (H, W) arrays`` (one per camera)."""

    t_ns: np.ndarray

    def images(self, index: int) -> list[np.ndarray]: ...


class RenderedFrames:
    """Frames rendered on demand by a :class:`FrameRenderer` at ``rate_hz`` from ``start_s``.

    The renderer's noise stream advances with every frame drawn, so frames are reproducible
    when drawn in order (as :class:`OpticalRun` does) from a fresh renderer.
    """

    def __init__(self, renderer: FrameRenderer, rate_hz: float, start_s: float, duration_s: float):
        if not rate_hz > 0 or not duration_s > 0:
            raise InputError("rate_hz and duration_s must be > 0")
        n = int(np.floor(duration_s * rate_hz)) + 1
        self.renderer = renderer
        self.times_s = start_s + np.arange(n) / rate_hz
        self.t_ns = np.round(self.times_s * 1e9).astype(np.int64)
        self.last = None  # the last Frame drawn (with its truth)

    def images(self, index: int) -> list[np.ndarray]:
        self.last = self.renderer.render(float(self.times_s[index]))
        return self.last.images


class OpticalRun:
    """One tracker over one frame source, evaluated lazily and in order.

    ``result(i)`` processes every frame up to ``i`` that was not processed yet and returns
    frame ``i``'s :class:`FrameResult`; asking for an earlier frame than the last processed
    one restarts from the beginning (after :meth:`reset`).
    """

    def __init__(self, tracker: OpticalTracker, frames: FrameSource, keep: int = 64):
        self.tracker = tracker
        self.frames = frames
        self.t_ns = np.asarray(frames.t_ns, dtype=np.int64)
        if self.t_ns.ndim != 1 or np.any(np.diff(self.t_ns) <= 0):
            raise InputError("frame times must be 1-D and strictly increasing")
        self.keep = int(keep)
        self.reset()

    def reset(self) -> None:
        self.tracker.reset()
        self._next = 0
        self._cache: dict[int, FrameResult] = {}

    def result(self, index: int) -> FrameResult:
        if index in self._cache:
            return self._cache[index]
        if index < self._next:
            self.reset()
        while self._next <= index:
            i = self._next
            res = self.tracker.process(self.t_ns[i] * 1e-9, self.frames.images(i))
            self._cache[i] = res
            self._cache.pop(i - self.keep, None)
            self._next += 1
        return self._cache[index]


class OpticalBodySensor(RecordingPlayer):
    """Source component of the edge ``T_world_body`` measured by an :class:`OpticalRun`.

    Parameters
    ----------
    name : str
        Component (and measured edge) name.
    run : OpticalRun
        Shared by the sensors of all bodies of one tracker.
    body : str
        Marker model name.
    latency_ns : int
        Exposure to availability [ns] (image transfer and processing).
    """

    kind = "sensor"

    def __init__(self, name: str, run: OpticalRun, body: str, latency_ns: int = 0):
        Component.__init__(self, name)
        if body not in {m.name for m in run.tracker.models}:
            raise InputError(f"sensor {name!r}: the tracker has no marker model {body!r}")
        if int(latency_ns) < 0:
            raise InputError(f"sensor {name!r}: latency must be >= 0")
        self.run_ = run
        self.body = body
        self.t_ns = run.t_ns
        self.latency_ns = int(latency_ns)
        self.reset()

    def reset(self) -> None:
        Component.reset(self)
        self.run_.reset()
        self._last_t = None

    def deliver(self, index: int) -> None:
        self.stats.events_in += 1
        res = self.run_.result(index).bodies[self.body]
        if res.pose is None:
            self.stats.reject("not measured")
            return
        t = int(self.t_ns[index])
        self.emit(Measurement(t, res.pose, t))


# -- setups ---------------------------------------------------------------------------------
@dataclass
class OpticalSetup:
    """A parsed optical setup: the trackflow setup, the rig, models and the tracker run."""

    setup: Setup
    rig: CameraRig
    models: list[MarkerModel]
    bodies: dict[str, str]  # setup sensor name -> model name
    run: OpticalRun
    source: str

    def sources(self) -> dict[str, OpticalBodySensor]:
        """One sensor component per measured body, for :meth:`trackflow.dataflow.Plan.build`."""
        out = {}
        for edge, body in self.bodies.items():
            latency = int(round(self.setup.graph.edge(edge).latency_s * 1e9))
            out[edge] = OpticalBodySensor(edge, self.run, body, latency)
        return out


_TOP = {"setup", "calibration", "calibration_unit_m", "image_size", "models", "bodies",
        "tracker", "render"}  # fmt: skip


def _at(path, item, key) -> str:
    """``file:line: key`` of ``key`` in the mapping ``item`` read from ``path``."""
    line = line_of(item, key)
    return f"{path}" + (f":{line}" if line else "") + f": {key}"


def _config(cls, item, where: str, skip=()):
    names = {f.name for f in fields(cls)} - set(skip)
    unknown = set(item) - names
    if unknown:
        raise ConfigError(f"{where}: unknown keys {sorted(unknown)} (allowed: {sorted(names)})")
    return dict(item)


def _tracker_config(item, where) -> TrackerConfig:
    kw = _config(TrackerConfig, item or {}, where)
    if "motion" in kw:
        m = kw["motion"]
        kw["motion"] = MotionModel(int(m.get("n_dp", 1)), int(m.get("n_do", 1)), m.get("noise"))
    return TrackerConfig(**kw)


def _renderer(item, rig, models, base: Path, where: str) -> RenderedFrames:
    from ..io import read_stream

    item = dict(item)
    frames = {k: item.pop(k) for k in ("rate_hz", "start_s", "duration_s", "seed") if k in item}
    trajs_cfg = item.pop("trajectories", None)
    if not isinstance(trajs_cfg, Mapping):
        raise ConfigError(f"{where}: render needs trajectories: {{model: {{recording: ...}}}}")
    kw = _config(RenderSettings, item, where)
    if "occluders" in kw:
        kw["occluders"] = [Cylinder(**c) for c in kw["occluders"]]
    if "hidden" in kw:
        kw["hidden"] = [tuple(h) for h in kw["hidden"]]
    trajs = {}
    for name, tc in trajs_cfg.items():
        if not isinstance(tc, Mapping) or "recording" not in tc:
            raise ConfigError(f"{where}: trajectory of {name!r} needs a recording")
        stream, _ = read_stream(base / tc["recording"], clean=True)
        trajs[name] = trajectory_from_stream(
            stream, tc.get("center", (0.0, 0.0, 1.0)), tc.get("t_start"), tc.get("detrend_s")
        )
    r = FrameRenderer(rig, models, trajs, RenderSettings(**kw), int(frames.get("seed", 0)))
    return RenderedFrames(
        r,
        float(frames.get("rate_hz", 120.0)),
        float(frames.get("start_s", 0.0)),
        float(frames.get("duration_s", 10.0)),
    )


def load_optical_setup(path) -> OpticalSetup:
    """Read an optical setup file (see the module docstring).

    The file is read by :func:`trackflow.yamlfile.read_yaml` (a key given twice is refused).
    Mistakes raise :class:`~trackflow.errors.ConfigError` naming the file, the line and the
    key; calibration files raise :class:`~trackflow.optical.calibration.CalibrationFileError`
    (a ``ConfigError``); an ``OSError`` (no such file) is passed on.
    """
    path = Path(path)
    doc = read_yaml(path)
    if not isinstance(doc, dict):
        raise ConfigError("an optical setup must be a mapping", path, line_of(doc))
    unknown = set(doc) - _TOP
    if unknown:
        first = min(unknown, key=lambda k: (line_of(doc, k), str(k)))
        raise ConfigError(
            f"unknown keys {sorted(unknown, key=str)} (allowed: {sorted(_TOP)})",
            path, line_of(doc, first),
        )  # fmt: skip
    for key in ("setup", "calibration", "models", "bodies"):
        if key not in doc:
            raise ConfigError(f"missing key {key!r}", path)
    base = path.parent
    setup = load_setup(base / doc["setup"])
    rig = read_opencv_calibration(
        base / doc["calibration"],
        image_size=doc.get("image_size"),
        unit_m=float(doc.get("calibration_unit_m", 1.0)),
    )
    if not isinstance(doc["models"], Sequence):
        raise ConfigError("must be a list", path, line_of(doc, "models"), "models")
    models = [
        MarkerModel.from_dict(m, _at(path, m, f"models[{i}]")) for i, m in enumerate(doc["models"])
    ]
    names = {m.name for m in models}
    bodies = doc["bodies"]
    if not isinstance(bodies, Mapping) or not bodies:
        raise ConfigError(
            "must map setup sensors to marker models", path, line_of(doc, "bodies"), "bodies"
        )
    for edge, body in bodies.items():
        if body not in names:
            raise ConfigError(
                f"{edge!r} -> unknown model {body!r}", path, line_of(bodies, edge), "bodies"
            )
        try:
            setup.graph.edge(edge)
        except (KeyError, ValueError) as e:
            raise ConfigError(
                f"{edge!r} is not a sensor of {doc['setup']}", path, line_of(bodies, edge), "bodies"
            ) from e
    try:
        config = _tracker_config(doc.get("tracker"), _at(path, doc, "tracker"))
    except (TypeError, ValueError) as e:
        if isinstance(e, ConfigError):
            raise
        raise ConfigError(str(e), path, line_of(doc, "tracker"), "tracker") from None
    tracker = OpticalTracker(rig, models, config)
    if "render" not in doc:
        raise ConfigError("give frames to track (render: ...)", path)
    frames = _renderer(doc["render"], rig, models, base, _at(path, doc, "render"))
    return OpticalSetup(setup, rig, models, dict(bodies), OpticalRun(tracker, frames), str(path))
