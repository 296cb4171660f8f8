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
      - {name: view, source: P, target: M, mode: push, rate_hz: 60, time_offset_ms: 0,
         ros2: {topic: /trackflow/view}}   # optional: answers as a ROS 2 topic (docs/ros2.md)
    include: [calib/hand_eye.yaml]      # optional setup fragments (trackflow calibrate ...)

A fragment (written by ``trackflow calibrate ... --fragment``) holds ``statics`` entries, which
are added, and ``sensors`` entries that name an existing sensor and replace some of its keys
(``stamp_offset_ms``, ``latency_ms``, ``covariance``, ``sigma_pos_mm``, ``sigma_ori_deg``).

Everything a file can say can also be built in Python with
:class:`trackflow.graph.SpatialRelationshipGraph` and :class:`trackflow.graph.Query`.
The file is read by :func:`trackflow.yamlfile.read_yaml` (a key given twice is refused).
Mistakes raise :class:`trackflow.errors.ConfigError` (a ``ValueError``) naming the file, the
line and the key.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ConfigError, PlanError
from ..graph import MotionSpec, Query, Requirements, SpatialRelationshipGraph
from ..math import Pose
from ..yamlfile import YamlMap, line_of, read_yaml
from ._online_spec import OnlineOffsetSpec
from ._planner import Plan, plan_query
from ._sources import RecordingPlayer
from ._static_loops import StaticLoops

__all__ = ["Setup", "load_setup", "parse_setup"]


@dataclass
class Setup:
    """A parsed setup: the SRG, named queries and the recordings of measured edges."""

    graph: SpatialRelationshipGraph
    queries: dict[str, Query] = field(default_factory=dict)
    recordings: dict[str, Path] = field(default_factory=dict)
    source: str = "<python>"
    #: live inputs of sensors: name -> :class:`trackflow.dataflow.InputSpec`
    inputs: dict = field(default_factory=dict)
    imus: dict = field(default_factory=dict)  # name -> ImuSpec (dataflow/_inertial.py)
    #: line of each entry in the file: ``"sensors.<name>"``, ``"queries.<name>"`` -> line
    lines: dict = field(default_factory=dict)
    #: push queries whose answers go to a ROS 2 topic: name -> :class:`Ros2Output`
    ros2: dict = field(default_factory=dict)
    #: the ``online_offsets:`` block (:class:`OnlineOffsetSpec`), ``None`` if absent
    online_offsets: OnlineOffsetSpec | None = None

    def refuse_online_offsets(self, mode: str) -> None:
        """Raise :class:`~trackflow.errors.ConfigError` naming the file, line and key if the
        setup has an ``online_offsets:`` block: ``mode`` (such as "an agent") cannot honour
        it, only ``trackflow run`` does."""
        if self.online_offsets is not None:
            raise ConfigError(
                f"{mode} does not estimate or apply online offsets (only trackflow run "
                "does); remove the block",
                self.source,
                self.lines.get("online_offsets", 0),
                "online_offsets",
            )

    def query(self, name: str | None = None) -> Query:
        """The query called ``name`` (the first one if ``None``)."""
        if not self.queries:
            raise PlanError(f"{self.source}: the setup defines no queries")
        if name is None:
            return next(iter(self.queries.values()))
        if name not in self.queries:
            raise PlanError(f"{self.source}: no query {name!r} (have {list(self.queries)})")
        return self.queries[name]

    def plan(
        self,
        query: Query | str | None = None,
        align: bool = True,
        graph: SpatialRelationshipGraph | None = None,
    ) -> Plan:
        """Plan a query of this setup (a :class:`Query`, a query name, or the first).

        ``graph``: plan on this graph instead of the setup's own (an agent's union of the
        realm's fragments); the setup's IMUs are attached all the same.
        """
        q = query if isinstance(query, Query) else self.query(query)
        graph = self.graph if graph is None else graph
        try:
            plan = plan_query(graph, q, align=align)
        except ValueError as exc:
            raise PlanError(f"{self.source}: {exc}") from None
        if self.imus and align:
            from ._inertial import attach_imus

            attach_imus(plan, graph, self.imus)
        for node in plan.nodes:  # failover: each sensor is down after its input's stale_ms
            if node.kind == "switch":
                for path in node.params["sensors"]:
                    for e, _ in path:
                        if e in self.inputs:
                            node.params["stale_ns"][e] = int(round(self.inputs[e].stale_s * 1e9))
        return plan

    def players(self) -> dict[str, RecordingPlayer]:
        """Players for every measured edge with a recording (read with ``trackflow.io``)."""
        from ..io import read_stream

        out = {}
        for name, path in self.recordings.items():
            edge = self.graph.edge(name)
            stream, _ = read_stream(path)
            out[name] = RecordingPlayer.from_stream(
                name, stream, int(round(edge.latency_s * 1e9)), covariance=edge.covariance
            )
        if self.imus:
            from ..io import read_imu
            from ._inertial import ImuPlayer

            for name, spec in self.imus.items():
                if spec.recording is not None:
                    imu, _ = read_imu(spec.recording)
                    out[name] = ImuPlayer(name, imu, spec.latency_ns, spec.clock_offset_ns)
        return out


