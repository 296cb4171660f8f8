"""The query planner: a path (or independent paths) of the SRG -> a dataflow network.

Construction rules (thesis 7.4, figures 7.2-7.4):

1. Every measured edge gets a source and, directly behind it, a pose Kalman filter, so that all
   inputs of an inference can be asked for one common time (prediction or interpolation;
   section 9.2.2). ``align=False`` uses a latest-value buffer instead (the naive chain).
2. Consecutive static edges are chained once at planning time into one static node (two static
   edges infer a static relationship); an inverted static edge is inverted there too.
3. An edge walked against its direction is inverted once, at the cheapest place: a run of
   consecutive inverted edges is chained in forward order and the product inverted once
   (``B^-1 A^-1 = (A B)^-1``); an inverted sensor edge is inverted behind its filter.
4. The terms of a path are chained by one inference component.
5. With ``fuse`` and several independent paths, each path's inference is triggered by its
   slowest sensor and pushes into one fusion filter.
6. If the queried relationship is static but measured through moving edges, the path
   inference pushes into a Kalman filter with a static motion model: a static estimator.
7. Push delivery appends a sampler at the query's rate and time offset; pull delivery a
   ``get(t)`` sink.
8. Failover (a query's ``failover``, not with ``fuse`` or a static relationship): the best
   path found without the sensors of the better ones is a fallback, up to
   :data:`MAX_FALLBACKS`; the paths meet in a :class:`~trackflow.dataflow.PathSwitch` that
   answers from the best live one (thesis 2.4.4). A sensor's filter is shared by every path
   using it, so a fallback's filters are warm when it is switched to.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from os import PathLike

from ..errors import InputError, PlanError
from ..graph import MotionSpec, Path, Query, SpatialRelationshipGraph, infer_motion, select_paths
from ..math import UncertainPose
from ._failover import PathSwitch
from ._inertial import InertialKalmanFilter
from ._network import Network
from ._plan_node import PlanNode
from ._processing import Inference, Inversion, KalmanFilter, LatestValue, Sampler
from ._sinks import PullSink, Recorder
from ._sources import RecordingPlayer, StaticPose

__all__ = ["MAX_FALLBACKS", "Plan", "PlanNode", "plan_query"]

#: the most fallback paths a query's failover plans (rule 8)
MAX_FALLBACKS = 3
#: a sensor is down after this long without data when its input names no ``stale_ms`` [ns]
DEFAULT_STALE_NS = 500_000_000


@dataclass
class Plan:
    """A query's dataflow plan: nodes in data order, the chosen paths and the reasons."""

    query: Query
    paths: list[Path]
    scores: list[float]
    nodes: list[PlanNode]
    output: str
    relationship_static: bool
    #: failover's fallback paths (rule 8), best first, and their evaluations
    fallbacks: list[Path] = field(default_factory=list)
    fallback_scores: list[float] = field(default_factory=list)

    def node(self, node_id: str) -> PlanNode:
        for n in self.nodes:
            if n.id == node_id:
                return n
        raise PlanError(f"no node {node_id!r} in the plan")

    @property
    def sensors(self) -> frozenset[str]:
        """Every sensor (measured edge) the plan reads: its paths' and its fallbacks'."""
        return frozenset(n.params["edge"] for n in self.nodes if n.kind == "source")

    def count(self, kind: str) -> int:
        """Number of nodes of a kind."""
        return sum(1 for n in self.nodes if n.kind == kind)

    def explain(self) -> str:
        """Human-readable plan: chosen path(s) with their evaluation, then every node, its
        inputs and the construction rule that put it there."""
        q = self.query
        lines = [
            f"query {q.name}: T_{q.source}_{q.target}, {q.mode} delivery"
            + (f" at {q.rate_hz:g} Hz, offset {q.time_offset_s * 1e3:+g} ms" if q.rate_hz else "")
            + f", evaluation {q.evaluate.__name__}"
            + (", relationship static" if self.relationship_static else ""),
        ]
        for i, (p, s) in enumerate(zip(self.paths, self.scores), 1):
            lines.append(f"path {i} (score {s:.6g}): {p}")
        for i, (p, s) in enumerate(zip(self.fallbacks, self.fallback_scores), 1):
            lines.append(f"fallback {i} (score {s:.6g}): {p}")
        lines.append("dataflow:")
        for n in self.nodes:
            src = ", ".join(f"{i} ({m})" for i, m in n.inputs)
            lines.append(f"  {n.id}: {n.label()}" + (f" <- {src}" if src else ""))
            if n.why:
                lines.append(f"      because {n.why}")
        return "\n".join(lines)

    def to_dot(self) -> str:
        """Graphviz dot of the dataflow (pull connections dashed)."""
        out = [f'digraph "{self.query.name}" {{', "  rankdir=LR;", "  node [shape=box];"]
        for n in self.nodes:
            shape = ", shape=ellipse" if n.kind in ("source", "static") else ""
            out.append(f'  "{n.id}" [label="{n.id}\\n{n.label()}"{shape}];')
        for n in self.nodes:
            for i, mode in n.inputs:
                style = " [style=dashed]" if mode == "pull" else ""
                out.append(f'  "{i}" -> "{n.id}"{style};')
        out.append("}")
        return "\n".join(out) + "\n"

    def build(
        self,
        sources: Mapping[str, RecordingPlayer],
        *,
        callback: Callable | None = None,
        filter_factory: Callable | None = None,
        history_s: float = 1.0,
        network: Network | None = None,
        prefix: str = "",
        record: str | PathLike | None = None,
        on_switch: Callable | None = None,
    ) -> tuple[Network, Recorder | PullSink]:
        """Instantiate the plan.

        Parameters
        ----------
        sources : mapping edge name -> RecordingPlayer (or SimulatedSensor)
            One player per measured edge of the plan.
        callback : callable, optional
            Called with every pushed result (push delivery).
        network : Network, optional
            Add to an existing network (component names get ``prefix``). Sources and the
            Kalman filter behind each sensor are shared: a plan built into a network that
            already holds the filter of one of its sensors (same motion model, stamp offset,
            history and filter factory) pulls from that filter instead of running a second
            copy of it - the filter's state does not depend on who asks it, so every query gets
            the same answers as in a network of its own, for the cost of one filter.
        record : path, optional
            Push delivery: the application recorder also writes every result to this
            ``.tfrec`` file (``T_source_target`` of the query, with covariance).
        on_switch : callable, optional
            Failover: called with every :class:`~trackflow.dataflow.SwitchEvent` of the
            query's path switch.

        Returns
        -------
        (network, sink)
            ``sink`` is a :class:`Recorder` (push) or :class:`PullSink` (pull).
        """
        net = network if network is not None else Network()
        made: dict[str, object] = {}
        reused: set = set()
        for n in self.nodes:
            name = prefix + n.id
            p = n.params
            if n.kind == "source":
                edge = p["edge"]
                if edge not in sources:
                    raise PlanError(f"no recording or sensor given for measured edge {edge!r}")
                c = sources[edge]
                if c.name in net.components:
                    c = net.components[c.name]
                else:
                    net.add(c)
            elif n.kind == "imu source":  # an IMU on a body frame (dataflow/_inertial.py)
                if p["imu"] not in sources:
                    raise PlanError(f"no recording or sensor given for IMU {p['imu']!r}")
                c = sources[p["imu"]]
                c = net.components[c.name] if c.name in net.components else net.add(c)
            elif n.kind == "kalman":
                cls, extra = KalmanFilter, {"filter_factory": filter_factory}
                if "imu" in p:
                    cls, extra = InertialKalmanFilter, {"imu": p["imu"]}
                kf = cls(
                    name,
                    p["motion"],
                    role=p["role"],
                    history_s=history_s,
                    stamp_offset_ns=p.get("stamp_offset_ns", 0),
                    prior=p.get("prior"),
                    **extra,
                )
                shared = net.components.get(n.id) if "edge" in p else None
                if isinstance(shared, KalmanFilter) and shared.same_filter(kf):
                    c = shared  # the filter of a sensor serves every query of the network
                    reused.add(c)
                    if p["role"] not in c.role.split("+"):
                        c.role += "+" + p["role"]
                else:
                    if "edge" in p and n.id not in net.components:
                        kf.name = n.id  # a sensor's filter is named for the sensor alone
                    c = net.add(kf)
            elif n.kind == "latest":
                c = net.add(LatestValue(name))
            elif n.kind == "static":
                c = net.add(StaticPose(name, p["value"]))
            elif n.kind == "inversion":
                c = net.add(Inversion(name))
            elif n.kind == "inference":
                c = net.add(Inference(name))
            elif n.kind == "sampler":
                c = net.add(Sampler(name, p["rate_hz"], p["offset_ns"]))
            elif n.kind == "recorder":
                q = self.query
                c = net.add(Recorder(name, callback, path=record, source=q.source, target=q.target))
            elif n.kind == "pull sink":
                c = net.add(PullSink(name))
            elif n.kind == "switch":
                sensors = [
                    [(e, made[kf], p["stale_ns"].get(e, DEFAULT_STALE_NS)) for e, kf in path]
                    for path in p["sensors"]
                ]
                c = net.add(
                    PathSwitch(name, sensors, hold_ns=p["hold_ns"],
                               refused_down=p["refused_down"], on_switch=on_switch,
                               require=self.query.require, paths=p["paths"],
                               evaluate=self.query.evaluate if p["paths"] else None)
                )  # fmt: skip
            else:  # pragma: no cover - plan nodes are made by plan_query only
                raise InputError(f"unknown plan node kind {n.kind!r}")
            made[n.id] = c
            if c in reused:
                continue  # already wired by the plan that made it
            for i, mode in n.inputs:
                net.connect(made[i], c, mode=mode)
        return net, made[self.output]


