"""Live trackers in and out: DTrack, NatNet and VRPN decoders, transports, clock mapping.

Each protocol has a pure decoder (bytes -> typed frames, no I/O) and an encoder (used by the
simulated senders and for golden packets): :mod:`.dtrack`, :mod:`.natnet`, :mod:`.vrpn`.
Decoding errors are :class:`PacketError` with a short ``reason`` that sensors count.
Conventions: ``docs/conventions.md``; protocols and time mapping: ``docs/trackers.md``.
"""

from ._packet import MAX_DATAGRAM, PacketError

__all__ = ["MAX_DATAGRAM", "PacketError"]