def _err(src: str, item, msg: str) -> ConfigError:
    """The error of ``item`` (a mapping of ``src``): the file, the line of ``item``, ``msg``."""
    return ConfigError(msg, src, line_of(item))


def _cov(src, item, what) -> np.ndarray:
    if "covariance" in item:
        c = np.asarray(item["covariance"], dtype=float)
        if c.shape != (6, 6):
            raise _err(src, item, f"{what}: covariance must be a 6x6 list of lists")
        return c
    sp = np.asarray(item.get("sigma_pos_mm", 0.0), float)
    so = np.asarray(item.get("sigma_ori_deg", 0.0), float)
    for key, v in (("sigma_pos_mm", sp), ("sigma_ori_deg", so)):
        if v.ndim > 1 or v.size not in (1, 3) or not np.all(np.isfinite(v)) or np.any(v < 0):
            raise _err(
                src, item, f"{what}: {key} must be one or three finite values >= 0, got "
                f"{item.get(key)!r}"
            )  # fmt: skip
    sp = np.broadcast_to(sp * 1e-3, (3,))
    so = np.radians(np.broadcast_to(so, (3,)))
    return np.diag(np.concatenate([sp**2, so**2]))


def _name(src, item, key: str, what: str) -> str:
    """A frame or edge name: a non-empty string without surrounding blanks."""
    v = item[key]
    if not isinstance(v, (str, int)) or isinstance(v, bool) or not str(v).strip():
        raise _err(src, item, f"{what}: {key} must be a non-empty name, got {v!r}")
    if str(v) != str(v).strip():
        raise _err(src, item, f"{what}: {key} {v!r} has leading or trailing blanks")
    return str(v)


def _frame(src, item, key: str, what: str, declared: set[str] | None) -> str:
    """A frame name, which must be one of ``frames:`` when the setup declares them."""
    name = _name(src, item, key, what)
    if declared is not None and name not in declared:
        raise _err(
            src, item, f"{what}: {key} frame {name!r} is not declared in frames: "
            f"{sorted(declared)}"
        )  # fmt: skip
    return name


def _motion(src, item, what) -> MotionSpec:
    m = item.get("motion", {"n_dp": 1, "n_do": 1})
    if m == "static":
        return MotionSpec.make_static()
    if not isinstance(m, dict):
        raise _err(src, item, f"{what}: motion must be 'static' or a mapping")
    unknown = set(m) - {"n_dp", "n_do", "noise"}
    if unknown:
        raise _err(src, m or item, f"{what}: unknown motion keys {sorted(unknown)}")
    n_dp, n_do = int(m.get("n_dp", 1)), int(m.get("n_do", 1))
    noise = m.get("noise", 1.0)
    if isinstance(noise, list):
        noise = tuple(float(v) for v in noise)
        need = (n_dp + 1) + (n_do + 1)
        if len(noise) not in (2, need):
            raise _err(
                src, m, f"{what}: motion noise needs one value per part (2: the highest "
                f"position and orientation levels) or per level ((n_dp + 1) + (n_do + 1) = "
                f"{need} for n_dp={n_dp}, n_do={n_do}); got {len(noise)}"
            )  # fmt: skip
    else:
        noise = float(noise)
    values = noise if isinstance(noise, tuple) else (noise,)
    if not all(np.isfinite(v) and v >= 0 for v in values):
        raise _err(src, m, f"{what}: motion noise must be finite and >= 0, got {m['noise']!r}")
    return MotionSpec(static=False, n_dp=n_dp, n_do=n_do, noise=noise)


