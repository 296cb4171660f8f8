"""The Zenoh session trackflow talks to a ROS 2 system through, as rmw_zenoh's nodes do.

One session per :class:`~trackflow.dataflow.Ros2Link` and process, shared by every topic
published or subscribed on it (:meth:`Ros2Session.acquire` / :meth:`Ros2Session.release`,
counted), like one ROS 2 context. Its configuration is built by
:func:`trackflow.zenohconf.build_config`: without ``zenoh_config`` a peer listening on
loopback (a free port), multicast scouting off, connecting to the link's endpoint (the
Zenoh router of the ROS 2 system, ``tcp/127.0.0.1:7447`` by default) and retrying while it
is not there; endpoints off this machine without TLS and access control are refused unless
the link says ``insecure``.

On the session trackflow appears in the ROS 2 graph as a node (``node``, in the root
namespace), with a liveliness token per publisher and subscription
(:mod:`trackflow.ros2.names`), so ``ros2 node list`` and ``ros2 topic list`` can see it.
"""

from __future__ import annotations

import threading
import time

from ..dataflow import Ros2Link
from ..errors import ServiceError
from ..optional import require
from ..zenohconf import DEFAULT_ZENOH, build_config
from .attachment import encode_attachment
from .names import entity_gid, entity_token, node_token, qos_keyexpr, topic_keyexpr

__all__ = ["Ros2Session", "Subscription", "TopicPublisher"]

_FEATURE = "ROS 2 topics"


def _zenoh():
    return require("zenoh", extra="distributed", feature=_FEATURE)


def session_config(link: Ros2Link):
    """The ``zenoh.Config`` of a link (module docstring)."""
    layers = (
        [] if link.zenoh_config else [DEFAULT_ZENOH, {"connect": {"endpoints": [link.connect]}}]
    )
    return build_config(
        layers,
        link.zenoh_config,
        insecure=link.insecure,
        where=f"ros2: {link.zenoh_config or link.connect}",
        hint=": give a TLS configuration (zenoh_config), or set 'insecure: true' in the ros2 "
        "key to accept it",
        feature=_FEATURE,
    )


class TopicPublisher:
    """A ROS 2 publisher: a Zenoh publisher on the topic's key expression, its ``MP``
    liveliness token, and the attachment (sequence number from 1, send time, GID) of every
    message."""

    def __init__(self, ctx: Ros2Session, domain: int, node: str, topic: str, msgtype: str,
                 type_hash: str, depth: int = 10):  # fmt: skip
        nid = ctx.node(domain, node)
        token = entity_token("MP", domain, ctx.zid, nid, ctx.next_id(), node, topic, msgtype,
                             type_hash, qos_keyexpr(depth=depth))  # fmt: skip
        self.keyexpr = topic_keyexpr(domain, topic, msgtype, type_hash)
        self.token = token
        self.gid = entity_gid(token)
        self.sequence = 0
        self._pub = ctx.session.declare_publisher(self.keyexpr)
        self._token = ctx.session.liveliness().declare_token(token)

    def put(self, payload: bytes, now_ns: int | None = None) -> None:
        """Send one serialised message (its attachment stamped ``now_ns``, default now)."""
        self.sequence += 1
        stamp = time.time_ns() if now_ns is None else int(now_ns)
        self._pub.put(payload, attachment=encode_attachment(self.sequence, stamp, self.gid))

    def close(self) -> None:
        self._token.undeclare()
        self._pub.undeclare()


class Subscription:
    """A ROS 2 subscription: a Zenoh subscriber on the topic's data (any type hash, so a
    system announcing another hash for the same type still reaches it) and its ``MS``
    liveliness token. ``callback(key, payload, attachment or None, arrival_ns)`` runs on
    Zenoh's thread."""

    def __init__(self, ctx: Ros2Session, domain: int, node: str, topic: str, msgtype: str,
                 type_hash: str, callback, depth: int = 10):  # fmt: skip
        nid = ctx.node(domain, node)
        token = entity_token("MS", domain, ctx.zid, nid, ctx.next_id(), node, topic, msgtype,
                             type_hash, qos_keyexpr(depth=depth))  # fmt: skip
        self.keyexpr = topic_keyexpr(domain, topic, msgtype, "*")
        self.token = token

        def on_sample(sample) -> None:
            arrival = time.time_ns()
            att = sample.attachment
            callback(str(sample.key_expr), sample.payload.to_bytes(),
                     None if att is None else att.to_bytes(), arrival)  # fmt: skip

        self._sub = ctx.session.declare_subscriber(self.keyexpr, on_sample)
        self._token = ctx.session.liveliness().declare_token(token)

    def close(self) -> None:
        self._token.undeclare()
        self._sub.undeclare()


class Ros2Session:
    """A Zenoh session shared by the topics of one link (module docstring)."""

    _open: dict[Ros2Link, Ros2Session] = {}
    _lock = threading.Lock()

    def __init__(self, link: Ros2Link):
        zenoh = _zenoh()
        conf = session_config(link)
        try:
            self.session = zenoh.open(conf)
        except zenoh.ZError as exc:
            raise ServiceError(f"ros2: cannot open the Zenoh session ({link}): {exc}") from None
        self.link = link
        self.zid = str(self.session.zid())
        self.users = 0
        self._ids = 0
        self._nodes: dict[tuple[int, str], tuple[int, object]] = {}
        self._id_lock = threading.Lock()

    @classmethod
    def acquire(cls, link: Ros2Link) -> Ros2Session:
        """The process's session of ``link``, opened on first use."""
        with cls._lock:
            ctx = cls._open.get(link)
            if ctx is None:
                ctx = cls._open[link] = cls(link)
            ctx.users += 1
            return ctx

    def release(self) -> None:
        """One user less; the last one closes the session (its tokens disappear)."""
        with Ros2Session._lock:
            self.users -= 1
            if self.users > 0:
                return
            Ros2Session._open.pop(self.link, None)
        for _, token in self._nodes.values():
            token.undeclare()
        self._nodes.clear()
        self.session.close()

    def next_id(self) -> int:
        """A new entity id, unique in this session."""
        with self._id_lock:
            self._ids += 1
            return self._ids

    def node(self, domain: int, name: str) -> int:
        """The id of node ``name`` in ``domain`` (its ``NN`` token declared on first use)."""
        key = (int(domain), name)
        with self._id_lock:
            if key not in self._nodes:
                self._ids += 1
                nid = self._ids
                token = self.session.liveliness().declare_token(
                    node_token(domain, self.zid, nid, name)
                )
                self._nodes[key] = (nid, token)
            return self._nodes[key][0]

    def publisher(self, domain, node, topic, msgtype, type_hash) -> TopicPublisher:
        """A publisher of ``topic`` (:class:`TopicPublisher`)."""
        return TopicPublisher(self, domain, node, topic, msgtype, type_hash)

    def subscribe(self, domain, node, topic, msgtype, type_hash, callback) -> Subscription:
        """A subscription to ``topic`` (:class:`Subscription`)."""
        return Subscription(self, domain, node, topic, msgtype, type_hash, callback)
