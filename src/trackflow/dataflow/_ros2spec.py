"""The ROS 2 keys of a setup, checked once: a sensor's ``input: {ros2: ...}`` and a push
query's ``ros2:`` (its answers published as a ROS 2 topic; ``docs/ros2.md``).

Examples (YAML)::

    sensors:
      - {name: head, source: room, target: head, ...,
         input: {ros2: {topic: /mocap/head, type: PoseStamped}}}
    queries:
      - {name: view, source: room, target: head, mode: push, rate_hz: 60,
         ros2: {topic: /trackflow/head, type: PoseWithCovarianceStamped}}

Both talk to ROS 2 through a Zenoh session (the ROS 2 middleware ``rmw_zenoh_cpp``), by
default connected to the Zenoh router of this machine (``connect: tcp/127.0.0.1:7447``, the
router ``ros2 run rmw_zenoh_cpp rmw_zenohd`` starts). The keys the two share:

``domain`` (``ROS_DOMAIN_ID``, default 0), ``connect`` (the router's endpoint),
``zenoh_config`` (a complete Zenoh configuration file instead, relative to the setup file),
``insecure`` (accept an endpoint off this machine without TLS and access control), ``node``
(the ROS 2 node name trackflow appears as, default ``trackflow``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from ..errors import ConfigError

__all__ = [
    "ROS2_INPUT_TYPES",
    "ROS2_OUTPUT_TYPES",
    "Ros2Link",
    "Ros2Output",
    "check_ros2_input",
    "parse_ros2_output",
    "ros2_topic_name",
]

#: message types a sensor can read from a topic (short names, ``docs/ros2.md``)
ROS2_INPUT_TYPES = ("PoseStamped", "PoseWithCovarianceStamped", "TransformStamped", "TFMessage")
#: message types a query's answers can be published as
ROS2_OUTPUT_TYPES = ("PoseStamped", "PoseWithCovarianceStamped", "TFMessage")
#: the default router endpoint of rmw_zenoh (its ``rmw_zenohd`` listens there)
DEFAULT_CONNECT = "tcp/127.0.0.1:7447"
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_ENDPOINT = re.compile(r"^[a-z0-9-]+/\S+$")
#: keys shared by inputs and outputs (the link and the node) with their types and defaults
LINK_OPTIONS: dict[str, tuple[type | tuple, object]] = {
    "domain": (int, 0),
    "connect": (str, DEFAULT_CONNECT),
    "zenoh_config": ((str, type(None)), None),
    "insecure": (bool, False),
    "node": (str, "trackflow"),
}


@dataclass(frozen=True)
class Ros2Link:
    """How trackflow reaches the ROS 2 system: a Zenoh session (one per link and process,
    shared by every topic on it).

    Attributes
    ----------
    connect : str
        The Zenoh router's endpoint (``tcp/127.0.0.1:7447``).
    zenoh_config : str or None
        A complete Zenoh configuration file instead of the defaults.
    insecure : bool
        Accept links off this machine without TLS and access control.
    """

    connect: str = DEFAULT_CONNECT
    zenoh_config: str | None = None
    insecure: bool = False

    @classmethod
    def of(cls, options: dict) -> Ros2Link:
        """The link of checked ``ros2`` options (an input's or an output's)."""
        return cls(options["connect"], options["zenoh_config"], options["insecure"])


@dataclass(frozen=True)
class Ros2Output:
    """A push query's answers as a ROS 2 topic.

    Attributes
    ----------
    topic : str
        Fully qualified topic name (``/trackflow/head``).
    type : str
        One of :data:`ROS2_OUTPUT_TYPES`.
    domain : int
        ROS domain id.
    frame_id, child_frame_id : str
        ``header.frame_id`` (the query's source frame by default) and the child frame (its
        target; ``TFMessage`` only).
    node : str
        The ROS 2 node name trackflow appears as.
    link : Ros2Link
    """

    topic: str
    type: str
    domain: int
    frame_id: str
    child_frame_id: str
    node: str = "trackflow"
    link: Ros2Link = Ros2Link()


def ros2_topic_name(value: str, what: str) -> str:
    """A ROS 2 topic name made fully qualified (``head`` -> ``/head``); ``ConfigError`` for
    one ROS 2 would refuse (empty parts, characters other than letters, digits and ``_``,
    a part starting with a digit)."""
    if not isinstance(value, str) or not value.strip("/"):
        raise ConfigError(f"{what}: {value!r} is not a ROS 2 topic name")
    name = value if value.startswith("/") else "/" + value
    parts = name[1:].split("/")
    if any(not _NAME.match(p) for p in parts):
        raise ConfigError(
            f"{what}: {value!r} is not a ROS 2 topic name (parts of letters, digits and '_', "
            "not starting with a digit, separated by single '/')"
        )
    return name


def _typed(raw: dict, allowed: dict, what: str) -> dict:
    """``raw`` checked against ``allowed`` (key -> (type, default); ``...`` = required)."""
    bad = set(raw) - set(allowed)
    if bad:
        raise ConfigError(f"{what}: unknown keys {sorted(bad, key=str)} (allowed: "
                          f"{sorted(allowed)})")  # fmt: skip
    out = {}
    for key, (typ, default) in allowed.items():
        if key not in raw:
            if default is ...:
                raise ConfigError(f"{what}: missing key {key!r}")
            out[key] = default
            continue
        v = raw[key]
        types = typ if isinstance(typ, tuple) else (typ,)
        if (isinstance(v, bool) and bool not in types) or not isinstance(v, typ):
            raise ConfigError(f"{what}.{key}: expected {typ}, got {v!r}")
        out[key] = v
    return out


def _check_link(opts: dict, what: str, base_dir) -> None:
    """The shared keys (module docstring), in place: a relative ``zenoh_config`` is made
    relative to the setup file's folder."""
    if not 0 <= opts["domain"] <= 232:
        raise ConfigError(f"{what}.domain: {opts['domain']} is not a ROS domain id (0..232)")
    if not _ENDPOINT.match(opts["connect"]):
        raise ConfigError(
            f"{what}.connect: {opts['connect']!r} is not a Zenoh endpoint such as {DEFAULT_CONNECT}"
        )
    if not _NAME.match(opts["node"]):
        raise ConfigError(f"{what}.node: {opts['node']!r} is not a ROS 2 node name")
    cfg = opts["zenoh_config"]
    if cfg is not None:
        if not cfg.strip():
            raise ConfigError(f"{what}.zenoh_config: empty path")
        if not Path(cfg).is_absolute() and base_dir is not None:
            opts["zenoh_config"] = str(Path(base_dir) / cfg)


