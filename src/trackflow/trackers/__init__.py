"""Live trackers in and out: DTrack, NatNet and VRPN decoders, transports, clock mapping.

Each protocol has a pure decoder (bytes -> typed frames, no I/O) and an encoder (used by the
simulated senders and for golden packets): :mod:`.dtrack`, :mod:`.natnet`, :mod:`.vrpn`.
Decoding errors are :class:`PacketError` with a short ``reason`` that sensors count.
:func:`run_live` drives a setup's dataflow from its trackers and records it; :func:`replay`
reproduces a recorded run bit for bit; :class:`VrpnTrackerServer` serves answers to VRPN
applications; :func:`simulate` replays a recording as a tracker.
Conventions: ``docs/conventions.md``; protocols and time mapping: ``docs/trackers.md``.
"""

from ..dataflow import InputSpec, parse_input
from ..timesync import ClockEstimate, ClockMapper
from ._packet import MAX_DATAGRAM, PacketError
from .inputs import LiveInput, Sample, make_input, make_inputs
from .runtime import LiveSource, ReplayResult, RunResult, replay, run_live
from .simulate import SimConfig, Simulator, simulate
from .status import SensorStatus
from .vrpn_server import VrpnTrackerServer

__all__ = [
    "MAX_DATAGRAM",
    "ClockEstimate",
    "ClockMapper",
    "InputSpec",
    "LiveInput",
    "LiveSource",
    "PacketError",
    "ReplayResult",
    "RunResult",
    "Sample",
    "SensorStatus",
    "SimConfig",
    "Simulator",
    "VrpnTrackerServer",
    "make_input",
    "make_inputs",
    "parse_input",
    "replay",
    "run_live",
    "simulate",
]
