"""Zenoh configurations, built in one place: agents (``trackflow.distributed``) and the ROS 2
topics of ``trackflow run`` and agents (``trackflow.ros2``) open their sessions with them.

A configuration is a Zenoh config file (or Zenoh's defaults) with layers of keys on top
(:func:`build_config`); whatever it says, its links are judged by :func:`security`: a
configuration that would listen on, or connect to, another machine without TLS with mutual
authentication and access control is refused unless the caller was told ``insecure``.
"""

from __future__ import annotations

import ipaddress
import json
from pathlib import Path

from .errors import ConfigError
from .optional import require

__all__ = [
    "DEFAULT_ZENOH",
    "NO_SHARED_MEMORY",
    "build_config",
    "insert_key",
    "link_security",
    "security",
]

#: Zenoh's shared-memory transport, off. trackflow's messages are small (a state batch is a
#: few kilobytes), where shared memory saves nothing, and it costs: every session creates a
#: 16 MB segment in ``/dev/shm`` that every local peer it hears from maps, so an agent's memory
#: grew with the realm (20 agents on one machine: 772 MB each with it, 380 MB without, 309 MB
#: alone), and a killed process's segment stays in ``/dev/shm`` until a later session sweeps
#: it. Part of :data:`DEFAULT_ZENOH` and of the realm's generated configurations; an agent
#: file may turn it on (``zenoh: {transport: {shared_memory: {enabled: true}}}``).
NO_SHARED_MEMORY = {"shared_memory": {"enabled": False}}

#: safe defaults for one machine: a peer listening on loopback (a free port), multicast
#: scouting off, connection attempts retried every 0.25 s .. 1 s (peers may start in any order),
#: and Zenoh's shared-memory transport off (:data:`NO_SHARED_MEMORY`)
DEFAULT_ZENOH = {
    "mode": "peer",
    "listen": {"endpoints": ["tcp/127.0.0.1:0"]},
    "connect": {
        "retry": {"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2}
    },
    "scouting": {"multicast": {"enabled": False}},
    "transport": NO_SHARED_MEMORY,
}


def _zenoh(feature: str):
    return require("zenoh", extra="distributed", feature=feature)


def insert_key(conf, key: str, value, feature: str = "Zenoh sessions") -> None:
    """Set ``key`` (a ``a/b/c`` path) of a ``zenoh.Config`` to ``value``: mappings key by key
    (so the other keys keep their defaults), or as a whole where Zenoh has no such sub-keys
    yet (a null default such as ``connect/retry``)."""
    zenoh = _zenoh(feature)
    if isinstance(value, dict) and value:
        try:
            for k, v in value.items():
                insert_key(conf, f"{key}/{k}", v, feature)
            return
        except zenoh.ZError:
            pass
    conf.insert_json5(key, json.dumps(value))


def build_config(
    layers,
    file: Path | None = None,
    *,
    insecure: bool = False,
    where: str = "zenoh",
    path: Path | None = None,
    hint: str = "",
    feature: str = "Zenoh sessions",
):
    """A ``zenoh.Config``: ``file`` (or Zenoh's defaults) with every mapping of ``layers`` on
    top, in order, checked by :func:`security`.

    Parameters
    ----------
    layers : sequence of dict
        Zenoh configuration keys (``mode``, ``listen``, ``connect``, ...).
    file : path, optional
        A complete Zenoh configuration file (JSON5) to start from.
    insecure : bool
        Accept links off this machine without TLS, mutual authentication and access control.
    where, path, hint : str, path, str
        For the error messages: the key that holds the configuration, the file it comes
        from, and how to accept or fix a refused configuration.
    feature : str
        What needs Zenoh (for the message when it is not installed).

    Raises
    ------
    ConfigError
        A key Zenoh refuses (``err.key`` is ``"zenoh"``), or links off this machine that are
        not protected while not ``insecure``.
    MissingExtraError
        ``eclipse-zenoh`` is not installed.
    """
    zenoh = _zenoh(feature)
    conf = zenoh.Config() if file is None else zenoh.Config.from_file(str(file))
    for layer in layers:
        for key, value in layer.items():
            try:
                insert_key(conf, str(key), value, feature)
            except zenoh.ZError as exc:
                err = ConfigError(f"zenoh config key {key!r} = {value!r}: {exc}")
                err.key = "zenoh"
                raise err from None
    kind, weak = security(conf)
    if kind == "insecure" and not insecure:
        raise ConfigError(
            f"{where}: links off this machine ({', '.join(weak)}) without TLS with mutual "
            f"authentication and access control{hint}",
            path,
        )
    return conf


def security(conf) -> tuple[str, list[str]]:
    """``(kind, endpoints)`` of a ``zenoh.Config``: ``loopback``, ``tls+acl`` or
    ``insecure`` (:func:`link_security`)."""
    keys = ("listen/endpoints", "connect/endpoints", "transport/link/tls/enable_mtls",
            "access_control/enabled")  # fmt: skip
    return link_security(*(json.loads(conf.get_json(k)) for k in keys))


def _endpoints(value) -> list[str]:
    """A Zenoh ``endpoints`` value: a list, or a map of lists by mode."""
    if isinstance(value, dict):
        return [e for v in value.values() for e in _endpoints(v)]
    return [str(e) for e in value or ()]


def _loopback(endpoint: str) -> bool:
    proto, _, address = endpoint.partition("/")
    if proto in ("unixsock-stream", "unixpipe", "vsock"):
        return True
    host = address.split("#", 1)[0].rsplit(":", 1)[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def link_security(listen, connect, mtls, access_control) -> tuple[str, list[str]]:
    """How a session's Zenoh links are protected: ``("tls+acl", [])`` when every endpoint is
    TLS (or QUIC) with mutual authentication and access control is on, else
    ``("loopback", [])`` when every endpoint is on this machine, else ``("insecure",
    the endpoints off this machine that are not protected)``."""
    every = _endpoints(listen) + _endpoints(connect)
    weak = [e for e in every if not e.startswith(("tls/", "quic/"))]
    if not weak and mtls is True and access_control is True:
        return "tls+acl", []
    off = [e for e in every if not _loopback(e)]
    if not off:
        return "loopback", []
    return "insecure", [e for e in off if e in weak] or off