#: Largest accepted ``| |q| - 1 |`` of a static quaternion in a setup (4 printed decimals).
STATIC_UNIT_TOLERANCE = 1e-3

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
    "failover",
    "require",
    "ros2",
}
_FAILOVER_KEYS = {"hold_ms", "refused_down", "rescore"}


def _require(src, q, what) -> Requirements | None:
    """A query's ``require:`` (``{max_latency_ms, max_sigma_pos_mm, max_sigma_ori_deg,
    min_rate_hz}``) as :class:`~trackflow.graph.Requirements`."""
    doc = q.get("require")
    if doc is None:
        return None
    if not isinstance(doc, dict):
        raise _err(src, q, f"{what}.require: expected a mapping")
    try:
        return Requirements.from_units(doc)
    except ValueError as exc:
        raise _err(src, q, f"{what}.{exc}") from None


def _failover(src, q, what) -> dict:
    """A query's ``failover:`` (``false``, ``true`` or ``{hold_ms, refused_down, rescore}``)
    as :class:`~trackflow.graph.Query` keywords."""
    spec = q.get("failover", True)
    if isinstance(spec, bool):
        return {"failover": spec}
    if not isinstance(spec, dict):
        raise _err(src, q, f"{what}.failover: expected true, false or a mapping")
    unknown = set(spec) - _FAILOVER_KEYS
    if unknown:
        raise _err(src, q, f"{what}.failover: unknown keys {sorted(unknown, key=str)} "
                           f"(allowed: {sorted(_FAILOVER_KEYS)})")  # fmt: skip
    out: dict = {"failover": True}
    if "hold_ms" in spec:
        out["hold_s"] = float(spec["hold_ms"]) * 1e-3
    if "refused_down" in spec:
        n = spec["refused_down"]
        if isinstance(n, bool) or not isinstance(n, int):
            raise _err(src, q, f"{what}.failover.refused_down: expected an integer, got {n!r}")
        out["refused_down"] = n
    if "rescore" in spec:
        if not isinstance(spec["rescore"], bool):
            raise _err(src, q, f"{what}.failover.rescore: expected true or false, "
                               f"got {spec['rescore']!r}")  # fmt: skip
        out["rescore"] = spec["rescore"]
    return out


def _check_keys(src, item, allowed, what):
    if not isinstance(item, dict):
        raise _err(src, item, f"{what} must be a mapping")
    unknown = set(item) - allowed
    if unknown:
        raise _err(
            src, item, f"{what}: unknown keys {sorted(unknown, key=str)} (allowed: "
            f"{sorted(allowed)})"
        )  # fmt: skip
    for key in ("name", "source", "target"):
        if key not in item:
            raise _err(src, item, f"{what}: missing key {key!r}")


_FRAGMENT_SENSOR_KEYS = {
    "name",
    "stamp_offset_ms",
    "latency_ms",
    "covariance",
    "sigma_pos_mm",
    "sigma_ori_deg",
}


def _copy_map(item):
    if isinstance(item, YamlMap):
        return item.copy()
    return dict(item) if isinstance(item, dict) else item


