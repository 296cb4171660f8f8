"""A realm's agent files as one setup, offline: what the agents' union graph would be.

``trackflow plan tracker.yaml camera.yaml app.yaml --query q`` (and any caller of
:func:`realm_setup`) sees every frame, sensor and static of the files in one graph and every
query of them, as the agents do once they have discovered each other, without starting a
Zenoh session. A sensor or a query named in two files is refused, naming both; so are
statics of different files that contradict each other
(:class:`trackflow.dataflow.StaticLoops`).
"""

from __future__ import annotations

from pathlib import Path

from ..dataflow import Setup, StaticLoops, load_setup
from ..errors import ConfigError
from ..graph import SpatialRelationshipGraph
from ..yamlfile import read_yaml
from .config import load_agent

__all__ = ["is_agent_file", "load_any_setup", "realm_setup"]


def is_agent_file(path) -> bool:
    """Whether ``path`` is a YAML agent file (a mapping with an ``agent:`` key)."""
    path = Path(path)
    if path.suffix.lower() not in (".yaml", ".yml") or not path.is_file():
        return False
    doc = read_yaml(path)
    return isinstance(doc, dict) and "agent" in doc


def load_any_setup(path) -> tuple[Setup, str | None]:
    """A setup file, or an agent file's setup: ``(setup, agent name or None)``."""
    path = Path(path)
    doc = read_yaml(path)
    if isinstance(doc, dict) and "agent" in doc:
        cfg = load_agent(path)
        return cfg.setup, cfg.name
    return load_setup(path), None


def realm_setup(paths) -> Setup:
    """One setup of the setups or agent files ``paths`` (module docstring)."""
    g = SpatialRelationshipGraph()
    queries, recordings, inputs, imus, lines, ros2 = {}, {}, {}, {}, {}, {}
    owner: dict[str, str] = {}
    loops = StaticLoops()
    for path in paths:
        setup, _ = load_any_setup(path)
        for f in setup.graph.frames:
            g.add_frame(f)
        for e in setup.graph.edges:
            if e.name in owner:
                raise ConfigError(f"{path}: edge {e.name!r} is also in {owner[e.name]}")
            owner[e.name] = str(path)
            g.add_edge(e)
            if e.kind == "static":
                why = loops.add(e.name, e.source, e.target, e.pose, e.covariance)
                if why is not None:
                    raise ConfigError(f"{path}: {why}")
        for name, q in setup.queries.items():
            if name in queries:
                raise ConfigError(f"{path}: query {name!r} is also in {owner['q:' + name]}")
            owner["q:" + name] = str(path)
            queries[name] = q
        recordings.update(setup.recordings)
        inputs.update(setup.inputs)
        imus.update(setup.imus)
        lines.update(setup.lines)
        ros2.update(setup.ros2)
    source = " + ".join(str(p) for p in paths)
    return Setup(g, queries, recordings, source, inputs, imus, lines, ros2)
