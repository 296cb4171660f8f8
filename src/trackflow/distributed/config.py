"""Agent configuration: the ``agent:`` section of an agent's YAML file and its Zenoh config.

An agent file is a trackflow setup (``sensors``, ``statics``, ``queries``, ``frames``; see
:func:`trackflow.dataflow.parse_setup`) plus one ``agent`` mapping::

    agent:
      name: tracker_host        # unique in the realm; letters, digits, _ and -
      realm: demo               # key space trackflow/<realm>/...
      zenoh:                    # Zenoh configuration keys (mode, listen, connect, ...)
        mode: peer
        listen: {endpoints: ["tcp/127.0.0.1:7447"]}
        connect: {endpoints: ["tcp/127.0.0.1:7448"]}
      zenoh_config: lan.json5   # or a complete Zenoh config file (TLS, access control)
      start_ns: 0               # recordings: recording time 0 plays at this agent-clock time
      reorder_ms: 0             # jitter buffer of push queries (0: deliver on arrival)
      clock_sync: estimate      # estimate: map remote stamps by a measured offset; none
      clock_offset_ms: 0        # shifts this agent's clock (emulates another host's clock)
      pull_via: replica         # pull queries read remote sensors from replicas of their
                                # filters (replica) or ask get/<edge> per request (get)
      thin: false               # push queries ask the sensors' agents for the states their
                                # ticks need only (needs reorder_ms > 0: the deadline of a tick)
      thin_grace_ms: 1.0        # (sensor side, recordings) a played state is the newest
                                # before a tick once the clock is this far past the tick
                                # (and the player has played every sample due by the tick)

Without ``zenoh_config`` the defaults are safe for one machine: peer mode, listening on
``tcp/127.0.0.1:0`` (loopback, a free port), multicast scouting off, and connection attempts
retried every 0.25-1 s (agents may start in any order).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from ..dataflow import Setup, parse_setup

__all__ = ["AgentConfig", "load_agent", "zenoh_config"]

_NAME = re.compile(r"^[A-Za-z0-9_-]+$")
_AGENT_KEYS = {
    "name",
    "realm",
    "zenoh",
    "zenoh_config",
    "start_ns",
    "reorder_ms",
    "clock_sync",
    "clock_offset_ms",
    "pull_via",
    "thin",
    "thin_grace_ms",
}
DEFAULT_ZENOH = {
    "mode": "peer",
    "listen": {"endpoints": ["tcp/127.0.0.1:0"]},
    # agents may start in any order: retry connecting every 0.25 s .. 1 s
    "connect": {
        "retry": {"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2}
    },
    "scouting": {"multicast": {"enabled": False}},
}


@dataclass
class AgentConfig:
    """Everything an :class:`trackflow.distributed.Agent` needs (see the module docstring)."""

    name: str
    setup: Setup
    realm: str = "default"
    zenoh: dict = field(default_factory=dict)
    zenoh_config: Path | None = None
    start_ns: int = 0
    reorder_ms: float = 0.0
    clock_sync: str = "estimate"
    clock_offset_ms: float = 0.0
    pull_via: str = "replica"
    thin: bool = False
    thin_grace_ms: float = 1.0

    def __post_init__(self):
        for what, value in (("name", self.name), ("realm", self.realm)):
            if not isinstance(value, str) or not _NAME.match(value):
                raise ValueError(f"agent {what} {value!r}: use letters, digits, '_' and '-'")
        for e in self.setup.graph.edges:
            if not _NAME.match(e.name):
                raise ValueError(f"edge name {e.name!r}: use letters, digits, '_' and '-'")
        if self.clock_sync not in ("estimate", "none"):
            raise ValueError(f"clock_sync must be 'estimate' or 'none', got {self.clock_sync!r}")
        if self.pull_via not in ("replica", "get"):
            raise ValueError(f"pull_via must be 'replica' or 'get', got {self.pull_via!r}")
        if not self.reorder_ms >= 0:
            raise ValueError(f"reorder_ms must be >= 0, got {self.reorder_ms}")
        if not isinstance(self.thin, bool):
            raise ValueError(f"thin must be true or false, got {self.thin!r}")
        if self.thin and not self.reorder_ms > 0:
            raise ValueError(
                "thin: true needs reorder_ms > 0 (thinned states come just after the tick "
                "they serve; reorder_ms is how long a tick may wait for them)"
            )
        if not 0 <= self.thin_grace_ms <= 1000:
            raise ValueError(f"thin_grace_ms must be in 0..1000, got {self.thin_grace_ms}")


def _insert(conf, key: str, value) -> None:
    """Set ``key`` (a ``a/b/c`` path) to ``value``: mappings key by key (so the other keys
    keep their defaults), or as a whole where Zenoh has no such sub-keys yet (a null
    default such as ``connect/retry``)."""
    import zenoh

    if isinstance(value, dict) and value:
        try:
            for k, v in value.items():
                _insert(conf, f"{key}/{k}", v)
            return
        except zenoh.ZError:
            pass
    conf.insert_json5(key, json.dumps(value))


def zenoh_config(cfg: AgentConfig):
    """The ``zenoh.Config`` of an agent: the file (if any), else the loopback defaults, then
    the ``zenoh`` keys of the agent file on top."""
    import zenoh

    if cfg.zenoh_config is not None:
        conf = zenoh.Config.from_file(str(cfg.zenoh_config))
        layers = [cfg.zenoh]
    else:
        conf = zenoh.Config()
        layers = [DEFAULT_ZENOH, cfg.zenoh]
    for layer in layers:
        for key, value in layer.items():
            try:
                _insert(conf, str(key), value)
            except zenoh.ZError as exc:
                raise ValueError(f"zenoh config key {key!r} = {value!r}: {exc}") from None
    return conf


def load_agent(path: str | Path) -> AgentConfig:
    """Read an agent YAML file (setup plus ``agent:`` section); errors name the file."""
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: invalid YAML: {exc}") from exc
    if not isinstance(doc, dict) or not isinstance(doc.get("agent"), dict):
        raise ValueError(f"{path}: an agent file needs an 'agent:' mapping (name, realm, ...)")
    a = doc.pop("agent")
    unknown = set(a) - _AGENT_KEYS
    if unknown:
        raise ValueError(
            f"{path}: agent: unknown keys {sorted(unknown)} (allowed: {sorted(_AGENT_KEYS)})"
        )
    if "name" not in a:
        raise ValueError(f"{path}: agent: missing key 'name'")
    setup = parse_setup(doc, str(path), path.parent)
    zc = a.get("zenoh_config")
    try:
        return AgentConfig(
            name=str(a["name"]),
            setup=setup,
            realm=str(a.get("realm", "default")),
            zenoh=dict(a.get("zenoh") or {}),
            zenoh_config=None if zc is None else (path.parent / str(zc)),
            start_ns=int(a.get("start_ns", 0)),
            reorder_ms=float(a.get("reorder_ms", 0.0)),
            clock_sync=str(a.get("clock_sync", "estimate")),
            clock_offset_ms=float(a.get("clock_offset_ms", 0.0)),
            pull_via=str(a.get("pull_via", "replica")),
            thin=a.get("thin", False),
            thin_grace_ms=float(a.get("thin_grace_ms", 1.0)),
        )
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: agent: {exc}") from exc