def _apply_includes(doc: dict, source: str, base_dir: Path | None) -> dict:
    """Merge the fragments listed under ``include:`` into a copy of ``doc``."""
    inc = doc.get("include") or []
    if isinstance(inc, str):
        inc = [inc]
    if not isinstance(inc, list):
        raise _err(source, doc, "include must be a file name or a list of file names")
    out = dict(doc)
    out.pop("include", None)
    statics = list(out.get("statics") or [])
    sensors = [_copy_map(s) for s in out.get("sensors") or []]
    for name in inc:
        path = Path(str(name))
        path = path if path.is_absolute() or base_dir is None else base_dir / path
        if not path.is_file():
            raise _err(source, doc, f"include: fragment {path} not found")
        frag = read_yaml(path)
        if not isinstance(frag, dict) or set(frag) - {"statics", "sensors"}:
            raise ConfigError(f"{path}: a fragment is a mapping with 'statics' and/or 'sensors'")
        statics += list(frag.get("statics") or [])
        for i, upd in enumerate(frag.get("sensors") or []):
            if not isinstance(upd, dict) or "name" not in upd:
                raise _err(str(path), upd, f"sensors[{i}]: needs the name of a sensor to update")
            unknown = set(upd) - _FRAGMENT_SENSOR_KEYS
            if unknown:
                allowed = sorted(_FRAGMENT_SENSOR_KEYS)
                msg = f"sensors[{i}]: keys {sorted(unknown)} cannot be set by a fragment"
                raise _err(str(path), upd, f"{msg} (allowed: {allowed})")
            match = [s for s in sensors if isinstance(s, dict) and s.get("name") == upd["name"]]
            if not match:
                raise _err(str(path), upd, f"sensors[{i}]: no sensor named {upd['name']!r}")
            if "covariance" in upd:  # a covariance replaces sigma_* and vice versa
                for k in ("sigma_pos_mm", "sigma_ori_deg"):
                    match[0].pop(k, None)
            if {"sigma_pos_mm", "sigma_ori_deg"} & set(upd):
                match[0].pop("covariance", None)
            match[0].update({k: v for k, v in upd.items() if k != "name"})
    out["statics"], out["sensors"] = statics, sensors
    return out