def _stamp_offset_ns(edge) -> int:
    return int(round(edge.stamp_offset_s * 1e9))


def plan_query(graph: SpatialRelationshipGraph, query: Query, *, align: bool = True) -> Plan:
    """Plan the dataflow answering ``query`` (rules in the module docstring).

    Parameters
    ----------
    align : bool
        True: a Kalman filter behind every sensor (time-aligned chain). False: latest-value
        buffers (the naive chain that ignores measurement times), for comparison.

    Raises
    ------
    ValueError
        Unknown frames, no path, bad query.
    """
    paths = select_paths(graph, query)
    scores = [query.evaluate(p) for p in paths]
    # A relationship is static if the query says so or if any path consists of static edges
    # only (a rigid chain pins it down).
    rel_static = query.static or any([infer_motion(p).static for p in paths])
    b = _PlanBuilder(query, align, rel_static)
    path_nodes = [b.path(p, f"p{i + 1}" if len(paths) > 1 else "path") for i, p in enumerate(paths)]
    end = b.meeting(paths, path_nodes)
    fallbacks = []
    if query.failover and align and not query.fuse and not rel_static:
        fallbacks = _fallbacks(graph, query, paths[0])
    if fallbacks or (query.require is not None and not query.fuse and not rel_static):
        ends = [end] + [b.path(p, f"fallback{k}") for k, p in enumerate(fallbacks, 1)]
        end = b.switch([paths[0], *fallbacks], ends)
    return Plan(
        query, paths, scores, b.nodes, b.delivery(end), rel_static,
        fallbacks, [query.evaluate(p) for p in fallbacks],
    )  # fmt: skip


