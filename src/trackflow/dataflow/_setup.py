"""Setups in YAML: frames, sensors, static calibrations, motion models and queries.

Example (``examples/demo_setup.yaml`` is a complete one)::

    sensors:
      - {name: art, source: A, target: T, rate_hz: 60, latency_ms: 20,
         sigma_pos_mm: 0.3, sigma_ori_deg: 0.05, motion: {n_dp: 1, n_do: 1, noise: [2, 8]},
         recording: art.tum,            # optional, relative to the YAML file
         input: {dtrack: {port: 5000, body: 3}}}  # optional live input (docs/trackers.md)
    statics:
      - {name: projector, source: P, target: A, position: [0, 2, 0],
         quaternion: [0, 0, 0, 1], sigma_pos_mm: 0.1, sigma_ori_deg: 0.01}
    queries:
      - {name: view, source: P, target: M, mode: push, rate_hz: 60, time_offset_ms: 0}

Everything a file can say can also be built in Python with
:class:`trackflow.graph.SpatialRelationshipGraph` and :class:`trackflow.graph.Query`.
Mistakes raise ``ValueError`` naming the file, the line and the key.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from ..graph import MotionSpec, Query, SpatialRelationshipGraph
from ..math import Pose
from ._planner import Plan, plan_query
from ._sources import RecordingPlayer

__all__ = ["Setup", "load_setup", "parse_setup"]


class _Map(dict):
    line = 0


class _LineLoader(yaml.SafeLoader):
    """A safe loader remembering the line of every mapping."""


def _construct_map(loader: _LineLoader, node) -> _Map:
    m = _Map(loader.construct_mapping(node, deep=True))
    m.line = node.start_mark.line + 1
    return m


_LineLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_map)


@dataclass
class Setup:
    """A parsed setup: the SRG, named queries and the recordings of measured edges."""

    graph: SpatialRelationshipGraph
    queries: dict[str, Query] = field(default_factory=dict)
    recordings: dict[str, Path] = field(default_factory=dict)
    source: str = "<python>"
    #: live inputs of sensors: name -> :class:`trackflow.trackers.spec.InputSpec`
    inputs: dict = field(default_factory=dict)

    def query(self, name: str | None = None) -> Query:
        """The query called ``name`` (the first one if ``None``)."""
        if not self.queries:
            raise ValueError(f"{self.source}: the setup defines no queries")
        if name is None:
            return next(iter(self.queries.values()))
        if name not in self.queries:
            raise ValueError(f"{self.source}: no query {name!r} (have {list(self.queries)})")
        return self.queries[name]

    def plan(self, query: Query | str | None = None, align: bool = True) -> Plan:
        """Plan a query of this setup (a :class:`Query`, a query name, or the first)."""
        q = query if isinstance(query, Query) else self.query(query)
        return plan_query(self.graph, q, align=align)

    def players(self) -> dict[str, RecordingPlayer]:
        """Players for every measured edge with a recording (read with ``trackflow.io``)."""
        from ..io import read_stream

        out = {}
        for name, path in self.recordings.items():
            edge = self.graph.edge(name)
            stream = read_stream(path)
            out[name] = RecordingPlayer.from_stream(
                name, stream, int(round(edge.latency_s * 1e9)), covariance=edge.covariance
            )
        return out


def _err(src: str, item, msg: str) -> ValueError:
    line = getattr(item, "line", 0)
    return ValueError(f"{src}" + (f":{line}" if line else "") + f": {msg}")


def _cov(src, item, what) -> np.ndarray:
    if "covariance" in item:
        c = np.asarray(item["covariance"], dtype=float)
        if c.shape != (6, 6):
            raise _err(src, item, f"{what}: covariance must be a 6x6 list of lists")
        return c
    sp = float(item.get("sigma_pos_mm", 0.0)) * 1e-3
    so = np.radians(np.broadcast_to(np.asarray(item.get("sigma_ori_deg", 0.0), float), (3,)))
    return np.diag(np.concatenate([np.full(3, sp**2), so**2]))


def _motion(src, item, what) -> MotionSpec:
    m = item.get("motion", {"n_dp": 1, "n_do": 1})
    if m == "static":
        return MotionSpec.make_static()
    if not isinstance(m, dict):
        raise _err(src, item, f"{what}: motion must be 'static' or a mapping")
    unknown = set(m) - {"n_dp", "n_do", "noise"}
    if unknown:
        raise _err(src, m or item, f"{what}: unknown motion keys {sorted(unknown)}")
    noise = m.get("noise", 1.0)
    noise = tuple(float(v) for v in noise) if isinstance(noise, list) else float(noise)
    return MotionSpec(
        static=False, n_dp=int(m.get("n_dp", 1)), n_do=int(m.get("n_do", 1)), noise=noise
    )


_SENSOR_KEYS = {
    "name",
    "source",
    "target",
    "rate_hz",
    "latency_ms",
    "stamp_offset_ms",
    "confidence",
    "cost",
    "sigma_pos_mm",
    "sigma_ori_deg",
    "covariance",
    "motion",
    "recording",
    "input",
}
_STATIC_KEYS = {
    "name",
    "source",
    "target",
    "position",
    "quaternion",
    "sigma_pos_mm",
    "sigma_ori_deg",
    "covariance",
}
_QUERY_KEYS = {
    "name",
    "source",
    "target",
    "mode",
    "rate_hz",
    "time_offset_ms",
    "fuse",
    "static",
    "exclude",
    "evaluation",
}


def _check_keys(src, item, allowed, what):
    if not isinstance(item, dict):
        raise _err(src, item, f"{what} must be a mapping")
    unknown = set(item) - allowed
    if unknown:
        raise _err(
            src, item, f"{what}: unknown keys {sorted(unknown)} (allowed: {sorted(allowed)})"
        )
    for key in ("name", "source", "target"):
        if key not in item:
            raise _err(src, item, f"{what}: missing key {key!r}")


def parse_setup(doc, source: str = "<setup>", base_dir: Path | None = None) -> Setup:
    """Build a :class:`Setup` from a parsed YAML document (a mapping)."""
    if not isinstance(doc, dict):
        raise ValueError(f"{source}: a setup must be a mapping with sensors/statics/queries")
    unknown = set(doc) - {"frames", "sensors", "statics", "queries"}
    if unknown:
        raise _err(source, doc, f"unknown top-level keys {sorted(unknown)}")
    g = SpatialRelationshipGraph()
    for f in doc.get("frames") or []:
        g.add_frame(str(f))
    recordings: dict[str, Path] = {}
    inputs: dict = {}
    for i, s in enumerate(doc.get("sensors") or []):
        what = f"sensors[{i}]"
        _check_keys(source, s, _SENSOR_KEYS, what)
        try:
            g.add_measured(
                str(s["name"]),
                str(s["source"]),
                str(s["target"]),
                latency_s=float(s.get("latency_ms", 0.0)) * 1e-3,
                rate_hz=float(s.get("rate_hz", 30.0)),
                confidence=float(s.get("confidence", 1.0)),
                cost=float(s.get("cost", 0.0)),
                covariance=_cov(source, s, what),
                motion=_motion(source, s, what),
                stamp_offset_s=float(s.get("stamp_offset_ms", 0.0)) * 1e-3,
            )
        except (TypeError, ValueError) as exc:
            raise _err(source, s, f"{what}: {exc}") from exc
        if "recording" in s:
            p = Path(str(s["recording"]))
            recordings[str(s["name"])] = p if p.is_absolute() or base_dir is None else base_dir / p
        if "input" in s:
            from ..trackers.spec import parse_input

            try:
                inputs[str(s["name"])] = parse_input(s["input"])
            except ValueError as exc:
                raise _err(source, s.get("input") or s, f"{what}: {exc}") from exc
    for i, s in enumerate(doc.get("statics") or []):
        what = f"statics[{i}]"
        _check_keys(source, s, _STATIC_KEYS, what)
        try:
            pose = Pose(
                s.get("position", [0, 0, 0]), s.get("quaternion", [0, 0, 0, 1]), normalize=True
            )
            g.add_static(
                str(s["name"]), str(s["source"]), str(s["target"]), pose, _cov(source, s, what)
            )
        except (TypeError, ValueError) as exc:
            raise _err(source, s, f"{what}: {exc}") from exc
    queries: dict[str, Query] = {}
    for i, q in enumerate(doc.get("queries") or []):
        what = f"queries[{i}]"
        _check_keys(source, q, _QUERY_KEYS, what)
        try:
            for frame in (q["source"], q["target"]):
                g.check_frame(str(frame))
            rate = q.get("rate_hz")
            queries[str(q["name"])] = Query(
                str(q["source"]),
                str(q["target"]),
                evaluation=q.get("evaluation"),
                mode=str(q.get("mode", "pull")),
                rate_hz=None if rate is None else float(rate),
                time_offset_s=float(q.get("time_offset_ms", 0.0)) * 1e-3,
                fuse=bool(q.get("fuse", False)),
                static=bool(q.get("static", False)),
                exclude=tuple(str(e) for e in q.get("exclude", ())),
                name=str(q["name"]),
            )
        except (TypeError, ValueError) as exc:
            raise _err(source, q, f"{what}: {exc}") from exc
    return Setup(g, queries, recordings, source, inputs)


def load_setup(path: str | Path) -> Setup:
    """Read a YAML setup file; errors name the file and line."""
    path = Path(path)
    text = path.read_text()
    try:
        doc = yaml.load(text, Loader=_LineLoader)  # a SafeLoader subclass
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: invalid YAML: {exc}") from exc
    return parse_setup(doc, str(path), path.parent)
