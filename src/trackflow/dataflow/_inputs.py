"""The ``input:`` key of a sensor in a setup: which live tracker feeds it, checked once.

Examples (YAML)::

    input: {natnet: {server: 127.0.0.1, body: head}, up: y}
    input: {dtrack: {port: 5000, body: 3}}
    input: {vrpn: {device: "Tracker0@127.0.0.1", sensor: 0}}
    input: {optical: {config: optical.yaml, body: wand}}
    input: {ros2: {topic: /mocap/head, type: PoseStamped}}

``optical`` is an in-process feed rather than a network tracker: the optical tracker of an
optical setup file (``config``, relative to the setup file; docs/optical.md) measuring the
marker model ``body``. Such feeds implement :class:`PoseFeed` and are made by a factory that
their package registers with :func:`register_feed` (dataflow knows neither the trackers
nor the optical package; the live runtime looks the factory up by the protocol's name).
``ros2`` reads a ROS 2 topic through rmw_zenoh's Zenoh key expressions (its keys:
:mod:`trackflow.dataflow._ros2spec`, ``docs/ros2.md``).

Common keys next to the protocol: ``up`` (``z``: frames as sent; ``y``: the tracker sends
Y-up frames, converted to Z-up, see ``docs/conventions.md``), ``unit`` (unit of positions on
the wire: ``m``, ``cm`` or ``mm``; default per protocol: DTrack mm, NatNet and VRPN m) and
``stale_ms`` (no data for that long = stale; default 500).
"""

from __future__ import annotations

import ipaddress
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from ..errors import ConfigError, InputError
from ._ros2spec import LINK_OPTIONS, check_ros2_input

__all__ = [
    "NETWORK_PROTOCOLS",
    "PROTOCOLS",
    "InputSpec",
    "PoseFeed",
    "feed_factory",
    "parse_input",
    "register_feed",
]

_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}
_DEFAULT_UNIT = {"natnet": "m", "dtrack": "mm", "vrpn": "m", "optical": "m", "ros2": "m"}

# key -> (type, default); a default of ... means required
_OPTIONS: dict[str, dict[str, tuple[type | tuple, object]]] = {
    "natnet": {
        "server": (str, "127.0.0.1"),
        "body": ((str, int), ...),
        "command_port": (int, 1510),
        "data_port": (int, 1511),
        "multicast": (bool, False),
        "group": (str, "239.255.42.99"),
        "interface": (str, "127.0.0.1"),
        "timeout_ms": ((int, float), 2000),
        "spin_us": ((int, float), 0),
    },
    "dtrack": {
        "port": (int, 5000),
        "body": (int, ...),
        "kind": (str, "body"),
        "interface": (str, "127.0.0.1"),
        "group": ((str, type(None)), None),
        "command": ((str, type(None)), None),
        "command_port": (int, 50105),
        "latency_ms": ((int, float), 0.0),
        "spin_us": ((int, float), 0),
    },
    "vrpn": {
        "device": (str, ...),
        "sensor": (int, 0),
        "clock": (str, "map"),
        "connect": (str, "tcp"),
        "latency_ms": ((int, float), 0.0),
        "timeout_ms": ((int, float), 2000),
    },
    "optical": {
        "config": (str, ...),
        "body": (str, ...),
    },
    "ros2": {
        "topic": (str, ...),
        "type": (str, "PoseStamped"),
        "frame_id": ((str, type(None)), None),
        "child_frame_id": ((str, type(None)), None),
        "clock": (str, "host"),
        "latency_ms": ((int, float), 0.0),
        **LINK_OPTIONS,
    },
}
PROTOCOLS = tuple(_OPTIONS)


@dataclass(frozen=True)
class InputSpec:
    """A validated live input of one sensor.

    Attributes
    ----------
    protocol : str
        ``natnet``, ``dtrack`` or ``vrpn``.
    options : dict
        The protocol's options with defaults filled in (see ``_OPTIONS``).
    up : str
        ``z`` (as sent) or ``y`` (Y-up frames converted to Z-up).
    unit_scale : float
        Metres per wire unit.
    stale_s : float
    """

    protocol: str
    options: dict = field(default_factory=dict)
    up: str = "z"
    unit_scale: float = 1.0
    stale_s: float = 0.5

    @property
    def vrpn_address(self) -> tuple[str, str, int]:
        """``(device, host, port)`` of a VRPN ``device`` string ``Name@host[:port]`` (also
        ``Name@tcp://host:port``)."""
        dev = self.options["device"]
        name, _, where = dev.partition("@")
        where = where.removeprefix("tcp://")
        host, _, port = where.partition(":")
        return name, host or "127.0.0.1", int(port) if port else 3883


def _check_host(value: str, what: str) -> None:
    try:
        ipaddress.ip_address(value)
    except ValueError:
        if not value or any(c.isspace() for c in value):
            raise ConfigError(f"{what}: {value!r} is not a host address") from None


class PoseFeed(Protocol):
    """An in-process live source of poses, produced frame by frame at its own rate.

    Attributes
    ----------
    t_ns : numpy.ndarray
        (N,) int64 exposure times of its frames [ns] on its own clock, strictly increasing;
        the runtime paces frame ``i`` at ``start + t_ns[i] - t_ns[0]`` on the host clock.
    """

    t_ns: np.ndarray

    def warm_up(self) -> None:
        """Prepare before real-time pacing starts (compile kernels, open devices); the
        feed's state afterwards is as if new."""
        ...

    def has_body(self, body: str) -> bool:
        """Whether ``body`` (an ``input.<protocol>.body`` selector) is measured."""
        ...

    def measure(self, index: int) -> Mapping:
        """Process frame ``index`` (increasing from call to call; frames may be skipped):
        ``{body: UncertainPose or None}``, each ``T_world_body`` [m] with its 6x6
        covariance over ``(dt, dtheta)``; ``None`` = not measured in this frame."""
        ...