def check_ros2_input(opts: dict, base_dir=None) -> None:
    """Check (in place) the options of ``input: {ros2: ...}`` as ``parse_input`` filled them
    in: the topic made fully qualified, the type known, a ``TFMessage`` topic's frame pair
    named."""
    what = "input.ros2"
    opts["topic"] = ros2_topic_name(opts["topic"], f"{what}.topic")
    if opts["type"] not in ROS2_INPUT_TYPES:
        raise ConfigError(
            f"{what}.type: {opts['type']!r} is not one of {list(ROS2_INPUT_TYPES)}"
        )  # fmt: skip
    if opts["type"] == "TFMessage" and not (opts["frame_id"] and opts["child_frame_id"]):
        raise ConfigError(
            f"{what}: a TFMessage topic carries many transforms: name the one with frame_id "
            "and child_frame_id"
        )
    if opts["clock"] not in ("host", "map"):
        raise ConfigError(
            f"{what}.clock must be 'host' (header stamps are this host's time) or 'map' "
            f"(estimate the sender's clock offset), got {opts['clock']!r}"
        )
    _check_link(opts, what, base_dir)


#: the keys of a query's ``ros2:`` (``topic`` defaults to ``/tf`` for ``TFMessage``)
_OUTPUT_OPTIONS: dict[str, tuple[type | tuple, object]] = {
    "topic": ((str, type(None)), None),
    "type": (str, "PoseWithCovarianceStamped"),
    "frame_id": ((str, type(None)), None),
    "child_frame_id": ((str, type(None)), None),
    **LINK_OPTIONS,
}


def parse_ros2_output(doc, source: str, target: str, mode: str, base_dir=None) -> Ros2Output:
    """A query's ``ros2:`` mapping (module docstring) for a query of ``source`` to ``target``
    in ``mode``; ``ConfigError`` names the offending key."""
    what = "ros2"
    if not isinstance(doc, dict):
        raise ConfigError(f"{what} must be a mapping like {{topic: /trackflow/head}}")
    if mode != "push":
        raise ConfigError(f"{what}: only a push query has answers to publish (mode: push)")
    opts = _typed(doc, _OUTPUT_OPTIONS, what)
    if opts["type"] not in ROS2_OUTPUT_TYPES:
        raise ConfigError(f"{what}.type: {opts['type']!r} is not one of {list(ROS2_OUTPUT_TYPES)}")
    topic = opts["topic"]
    if topic is None:
        if opts["type"] != "TFMessage":
            raise ConfigError(f"{what}: missing key 'topic'")
        topic = "/tf"
    _check_link(opts, what, base_dir)
    frame_id = source if opts["frame_id"] is None else opts["frame_id"]
    child = target if opts["child_frame_id"] is None else opts["child_frame_id"]
    for key, value in (("frame_id", frame_id), ("child_frame_id", child)):
        if not value.strip():
            raise ConfigError(f"{what}.{key}: empty frame name")
    return Ros2Output(
        ros2_topic_name(topic, f"{what}.topic"), opts["type"], opts["domain"], frame_id, child,
        opts["node"], Ros2Link.of(opts),
    )  # fmt: skip
