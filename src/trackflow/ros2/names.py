"""The names rmw_zenoh gives ROS 2 topics in Zenoh: data key expressions and the liveliness
tokens of the ROS 2 graph (``docs/ros2.md``; the format of ``ros2/rmw_zenoh``'s
``docs/design.md`` and its ``liveliness_utils.cpp``).

Data of topic ``/a/b`` of type ``pkg/msg/T`` in domain ``d``::

    <d>/a/b/pkg::msg::dds_::T_/<type hash>

Graph tokens (``ros2 node list``, ``ros2 topic list`` and ``info`` read them)::

    @ros2_lv/<d>/<zid>/<nid>/<nid>/NN/<enclave>/<namespace>/<node>
    @ros2_lv/<d>/<zid>/<nid>/<eid>/MP|MS/<enclave>/<namespace>/<node>/<topic>/<type>/<hash>/<qos>

where names are *mangled* (every ``/`` becomes ``%``: the default namespace and enclave
``/`` are ``%``), ``MP`` is a publisher and ``MS`` a subscription, and ``qos`` lists the
QoS policies that differ from rmw_zenoh's defaults (:func:`qos_keyexpr`).
"""

from __future__ import annotations

import hashlib

__all__ = [
    "ADMIN_SPACE",
    "dds_type_name",
    "entity_gid",
    "entity_token",
    "mangle",
    "node_token",
    "qos_keyexpr",
    "topic_keyexpr",
]

#: the key space of the ROS 2 graph's liveliness tokens
ADMIN_SPACE = "@ros2_lv"

# rmw's enum values (rmw/types.h)
_RELIABLE, _BEST_EFFORT = 1, 2
_TRANSIENT_LOCAL, _VOLATILE = 1, 2
_KEEP_LAST, _KEEP_ALL = 1, 2
#: rmw_zenoh's defaults, which the QoS part of a token leaves out: reliable, volatile, keep
#: last 42, infinite deadline, lifespan and liveliness lease, automatic liveliness
_DEFAULT = {"reliability": _RELIABLE, "durability": _VOLATILE, "history": _KEEP_LAST,
            "depth": 42}  # fmt: skip


def dds_type_name(msgtype: str) -> str:
    """The DDS-style type name rmw uses (``geometry_msgs/msg/PoseStamped`` ->
    ``geometry_msgs::msg::dds_::PoseStamped_``)."""
    pkg, kind, name = msgtype.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def topic_keyexpr(domain: int, topic: str, msgtype: str, type_hash: str) -> str:
    """The Zenoh key expression of a topic's data (``topic`` fully qualified, ``msgtype``
    like ``geometry_msgs/msg/PoseStamped``, ``type_hash`` ``RIHS01_...``)."""
    return f"{int(domain)}/{topic.strip('/')}/{dds_type_name(msgtype)}/{type_hash}"


def mangle(name: str) -> str:
    """A name as one chunk of a liveliness token: every ``/`` becomes ``%``."""
    return name.replace("/", "%")


def qos_keyexpr(
    *, reliable: bool = True, transient_local: bool = False, keep_all: bool = False,
    depth: int = 10,
) -> str:  # fmt: skip
    """The QoS chunk of a token: ``reliability:durability:history,depth:deadline:lifespan:
    liveliness`` with every value equal to rmw_zenoh's default left empty (durations are
    rmw_zenoh's infinite defaults, so ``depth = 10`` gives ``::,10:,:,:,,``)."""
    values = {
        "reliability": _RELIABLE if reliable else _BEST_EFFORT,
        "durability": _TRANSIENT_LOCAL if transient_local else _VOLATILE,
        "history": _KEEP_ALL if keep_all else _KEEP_LAST,
        "depth": int(depth),
    }
    v = {k: "" if x == _DEFAULT[k] else str(x) for k, x in values.items()}
    return f"{v['reliability']}:{v['durability']}:{v['history']},{v['depth']}:,:,:,,"


def node_token(
    domain: int, zid: str, nid: int, node: str, namespace: str = "/", enclave: str = "/"
) -> str:
    """The liveliness token of a ROS 2 node (``ros2 node list``)."""
    return (
        f"{ADMIN_SPACE}/{int(domain)}/{zid}/{nid}/{nid}/NN/{mangle(enclave)}/"
        f"{mangle(namespace)}/{mangle(node)}"
    )


def entity_token(
    kind: str,
    domain: int,
    zid: str,
    nid: int,
    eid: int,
    node: str,
    topic: str,
    msgtype: str,
    type_hash: str,
    qos: str,
    namespace: str = "/",
    enclave: str = "/",
) -> str:
    """The liveliness token of a publisher (``kind = "MP"``) or a subscription (``"MS"``)
    of node ``node`` on ``topic`` (fully qualified)."""
    if kind not in ("MP", "MS"):
        raise ValueError(f"entity kind {kind!r}: 'MP' (publisher) or 'MS' (subscription)")
    return (
        f"{ADMIN_SPACE}/{int(domain)}/{zid}/{nid}/{eid}/{kind}/{mangle(enclave)}/"
        f"{mangle(namespace)}/{mangle(node)}/{mangle(topic)}/{dds_type_name(msgtype)}/"
        f"{type_hash}/{qos}"
    )


def entity_gid(token: str) -> bytes:
    """The 16-byte GID of an entity, derived from its liveliness token (the first 16 bytes
    of its SHA-256; rmw_zenoh hashes the token with XXH3-128: the GID is unique per entity
    either way, and subscribers only pass it on as the message's publisher GID)."""
    return hashlib.sha256(token.encode()).digest()[:16]