#: network trackers, implemented by trackflow.trackers itself (not feeds)
NETWORK_PROTOCOLS = ("natnet", "dtrack", "vrpn", "ros2")
#: protocol -> factory(options) of its feed, registered by the package implementing it
_FEEDS: dict[str, Callable[[dict], PoseFeed]] = {}


def register_feed(protocol: str, factory: Callable[[dict], PoseFeed]) -> None:
    """Register the factory building the :class:`PoseFeed` of ``input: {protocol: ...}``
    from the parsed options (done by the implementing package when imported)."""
    if protocol not in _OPTIONS or protocol in NETWORK_PROTOCOLS:
        raise InputError(f"{protocol!r} is not a feed protocol")
    _FEEDS[protocol] = factory


def feed_factory(protocol: str) -> Callable[[dict], PoseFeed]:
    """The registered factory of ``protocol``; ``ValueError`` naming the package to import."""
    try:
        return _FEEDS[protocol]
    except KeyError:
        raise ConfigError(
            f"input.{protocol}: no feed registered (import trackflow.{protocol} first)"
        ) from None


def parse_input(doc, base_dir=None) -> InputSpec:
    """Validate an ``input:`` mapping; ``ValueError`` names the offending key.

    ``base_dir`` (the setup file's folder) resolves a relative ``optical.config`` path.
    """
    if not isinstance(doc, dict):
        raise ConfigError("input must be a mapping like {natnet: {server: ..., body: ...}}")
    protos = [k for k in doc if k in _OPTIONS]
    if len(protos) != 1:
        raise ConfigError(f"input needs exactly one of {list(PROTOCOLS)}, got {sorted(doc)}")
    proto = protos[0]
    unknown = set(doc) - {proto, "up", "unit", "stale_ms"}
    if unknown:
        raise ConfigError(f"input: unknown keys {sorted(unknown)} (allowed: up, unit, stale_ms)")
    raw = doc[proto] or {}
    if not isinstance(raw, dict):
        raise ConfigError(f"input.{proto} must be a mapping")
    allowed = _OPTIONS[proto]
    bad = set(raw) - set(allowed)
    if bad:
        raise ConfigError(f"input.{proto}: unknown keys {sorted(bad)} (allowed: {sorted(allowed)})")
    opts = {}
    for key, (typ, default) in allowed.items():
        if key not in raw:
            if default is ...:
                raise ConfigError(f"input.{proto}: missing key {key!r}")
            opts[key] = default
            continue
        v = raw[key]
        if (
            isinstance(v, bool)
            and typ is not bool
            and bool not in (typ if isinstance(typ, tuple) else (typ,))
        ):
            raise ConfigError(f"input.{proto}.{key}: expected {typ}, got {v!r}")
        if not isinstance(v, typ):
            raise ConfigError(f"input.{proto}.{key}: expected {typ}, got {v!r}")
        opts[key] = v
    for key in ("port", "command_port", "data_port"):
        if key in opts and not 0 < opts[key] < 65536:
            raise ConfigError(f"input.{proto}.{key}: {opts[key]} is not a port")
    for key in ("server", "interface", "group", "command"):
        if opts.get(key) is not None:
            _check_host(opts[key], f"input.{proto}.{key}")
    if proto == "vrpn":
        if "@" not in opts["device"]:
            raise ConfigError(f"input.vrpn.device: {opts['device']!r} is not Name@host[:port]")
        if opts["clock"] not in ("map", "host"):
            raise ConfigError("input.vrpn.clock must be 'map' (estimate the offset) or 'host'")
        if opts["connect"] not in ("tcp", "udp"):
            raise ConfigError(
                "input.vrpn.connect must be 'tcp' (connect directly) or 'udp' (ask by UDP, "
                "the server connects back)"
            )
    if proto == "dtrack" and opts["kind"] not in ("body", "flystick", "tool", "hand"):
        raise ConfigError(
            f"input.dtrack.kind must be 'body' (6d), 'flystick' (6df2), 'tool' (6dmt2) or "
            f"'hand' (gl), got {opts['kind']!r}"
        )
    if proto == "ros2":
        check_ros2_input(opts, base_dir)
    if proto == "optical":
        if not opts["config"].strip():
            raise ConfigError("input.optical.config: empty path")
        cfg = Path(opts["config"])
        if not cfg.is_absolute() and base_dir is not None:
            opts["config"] = str(Path(base_dir) / cfg)
    for key in ("latency_ms", "timeout_ms", "spin_us"):
        if key in opts and not 0 <= float(opts[key]) < 1e5:
            raise ConfigError(f"input.{proto}.{key}: {opts[key]} out of range")
    up = str(doc.get("up", "z")).lower()
    if up not in ("y", "z"):
        raise ConfigError(f"input.up must be 'y' or 'z', got {doc.get('up')!r}")
    unit = str(doc.get("unit", _DEFAULT_UNIT[proto]))
    if unit not in _UNITS:
        raise ConfigError(f"input.unit must be one of {sorted(_UNITS)}, got {unit!r}")
    stale = float(doc.get("stale_ms", 500)) * 1e-3
    if not 0 < stale < 3600:
        raise ConfigError(f"input.stale_ms: {doc.get('stale_ms')} out of range")
    return InputSpec(proto, opts, up, _UNITS[unit], stale)
