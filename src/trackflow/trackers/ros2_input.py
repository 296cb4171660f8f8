"""The live input of a ROS 2 topic (``input: {ros2: {topic: ..., type: ...}}``, ``docs/ros2.md``).

One input per topic (sensors reading different transforms of one ``TFMessage`` topic share
it, so each message is decoded once): a Zenoh subscription on the topic's rmw_zenoh key
expression, on the shared session of its link (:class:`trackflow.ros2.Ros2Session`).
Zenoh's thread hands every message to the runtime as one packet, stamped on arrival.

A message's poses go to the sensors whose frames they carry: ``PoseStamped``,
``PoseWithCovarianceStamped`` and ``TransformStamped`` to every sensor of the topic (a
sensor's ``frame_id`` / ``child_frame_id``, when given, must match, else the message is a
counted rejection, ``frame mismatch``), a ``TFMessage``'s transforms to the sensor naming
their pair (other transforms are not for us and are not counted). Time: ``header.stamp``,
as this host's time (``clock: host``, ROS time is the system clock), or mapped from the
sender's clock (``clock: map``: the stamp plus ``latency_ms`` is taken as the send time and
the offset estimated as for VRPN). Covariance: ``PoseWithCovarianceStamped``'s, converted
from ROS's convention (:func:`trackflow.math.cov_from_ros`), else the sensor's nominal one.

Anything malformed is a counted rejection of the topic's sensors, never an exception: a
payload that is not a CDR message of the type (``malformed message``), an attachment that
is not rmw_zenoh's (``bad attachment``; a message without one, from a plain Zenoh
publisher, is taken), a message of another type name on the key (``wrong type``).
"""

from __future__ import annotations

import math

from ..dataflow import InputSpec, Ros2Link
from ..errors import FormatError, InputError
from ..math import cov_from_ros
from ..ros2 import AttachmentError, PoseCodec, Ros2Session, decode_attachment
from ..ros2.names import dds_type_name
from ..ros2.session import session_config
from ..timesync import ClockMapper
from ._packet import PacketError
from .live_input import Body, LiveInput
from .wire_checks import near_unit

__all__ = ["Ros2Input"]


class Ros2Input(LiveInput):
    """The sensors fed by one ROS 2 topic (module docstring)."""

    protocol = "ros2"

    def __init__(self, spec: InputSpec):
        super().__init__(spec)
        o = spec.options
        self.topic = o["topic"]
        self.codec = PoseCodec(o["type"])
        self.link = Ros2Link.of(o)
        session_config(self.link)  # a refused configuration fails here, not in the thread
        self._type_chunk = "/" + dds_type_name(self.codec.msgtype) + "/"
        self._clocks: dict[int, ClockMapper] = {}  # latency -> mapper (clock: map)
        self.subscription = None
        #: the newest attachment taken (sequence number, send stamp, GID)
        self.last_attachment = None

    def add_body(self, name: str, spec: InputSpec, covariance) -> Body:
        o = spec.options
        for b in self.bodies:
            if (b.options["frame_id"], b.options["child_frame_id"]) == (
                o["frame_id"], o["child_frame_id"]
            ):  # fmt: skip
                raise InputError(
                    f"sensor {name!r}: input.ros2 reads the same poses of {self.topic} as "
                    f"sensor {b.name!r} (name another frame_id / child_frame_id)"
                )
        return super().add_body(name, spec, covariance)

    # -- pure part --------------------------------------------------------------------------------
    def _handle(self, data, arrival_ns):
        key, payload, attachment = data
        if self._type_chunk not in key:
            raise PacketError("wrong type", key)
        if attachment is not None:
            try:
                self.last_attachment = decode_attachment(attachment)
            except AttachmentError as exc:
                raise PacketError("bad attachment", str(exc)) from None
        try:
            poses = self.codec.decode(payload)
        except FormatError as exc:
            raise PacketError("malformed message", str(exc)) from None
        tf = self.codec.short == "TFMessage"

        def one(b: Body):
            want = (b.options["frame_id"], b.options["child_frame_id"])
            for p in poses:
                if tf:
                    if (p.frame_id, p.child_frame_id) != want:
                        continue
                elif (want[0] is not None and p.frame_id != want[0]) or (
                    want[1] is not None and p.child_frame_id != want[1]
                ):
                    raise PacketError("frame mismatch", f"{p.frame_id} -> {p.child_frame_id}")
                return self._pose_sample(b, p, arrival_ns)
            return None  # a TFMessage without this sensor's transform

        return self._per_body(one)

    def _pose_sample(self, b: Body, p, arrival_ns: int):
        t = p.stamp_ns
        if b.options["clock"] == "map":
            lat = int(round(b.options["latency_ms"] * 1e6))
            clock = self._clocks.setdefault(lat, ClockMapper())
            if not clock.add(t + lat, arrival_ns):
                raise PacketError("clock jump not confirmed", f"stamp {t} ns")
            b.status.clock = clock.estimate
            t = clock.estimate.to_host(t + lat) - lat
        cov = None
        if p.covariance is not None:
            qx, qy, qz, qw = p.quaternion
            n2 = qx * qx + qy * qy + qz * qz + qw * qw
            if math.isfinite(n2) and near_unit(n2):
                n = math.sqrt(n2)
                cov = cov_from_ros(p.covariance, (qx / n, qy / n, qz / n, qw / n))
        return self._sample(b, t, arrival_ns, p.position, p.quaternion, cov)

    # -- transport ---------------------------------------------------------------------------------
    def _run(self, sink) -> None:
        try:
            ctx = Ros2Session.acquire(self.link)
        except (InputError, OSError, RuntimeError):
            self._event_all("session failed")
            self.ready.set()
            return
        o = self.options

        def on_message(key, payload, attachment, arrival_ns) -> None:
            if not self._stop.is_set():
                sink(self, (key, payload, attachment), arrival_ns)

        try:
            self.subscription = ctx.subscribe(
                o["domain"], o["node"], self.topic, self.codec.msgtype, self.codec.type_hash,
                on_message,
            )  # fmt: skip
            self._connected(True)
            self.ready.set()
            self._stop.wait()
        finally:
            self._connected(False)
            if self.subscription is not None:
                self.subscription.close()
                self.subscription = None
            ctx.release()
            self.ready.set()