def parse_setup(doc, source: str = "<setup>", base_dir: Path | None = None) -> Setup:
    """Build a :class:`Setup` from a parsed YAML document (a mapping)."""
    if not isinstance(doc, dict):
        raise ConfigError(f"{source}: a setup must be a mapping with sensors/statics/queries")
    unknown = set(doc) - {
        "frames",
        "sensors",
        "statics",
        "queries",
        "include",
        "imus",
        "online_offsets",
    }
    if unknown:
        raise _err(source, doc, f"unknown top-level keys {sorted(unknown)}")
    if "include" in doc:
        doc = _apply_includes(doc, source, base_dir)
    g = SpatialRelationshipGraph()
    frames = doc.get("frames")
    declared: set[str] | None = None
    if frames is not None:
        if not isinstance(frames, list):
            raise _err(
                source, doc, f"frames must be a list such as [P, A, T], got {frames!r}"
            )  # fmt: skip
        declared = set()
        for f in frames:
            entry = YamlMap(frame=f)
            entry.line = line_of(doc, "frames")
            name = _name(source, entry, "frame", "frames")
            if name in declared:
                raise _err(source, doc, f"frames: {name!r} is listed twice")
            declared.add(name)
            g.add_frame(name)
    recordings: dict[str, Path] = {}
    inputs: dict = {}
    lines: dict[str, int] = {}
    for i, s in enumerate(doc.get("sensors") or []):
        what = f"sensors[{i}]"
        _check_keys(source, s, _SENSOR_KEYS, what)
        name = _name(source, s, "name", what)
        lines[f"sensors.{name}"] = getattr(s, "line", 0)
        src_f = _frame(source, s, "source", what, declared)
        tgt_f = _frame(source, s, "target", what, declared)
        cov, motion = _cov(source, s, what), _motion(source, s, what)
        try:
            g.add_measured(
                name,
                src_f,
                tgt_f,
                latency_s=float(s.get("latency_ms", 0.0)) * 1e-3,
                rate_hz=float(s.get("rate_hz", 30.0)),
                confidence=float(s.get("confidence", 1.0)),
                cost=float(s.get("cost", 0.0)),
                covariance=cov,
                motion=motion,
                stamp_offset_s=float(s.get("stamp_offset_ms", 0.0)) * 1e-3,
            )
        except (TypeError, ValueError) as exc:
            raise _err(source, s, f"{what}: {exc}") from exc
        if "recording" in s:
            p = Path(str(s["recording"]))
            recordings[str(s["name"])] = p if p.is_absolute() or base_dir is None else base_dir / p
        if "input" in s:
            from ._inputs import parse_input

            try:
                inputs[str(s["name"])] = parse_input(s["input"], base_dir)
            except ValueError as exc:
                raise _err(source, s.get("input") or s, f"{what}: {exc}") from exc
    loops = StaticLoops()
    for i, s in enumerate(doc.get("statics") or []):
        what = f"statics[{i}]"
        _check_keys(source, s, _STATIC_KEYS, what)
        name = _name(source, s, "name", what)
        src_f = _frame(source, s, "source", what, declared)
        tgt_f = _frame(source, s, "target", what, declared)
        cov = _cov(source, s, what)
        try:
            q = np.asarray(s.get("quaternion", [0, 0, 0, 1]), dtype=float)
            if q.shape != (4,) or not np.all(np.isfinite(q)):
                raise ConfigError(f"quaternion must be 4 finite numbers (x, y, z, w), got {q}")
            if abs(np.linalg.norm(q) - 1.0) > STATIC_UNIT_TOLERANCE:
                raise ConfigError(
                    f"quaternion {q.tolist()} has norm {np.linalg.norm(q):.6g}, not unit "
                    f"(allowed deviation {STATIC_UNIT_TOLERANCE:g}, for rounded digits)"
                )
            pose = Pose(s.get("position", [0, 0, 0]), q, normalize=True)
            g.add_static(name, src_f, tgt_f, pose, cov)
        except (TypeError, ValueError) as exc:
            raise _err(source, s, f"{what}: {exc}") from exc
        why = loops.add(name, src_f, tgt_f, pose, g.edge(name).covariance)
        if why is not None:
            raise _err(source, s, f"{what}: {why}")
    queries: dict[str, Query] = {}
    ros2: dict = {}
    for i, q in enumerate(doc.get("queries") or []):
        what = f"queries[{i}]"
        _check_keys(source, q, _QUERY_KEYS, what)
        lines[f"queries.{_name(source, q, 'name', what)}"] = getattr(q, "line", 0)
        try:
            for frame in (_frame(source, q, "source", what, declared),
                          _frame(source, q, "target", what, declared)):  # fmt: skip
                g.check_frame(frame)
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
                **_failover(source, q, what),
                require=_require(source, q, what),
            )
        except (TypeError, ValueError) as exc:
            raise _err(source, q, f"{what}: {exc}") from exc
        if "ros2" in q:
            from ._ros2spec import parse_ros2_output

            query = queries[str(q["name"])]
            try:
                ros2[query.name] = parse_ros2_output(
                    q["ros2"], query.source, query.target, query.mode, base_dir
                )
            except ValueError as exc:
                raise ConfigError(f"{what}.{exc}", source, line_of(q, "ros2")) from exc
    imus = {}
    if doc.get("imus"):
        from ._inertial import parse_imus

        imus = parse_imus(source, doc["imus"], base_dir, lambda item, msg: _err(source, item, msg))
        for spec in imus.values():
            try:
                g.check_frame(spec.body)
            except ValueError as exc:
                raise _err(source, doc, f"IMU {spec.name}: {exc}") from exc
    online = None
    if "online_offsets" in doc:
        lines["online_offsets"] = line_of(doc, "online_offsets")
        try:
            online = OnlineOffsetSpec.from_mapping(doc["online_offsets"])
        except ValueError as exc:
            raise ConfigError(str(exc), source, lines["online_offsets"]) from exc
        if online.reference is not None and online.reference not in inputs:
            raise ConfigError(
                f"{online.reference!r} is not a sensor with an 'input:' (have {sorted(inputs)})",
                source,
                lines["online_offsets"],
                "online_offsets.reference",
            )
    return Setup(g, queries, recordings, source, inputs, imus, lines, ros2, online)


def load_setup(path: str | Path) -> Setup:
    """Read a YAML setup file; errors name the file and line."""
    path = Path(path)
    return parse_setup(read_yaml(path), str(path), path.parent)
