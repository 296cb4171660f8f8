"""A push query's answers published as a ROS 2 topic (a query's ``ros2:`` key).

Each answer ``T_source_target(t)`` with its covariance becomes one message stamped ``t``:
``PoseWithCovarianceStamped`` (covariance converted to ROS's convention), ``PoseStamped``
(no covariance) or a ``TFMessage`` of one transform (``/tf`` by default), ``header.frame_id``
the query's source frame and the child frame its target unless the key names others.
``trackflow run`` and agents make one :class:`AnswerPublisher` per such query.
"""

from __future__ import annotations

from ..dataflow import Ros2Output
from ..errors import TrackflowError
from ..optional import require
from .messages import PoseCodec
from .session import Ros2Session

__all__ = ["AnswerPublisher", "close_publishers", "open_publishers"]


class AnswerPublisher:
    """The answers of one query on its topic; called with each answer (a
    :class:`trackflow.dataflow.Measurement`).

    Attributes
    ----------
    published : int
        Messages handed to Zenoh.
    failed : int
        Answers that could not be sent (the session closed under them); never raised into
        the run.
    """

    def __init__(self, spec: Ros2Output):
        self.spec = spec
        self.codec = PoseCodec(spec.type)
        self.ctx = Ros2Session.acquire(spec.link)
        try:
            self.topic = self.ctx.publisher(
                spec.domain, spec.node, spec.topic, self.codec.msgtype, self.codec.type_hash
            )
        except BaseException:
            self.ctx.release()
            raise
        self.published = 0
        self.failed = 0
        self._zerror = require("zenoh", extra="distributed", feature="ROS 2 topics").ZError

    @property
    def keyexpr(self) -> str:
        """The Zenoh key expression the messages go to."""
        return self.topic.keyexpr

    def publish(self, t_ns: int, pose) -> None:
        """Send the answer ``pose`` (an :class:`~trackflow.math.UncertainPose`) at ``t_ns``."""
        s = self.spec
        payload = self.codec.encode(
            t_ns, s.frame_id, s.child_frame_id, pose.position, pose.quaternion, pose.covariance
        )
        try:
            self.topic.put(payload)
        except self._zerror:  # a closed session: counted, the run goes on
            self.failed += 1
            return
        self.published += 1

    def __call__(self, m) -> None:
        self.publish(m.t_ns, m.pose)

    def status(self) -> dict:
        """Topic, key expression and counts, as JSON-able data."""
        return {"topic": self.spec.topic, "type": self.spec.type, "keyexpr": self.keyexpr,
                "published": self.published, "failed": self.failed}  # fmt: skip

    def close(self) -> None:
        self.topic.close()
        self.ctx.release()


def open_publishers(outputs: dict[str, Ros2Output]) -> dict[str, AnswerPublisher]:
    """An :class:`AnswerPublisher` per query of ``outputs`` (all or none: a failure closes
    the ones already open)."""
    out: dict[str, AnswerPublisher] = {}
    try:
        for name, spec in outputs.items():
            out[name] = AnswerPublisher(spec)
    except (TrackflowError, OSError):
        close_publishers(out)
        raise
    return out


def close_publishers(publishers: dict[str, AnswerPublisher]) -> None:
    """Close every publisher (their sessions close with the last user)."""
    for p in publishers.values():
        p.close()
