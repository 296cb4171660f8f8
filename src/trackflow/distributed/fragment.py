"""An agent's fragment of the spatial relationship graph as JSON (abilities, thesis 2.2).

The fragment lists the edges an agent can provide: measured edges (its sensors) with every
quality attribute, and static edges with their pose and covariance. It is metadata, small and
rare, so it travels as JSON (``{"version": 1, "agent": ..., "edges": [...]}``); measurements
use the binary encoding of :mod:`trackflow.distributed.wire`. A sensor with a live input also
carries its ``stale_s`` (the input's ``stale_ms``): how long it may send nothing before it
counts as down, which the agents that use it judge it by (:func:`fragment_stale`).
"""

from __future__ import annotations

import json
import math

import numpy as np

from ..errors import FormatError
from ..graph import Edge, MotionSpec, SpatialRelationshipGraph
from ..math import Pose

__all__ = [
    "FRAGMENT_VERSION",
    "edge_from_dict",
    "edge_to_dict",
    "first_fragment",
    "fragment_json",
    "fragment_stale",
    "parse_fragment",
]

FRAGMENT_VERSION = 1


def edge_to_dict(edge: Edge) -> dict:
    """Plain-JSON description of an edge (covariance as a 6x6 list, metres and radians)."""
    m = edge.motion
    d = {
        "name": edge.name,
        "source": edge.source,
        "target": edge.target,
        "kind": edge.kind,
        "latency_s": edge.latency_s,
        "rate_hz": None if math.isinf(edge.rate_hz) else edge.rate_hz,
        "confidence": edge.confidence,
        "covariance": edge.covariance.tolist(),
        "cost": edge.cost,
        "motion": {
            "static": m.static,
            "n_dp": int(m.n_dp),
            "n_do": int(m.n_do),
            "noise": list(m.noise) if isinstance(m.noise, tuple) else float(m.noise),
        },
        "stamp_offset_s": edge.stamp_offset_s,
    }
    if edge.pose is not None:
        d["pose"] = {
            "position": edge.pose.position.tolist(),
            "quaternion": edge.pose.quaternion.tolist(),
        }
    return d


def edge_from_dict(d: dict) -> Edge:
    """Inverse of :func:`edge_to_dict`; raises ``ValueError`` naming the edge and the problem."""
    if not isinstance(d, dict):
        raise FormatError("fragment edge must be a mapping")
    name = d.get("name", "?")
    try:
        m = d["motion"]
        noise = m["noise"]
        motion = (
            MotionSpec.make_static()
            if m["static"]
            else MotionSpec(
                static=False,
                n_dp=int(m["n_dp"]),
                n_do=int(m["n_do"]),
                noise=tuple(float(v) for v in noise) if isinstance(noise, list) else float(noise),
            )
        )
        pose = None
        if "pose" in d:
            pose = Pose(d["pose"]["position"], d["pose"]["quaternion"], normalize=True)
        rate = d.get("rate_hz")
        return Edge(
            str(d["source"]),
            str(d["target"]),
            str(name),
            kind=str(d["kind"]),
            latency_s=float(d["latency_s"]),
            rate_hz=math.inf if rate is None else float(rate),
            confidence=float(d["confidence"]),
            covariance=np.asarray(d["covariance"], dtype=float),
            cost=float(d["cost"]),
            motion=motion,
            pose=pose,
            stamp_offset_s=float(d.get("stamp_offset_s", 0.0)),
        )
    except (KeyError, TypeError) as exc:
        raise FormatError(f"fragment edge {name!r}: missing or malformed field {exc}") from None
    except ValueError as exc:
        raise FormatError(f"fragment edge {name!r}: {exc}") from None


def fragment_json(agent: str, graph: SpatialRelationshipGraph, frames=(), stale_s=None) -> bytes:
    """The JSON fragment of ``graph`` offered by ``agent`` (UTF-8 bytes); ``stale_s``: the
    sensors' liveness windows [s] by name (those with a live input)."""
    stale_s = stale_s or {}
    edges = []
    for e in graph.edges:
        d = edge_to_dict(e)
        if e.name in stale_s:
            d["stale_s"] = float(stale_s[e.name])
        edges.append(d)
    doc = {
        "version": FRAGMENT_VERSION,
        "agent": agent,
        "frames": sorted(set(frames) | set(graph.frames)),
        "edges": edges,
    }
    return json.dumps(doc).encode()


def fragment_stale(data: bytes) -> dict[str, float]:
    """The liveness windows [s] a fragment advertises, by sensor name (a parsed fragment,
    :func:`parse_fragment`; a malformed or non-positive window is left out)."""
    out = {}
    for d in json.loads(bytes(data).decode())["edges"]:
        v, name = d.get("stale_s"), d.get("name")
        if isinstance(v, (int, float)) and not isinstance(v, bool) and 0 < v < math.inf:
            if isinstance(name, str):
                out[name] = float(v)
    return out


def first_fragment(replies, rejections) -> tuple[list[str], list[Edge], bytes] | None:
    """The first fragment among a Zenoh get's ``replies`` that parses: ``(frames, edges,
    its bytes)``; each one that does not is counted in ``rejections`` ("malformed
    fragment"). ``None`` if none came."""
    for reply in replies:
        if reply.ok is None:
            continue
        data = reply.ok.payload.to_bytes()
        try:
            _, frames, edges = parse_fragment(data)
        except ValueError:
            rejections.add("malformed fragment")
            continue
        return frames, edges, data
    return None


def parse_fragment(data: bytes) -> tuple[str, list[str], list[Edge]]:
    """``(agent, frames, edges)`` of a JSON fragment; ``ValueError`` on anything malformed."""
    try:
        doc = json.loads(bytes(data).decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FormatError(f"fragment is not JSON: {exc}") from None
    if not isinstance(doc, dict) or doc.get("version") != FRAGMENT_VERSION:
        version = doc.get("version") if isinstance(doc, dict) else None
        raise FormatError(f"unknown fragment version {version!r}")
    agent = doc.get("agent")
    frames = doc.get("frames", [])
    edges = doc.get("edges")
    if not isinstance(agent, str) or not isinstance(frames, list) or not isinstance(edges, list):
        raise FormatError("fragment needs 'agent' (string), 'frames' and 'edges' (lists)")
    return agent, [str(f) for f in frames], [edge_from_dict(e) for e in edges]
