"""Live inputs made from a setup's ``input:`` specs: one input per connection.

The inputs themselves: :class:`~.live_input.LiveInput` (the common part, with
:class:`~.live_input.Sample` and :class:`~.live_input.SampleBlock`) and one per protocol,
:class:`~.dtrack_input.DTrackInput`, :class:`~.natnet_input.NatNetInput`,
:class:`~.vrpn_input.VrpnInput`, :class:`~.ros2_input.Ros2Input` (a ROS 2 topic) and
:class:`~.feed.FeedInput` (in-process feeds); their
names are also importable from here.
"""

from __future__ import annotations

import numpy as np

from ..dataflow import InputSpec
from ..timesync import ClockMapper
from .dtrack_input import DTrackInput
from .feed import FeedInput
from .live_input import (
    Body,
    CheckedSample,
    LiveInput,
    Sample,
    SampleBlock,
    enable_kernel_stamps,
    host_ns,
    recv_stamped,
)
from .natnet_input import NatNetInput
from .ros2_input import Ros2Input
from .vrpn_input import VrpnInput

__all__ = [
    "Body",
    "CheckedSample",
    "DTrackInput",
    "FeedInput",
    "LiveInput",
    "NatNetInput",
    "Ros2Input",
    "Sample",
    "SampleBlock",
    "VrpnInput",
    "enable_kernel_stamps",
    "host_ns",
    "make_input",
    "make_inputs",
    "recv_stamped",
    "warm_up_inputs",
]

_INPUTS = {"dtrack": DTrackInput, "natnet": NatNetInput, "vrpn": VrpnInput, "ros2": Ros2Input}


def warm_up_inputs() -> None:
    """Compile (or load) the inputs' kernels, the clock fit and NatNet's one pass over a
    frame's bodies, before any tracker is listened to."""
    ClockMapper.warm_up()
    NatNetInput.warm_up()


def _input_class(protocol: str) -> type[LiveInput]:
    """The input of a network tracker, else a :class:`~trackflow.trackers.feed.FeedInput`
    (in-process feeds such as ``optical``, see :func:`trackflow.dataflow.register_feed`)."""
    if protocol in _INPUTS:
        return _INPUTS[protocol]
    return FeedInput


def make_input(name: str, spec: InputSpec, covariance) -> LiveInput:
    """A live input (one connection) feeding the one sensor ``name``."""
    inp = _input_class(spec.protocol)(spec)
    inp.add_body(name, spec, covariance)
    return inp


def make_inputs(sensors: dict[str, tuple[InputSpec, np.ndarray]]) -> list[LiveInput]:
    """Live inputs for ``{sensor: (spec, nominal covariance)}``: sensors on the same
    connection (same server, ports) share one input, so each packet is decoded once."""
    by_key: dict[tuple, LiveInput] = {}
    for name, (spec, cov) in sensors.items():
        key = LiveInput.connection_key(spec)
        if key not in by_key:
            by_key[key] = _input_class(spec.protocol)(spec)
        by_key[key].add_body(name, spec, cov)
    return list(by_key.values())