def _fallbacks(graph: SpatialRelationshipGraph, query: Query, best: Path) -> list[Path]:
    """Rule 8: the best path without the sensors of ``best`` and of the fallbacks before,
    while there is one (at most :data:`MAX_FALLBACKS`; a path of static edges only, always
    live, ends the list)."""
    out: list[Path] = []
    used = set(best.sensors)
    while used and len(out) < MAX_FALLBACKS:
        try:
            p = select_paths(graph, replace(query, exclude=(*query.exclude, *sorted(used))))[0]
        except (PlanError, InputError):
            break
        out.append(p)
        if not p.sensors:
            break
        used |= p.sensors
    return out


def _compose(edges) -> UncertainPose:
    """The product of static edges' values, in order."""
    value = None
    for e in edges:
        value = e.value() if value is None else value.compose(e.value())
    return value


class _PlanBuilder:
    """The nodes of one plan, added rule by rule (module docstring); ids are unique."""

    def __init__(self, query: Query, align: bool, relationship_static: bool):
        self.query, self.align, self.rel_static = query, align, relationship_static
        self.nodes: list[PlanNode] = []
        self.ids: set[str] = set()
        self.sensor_term: dict[str, str] = {}  # measured edge -> its filter (or buffer) node

    def add(self, node: PlanNode) -> str:
        """Append ``node`` (its id made unique with a ``_2``, ``_3``... suffix); its id."""
        base, k = node.id, 1
        while node.id in self.ids:
            k += 1
            node.id = f"{base}_{k}"
        self.ids.add(node.id)
        self.nodes.append(node)
        return node.id

    def sensor(self, edge) -> str:
        """Rule 1: source + filter (or naive buffer) of one measured edge, created once."""
        if edge.name in self.sensor_term:
            return self.sensor_term[edge.name]
        src = self.add(
            PlanNode(
                f"src_{edge.name}",
                "source",
                {"edge": edge.name},
                why=f"measured edge {edge.source}->{edge.target}",
            )
        )
        if not self.align:
            node = self.add(
                PlanNode(
                    f"latest_{edge.name}",
                    "latest",
                    {},
                    [(src, "push")],
                    why="naive chain: newest value, no time alignment",
                )
            )
        else:
            node = self.add(self._sensor_filter(edge, src))
        self.sensor_term[edge.name] = node
        return node

    def _sensor_filter(self, edge, src: str) -> PlanNode:
        """The Kalman filter behind a sensor, in the role the query needs of it."""
        if edge.motion.static:
            role = "buffer"
            why = "buffer for a sensor measuring a static relationship"
        else:
            role = (
                "interpolator" if self.rel_static or self.query.time_offset_s < 0 else "predictor"
            )
            why = (
                f"a dynamic sensor must be valid at any requested time (7.4, rule 1); "
                f"{edge.latency_s * 1e3:g} ms latency"
            )
        if edge.stamp_offset_s:
            why += f"; corrects the {edge.stamp_offset_s * 1e3:+g} ms timestamp offset"
        params = {
            "edge": edge.name,
            "motion": edge.motion,
            "role": role,
            "stamp_offset_ns": _stamp_offset_ns(edge),
        }
        return PlanNode(f"kf_{edge.name}", "kalman", params, [(src, "push")], why=why)

    def static(self, edges, inverted: bool = False) -> str:
        """Rules 2 and 3: a run of static edges chained (and inverted) once at planning time."""
        value = _compose(edges)
        names = "+".join(e.name for e in edges)
        if inverted:
            why = "inverted static edge(s): inverted once at planning time (rule 3)"
            return self.add(
                PlanNode(f"static_{names}_inv", "static", {"value": value.inverse()}, why=why)
            )
        why = (
            "static edge"
            if len(edges) == 1
            else "static edges chained once at planning time (static . static = static)"
        )
        return self.add(PlanNode(f"static_{names}", "static", {"value": value}, why=why))

    def inference(self, terms: list[str], tag: str) -> str:
        """Rule 4: one inference chaining ``terms`` (a single term needs none)."""
        if len(terms) == 1:
            return terms[0]
        return self.add(
            PlanNode(
                f"inference_{tag}",
                "inference",
                {},
                [(t, "pull") for t in terms],
                why="chains the terms of the path at one common time (rule 4)",
            )
        )

    def chain(self, edges, tag: str) -> str:
        """Forward (non-inverted) edges: sensors and folded static runs, chained (rule 4)."""
        terms: list[str] = []
        static_run: list = []
        for e in edges:
            if e.kind == "static":
                static_run.append(e)
                continue
            if static_run:
                terms.append(self.static(static_run))
                static_run = []
            terms.append(self.sensor(e))
        if static_run:
            terms.append(self.static(static_run))
        return self.inference(terms, tag)

    def inverted(self, edges, tag: str) -> str:
        """Rule 3: a run of edges walked against their direction, inverted once: its product
        in forward order, then one inversion (``B^-1 A^-1 = (A B)^-1``)."""
        forward = list(reversed(edges))
        if all(e.kind == "static" for e in forward):
            return self.static(forward, inverted=True)
        inner = self.chain(forward, tag)
        what = (
            "the product of a run of inverted edges"
            if len(forward) > 1
            else f"edge {forward[0].name} walked against its direction"
        )
        return self.add(
            PlanNode(
                f"inv_{inner}",
                "inversion",
                {},
                [(inner, "pull")],
                why=f"{what}: one inversion at the cheapest place (rule 3)",
            )
        )

    def path(self, path: Path, tag: str) -> str:
        """One path: runs of equal direction, each chained or inverted, then chained."""
        runs: list[tuple[bool, list]] = []
        for s in path.steps:
            if runs and runs[-1][0] == s.inverted:
                runs[-1][1].append(s.edge)
            else:
                runs.append((s.inverted, [s.edge]))
        if len(runs) == 1:
            inverted, edges = runs[0]
            return self.inverted(edges, tag) if inverted else self.chain(edges, tag)
        terms = [
            self.inverted(edges, f"{tag}_{k}") if inverted else self.chain(edges, f"{tag}_{k}")
            for k, (inverted, edges) in enumerate(runs)
        ]
        return self.inference(terms, tag)

    def meeting(self, paths: list[Path], path_nodes: list[str]) -> str:
        """Rules 5 and 6: where the paths end: a static estimator, a fusion filter, or the
        (single) path itself."""
        dynamic = [(p, n) for p, n in zip(paths, path_nodes) if p.sensors]
        if self.rel_static and dynamic:
            why = (
                "the queried relationship is static: a Kalman filter with a static motion "
                "model averages all inferred measurements (rule 6, 7.4.1)"
            )
            end = self.estimator(
                dynamic, MotionSpec.make_static(), "static_estimator", "static estimator", why
            )
            static_paths = [p for p in paths if not p.sensors]
            if static_paths:
                est = self.nodes[-1]
                est.params["prior"] = static_paths[0].value()
                est.why += f"; the static path {static_paths[0]} enters as its prior"
            return end
        if len(dynamic) > 1:
            why = f"{len(paths)} independent paths meet: one fusion filter (rule 5)"
            return self.estimator(dynamic, infer_motion(dynamic[0][0]), "fusion", "fusion", why)
        return path_nodes[0]

    def estimator(self, dynamic_paths, motion, node_id, role, why) -> str:
        """A filter fed by push-triggered path inferences (fusion or static estimation): each
        path is evaluated whenever its slowest sensor delivers."""
        inputs = []
        by_id = {n.id: n for n in self.nodes}
        for p, n in dynamic_paths:
            slowest = min(
                (s.edge for s in p.steps if s.edge.kind == "measured"),
                key=lambda e: (e.rate_hz, e.name),
            )
            term = self.sensor_term[slowest.name]
            trig = term if by_id[term].kind == "kalman" else by_id[term].inputs[0][0]
            node = by_id[n]
            note = f"; triggered whenever its slowest sensor {slowest.name} delivers"
            if node.kind == "inference":
                node.inputs.append((trig, "push"))
                node.why += note
                trigger = n
            else:
                trigger = self.add(
                    PlanNode(
                        f"trigger_{n}",
                        "inference",
                        {},
                        [(n, "pull"), (trig, "push")],
                        why="evaluates the path" + note,
                    )
                )
            inputs.append((trigger, "push"))
        return self.add(
            PlanNode(node_id, "kalman", {"motion": motion, "role": role}, inputs, why=why)
        )

    def switch(self, paths: list[Path], ends: list[str]) -> str:
        """Rule 8: the path switch over the preferred path's end and its fallbacks'."""
        sensors = [[(e, self.sensor_term[e]) for e in sorted(p.sensors)] for p in paths]
        q = self.query
        params = {
            "sensors": sensors,
            "stale_ns": {},  # per sensor, from its input's stale_ms (Setup.plan)
            "hold_ns": int(round(q.hold_s * 1e9)),
            "refused_down": q.refused_down,
            # re-scored with the measured attributes while running (unless the query says not)
            "paths": list(paths) if q.rescore else None,
        }
        why = (
            f"failover: {len(paths) - 1} fallback path(s) sharing no sensor with a better one; "
            "answers from the best live path (rule 8)"
        )
        if q.require is not None:
            why += "; checks every answer against the query's requirements"
        return self.add(PlanNode("switch", "switch", params, [(n, "pull") for n in ends], why))

    def delivery(self, end: str) -> str:
        """Rule 7: a sampler and the application's recorder (push), or a pull sink."""
        q = self.query
        if q.mode == "push":
            offset_ns = int(round(q.time_offset_s * 1e9))
            s = self.add(
                PlanNode(
                    "sampler",
                    "sampler",
                    {"rate_hz": float(q.rate_hz), "offset_ns": offset_ns},
                    [(end, "pull")],
                    why="push delivery at a fixed rate (rule 7)",
                )
            )
            return self.add(PlanNode("app", "recorder", {}, [(s, "push")], why="the application"))
        return self.add(
            PlanNode(
                "app", "pull sink", {}, [(end, "pull")], why="the application pulls get(t) (rule 7)"
            )
        )
