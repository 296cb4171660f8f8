"""The optical tracker as a live feed of ``trackflow run``: ``input: {optical: ...}``.

A sensor of a trackflow setup with ``input: {optical: {config: optical.yaml, body: wand}}``
is measured live by the optical tracker of the optical setup file ``config`` (its rig,
marker models, tracker settings and frames; :func:`~trackflow.optical.source.load_optical_setup`)
for the marker model ``body``. :class:`OpticalFeed` implements
:class:`trackflow.dataflow.PoseFeed`; importing this package registers it under the protocol
``optical`` (:func:`trackflow.dataflow.register_feed`), so the live runtime of
:mod:`trackflow.trackers` builds it without importing the optical package (both are layer 3;
docs/architecture.md). Sensors naming the same ``config`` share one tracker: every frame is
processed once for all bodies.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..dataflow import register_feed
from ..errors import ConfigError, InputError
from .pipeline import OpticalTracker
from .source import FrameSource, load_optical_setup

__all__ = ["OpticalFeed", "optical_feed"]


class OpticalFeed:
    """Frames of a :class:`FrameSource` processed one by one by an :class:`OpticalTracker`.

    Attributes
    ----------
    t_ns : numpy.ndarray
        (N,) exposure times of the frames [ns] (the frame source's clock).
    """

    def __init__(self, tracker: OpticalTracker, frames: FrameSource, source: str = "<optical>"):
        self.tracker = tracker
        self.frames = frames
        self.source = source
        self.t_ns = np.asarray(frames.t_ns, dtype=np.int64)
        self._last = -1

    def warm_up(self, frames: int = 12) -> None:
        """Process the first ``frames`` frames once and forget them, so that the kernels of
        every pipeline stage (search and tracking) are compiled or loaded before frames are
        paced in real time. The renderer's noise stream moves on by that many frames."""
        for i in range(min(frames, len(self.t_ns))):
            self.tracker.process(self.t_ns[i] * 1e-9, self.frames.images(i))
        self.tracker.reset()

    def has_body(self, body: str) -> bool:
        return body in {m.name for m in self.tracker.models}

    def measure(self, index: int) -> Mapping:
        """``{model name: UncertainPose or None}`` of frame ``index`` (``T_world_body`` [m],
        the pipeline's 6x6 covariance); indices must increase (frames may be skipped)."""
        if index <= self._last:
            raise InputError(f"{self.source}: frame {index} after frame {self._last}")
        self._last = index
        res = self.tracker.process(self.t_ns[index] * 1e-9, self.frames.images(index))
        return {name: b.pose for name, b in res.bodies.items()}


def optical_feed(options: dict) -> OpticalFeed:
    """The feed of ``input: {optical: options}``: the tracker and frames of the optical setup
    file ``options["config"]`` (``ValueError`` naming the file for a bad or missing one)."""
    path = Path(options["config"])
    if not path.is_file():
        raise ConfigError(f"input.optical.config: {path} is not a file")
    opt = load_optical_setup(path)
    return OpticalFeed(opt.run.tracker, opt.run.frames, str(path))


register_feed("optical", optical_feed)
