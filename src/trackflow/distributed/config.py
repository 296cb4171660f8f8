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
      insecure: false           # allow links off this machine without TLS and access control

The file is read by :func:`trackflow.yamlfile.read_yaml`: a key given twice is refused, and
every mistake is a :class:`trackflow.errors.ConfigError` naming the file, the line and the key.

Without ``zenoh_config`` the defaults are safe for one machine: peer mode, listening on
``tcp/127.0.0.1:0`` (loopback, a free port), multicast scouting off, and connection attempts
retried every 0.25-1 s (agents may start in any order). An agent whose configuration would
listen on, or connect to, another machine without TLS (mutual authentication) and access
control is refused, unless ``insecure: true`` (its status then says ``"security":
"insecure"``); ``trackflow realm init`` makes the secure configuration
(:mod:`trackflow.distributed.realm`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from ..dataflow import Setup, parse_setup
from ..errors import ConfigError
from ..yamlfile import config_error, line_of, read_yaml
from ..zenohconf import DEFAULT_ZENOH, build_config, link_security, security

__all__ = ["AgentConfig", "link_security", "load_agent", "security", "zenoh_config"]

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
    "insecure",
}


def _bad(key: str | None, message: str) -> ConfigError:
    """The error of the agent key ``key`` (``load_agent`` adds the file and line)."""
    err = ConfigError(message)
    err.key = key
    return err


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
    insecure: bool = False
    #: the agent file (errors found later, opening the session, name it)
    path: Path | None = None

    def __post_init__(self):
        for what, value in (("name", self.name), ("realm", self.realm)):
            if not isinstance(value, str) or not _NAME.match(value):
                raise _bad(what, f"agent {what} {value!r}: use letters, digits, '_' and '-'")
        for e in self.setup.graph.edges:
            if not _NAME.match(e.name):
                raise _bad(None, f"edge name {e.name!r}: use letters, digits, '_' and '-'")
        if self.clock_sync not in ("estimate", "none"):
            raise _bad(
                "clock_sync", f"clock_sync must be 'estimate' or 'none', got {self.clock_sync!r}"
            )
        if self.pull_via not in ("replica", "get"):
            raise _bad("pull_via", f"pull_via must be 'replica' or 'get', got {self.pull_via!r}")
        if not self.reorder_ms >= 0:
            raise _bad("reorder_ms", f"reorder_ms must be >= 0, got {self.reorder_ms}")
        if not isinstance(self.thin, bool):
            raise _bad("thin", f"thin must be true or false, got {self.thin!r}")
        if self.thin and not self.reorder_ms > 0:
            raise _bad(
                "thin",
                "thin: true needs reorder_ms > 0 (thinned states come just after the tick "
                "they serve; reorder_ms is how long a tick may wait for them)",
            )
        if not isinstance(self.insecure, bool):
            raise _bad("insecure", f"insecure must be true or false, got {self.insecure!r}")
        if not 0 <= self.thin_grace_ms <= 1000:
            raise _bad(
                "thin_grace_ms", f"thin_grace_ms must be in 0..1000, got {self.thin_grace_ms}"
            )


def zenoh_config(cfg: AgentConfig):
    """The ``zenoh.Config`` of an agent: the file (if any), else the loopback defaults, then
    the ``zenoh`` keys of the agent file on top (:func:`trackflow.zenohconf.build_config`)."""
    where = f"zenoh_config {cfg.zenoh_config}" if cfg.zenoh_config else "zenoh"
    try:
        return build_config(
            [cfg.zenoh] if cfg.zenoh_config is not None else [DEFAULT_ZENOH, cfg.zenoh],
            cfg.zenoh_config,
            insecure=cfg.insecure,
            where=f"agent: {where}",
            path=cfg.path,
            hint=": make the realm's files with 'trackflow realm init' (docs/distributed.md), "
            "or set 'insecure: true' in the agent section (or pass --insecure) to accept it",
            feature="trackflow agent",
        )
    except ConfigError as exc:
        if getattr(exc, "key", None) == "zenoh":
            raise _bad("zenoh", exc.reason) from None
        raise


def _value(path, a, key: str, convert, default):
    """``convert(a[key])`` (``default`` without the key); a value it refuses is a
    :class:`ConfigError` at the key's line."""
    if key not in a:
        return default
    try:
        return convert(a[key])
    except (TypeError, ValueError) as exc:
        raise ConfigError(
            f"agent: {key}: {a[key]!r} is not valid ({exc})", path, line_of(a, key)
        ) from None


def _relative(path: Path, value) -> Path | None:
    return None if value is None else path.parent / str(value)


def _mapping(value) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ConfigError("expected a mapping of Zenoh configuration keys")
    return dict(value)


def load_agent(path: str | Path) -> AgentConfig:
    """Read an agent YAML file (setup plus ``agent:`` section).

    Raises
    ------
    ConfigError
        A mistake, naming the file, the line and the key (a key given twice included).
    OSError
        The file cannot be read.
    """
    path = Path(path)
    doc = read_yaml(path)
    if not isinstance(doc, dict) or not isinstance(doc.get("agent"), dict):
        raise config_error(
            path, doc, "an agent file needs an 'agent:' mapping (name, realm, ...)", "agent"
        )
    doc = doc.copy()  # the lines stay (a YamlMap)
    a = doc.pop("agent")
    unknown = set(a) - _AGENT_KEYS
    if unknown:
        first = min(unknown, key=lambda k: (line_of(a, k), str(k)))
        raise ConfigError(
            f"unknown keys {sorted(unknown, key=str)} (allowed: {sorted(_AGENT_KEYS)})",
            path, line_of(a, first), "agent",
        )  # fmt: skip
    if "name" not in a:
        raise config_error(path, a, "missing key 'name'", "agent")
    setup = parse_setup(doc, str(path), path.parent)
    setup.refuse_online_offsets("an agent")
    try:
        return AgentConfig(
            name=str(a["name"]),
            setup=setup,
            realm=_value(path, a, "realm", str, "default"),
            zenoh=_value(path, a, "zenoh", _mapping, {}),
            zenoh_config=_value(path, a, "zenoh_config", lambda v: _relative(path, v), None),
            start_ns=_value(path, a, "start_ns", int, 0),
            reorder_ms=_value(path, a, "reorder_ms", float, 0.0),
            clock_sync=_value(path, a, "clock_sync", str, "estimate"),
            clock_offset_ms=_value(path, a, "clock_offset_ms", float, 0.0),
            pull_via=_value(path, a, "pull_via", str, "replica"),
            thin=a.get("thin", False),
            thin_grace_ms=_value(path, a, "thin_grace_ms", float, 1.0),
            insecure=a.get("insecure", False),
            path=path,
        )
    except ConfigError as exc:  # AgentConfig's checks name the key; here the file and line
        if exc.file is not None:
            raise
        if exc.key is None:  # not a key of the agent section (an edge name)
            raise ConfigError(exc.reason, path) from None
        raise ConfigError(f"agent: {exc.reason}", path, line_of(a, exc.key)) from None
