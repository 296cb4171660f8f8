"""Setup fragments: calibration results as YAML that ``trackflow.dataflow.load_setup`` includes.

A fragment holds ``statics`` (static edges with a 6x6 covariance, as in a setup) and
``sensors`` entries that update an existing sensor by name (``stamp_offset_ms``,
``covariance``). A setup lists fragments under ``include:``; see ``docs/calibration.md``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from ..errors import InputError
from ..io import atomic_output
from ..math import UncertainPose

__all__ = ["sensor_update", "static_edge", "write_fragment"]


def _matrix(c) -> list[list[float]]:
    return [[float(v) for v in row] for row in np.asarray(c, float)]


def static_edge(name: str, source: str, target: str, pose: UncertainPose) -> dict:
    """A ``statics`` entry for ``T_source_target`` with its covariance (metres, radians)."""
    return {
        "name": name,
        "source": source,
        "target": target,
        "position": [float(v) for v in pose.position],
        "quaternion": [float(v) for v in pose.quaternion],
        "covariance": _matrix(pose.covariance),
    }


def sensor_update(
    name: str, clock_offset_s: float | None = None, covariance: np.ndarray | None = None
) -> dict:
    """A ``sensors`` entry of a fragment: the sensor's stamp offset and/or noise covariance.

    ``clock_offset_s`` is the ``offset_s`` of the clock-offset / hand-eye / alignment results
    (``t_reference = t_sensor + offset_s``). The setup's ``stamp_offset_ms`` follows the
    thesis (9.2.2): ``stamp = true time + stamp_offset``, so it is ``-offset_s`` in ms.
    """
    out: dict = {"name": name}
    if clock_offset_s is not None:
        out["stamp_offset_ms"] = -float(clock_offset_s) * 1e3
    if covariance is not None:
        out["covariance"] = _matrix(covariance)
    return out


def write_fragment(
    path: str | Path,
    statics: list[dict] = (),
    sensors: list[dict] = (),
    note: str = "",
    overwrite: bool = False,
) -> Path:
    """Write a fragment YAML (``statics`` and ``sensors`` lists); returns the path."""
    path = Path(path)
    doc: dict = {}
    if statics:
        doc["statics"] = list(statics)
    if sensors:
        doc["sensors"] = list(sensors)
    if not doc:
        raise InputError("a setup fragment needs at least one static edge or sensor update")
    head = "".join(f"# {line}\n" for line in note.splitlines()) if note else ""
    with atomic_output(path, overwrite=overwrite) as tmp:
        tmp.write_text(head + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None))
    return path
