"""Clock synchronisation: one sign convention, three estimators, each with its uncertainty.

Convention (``docs/conventions.md``): the offset of a remote clock is ``host - remote``, so a
remote stamp maps onto the host clock as ``host = remote + offset`` (and drift, where one is
estimated, is ``d(host) / d(remote) - 1``). "Host" is the clock everything is mapped onto:
this process, the reference recording, the tracker an IMU is fused with.

* :func:`round_trip_offset` / :class:`RoundTripOffset`: from request-answer round trips
  (Cristian's method), between agents or with a tracker that answers echo requests;
* :class:`ClockMapper`: offset and drift of a stream of stamped packets from the lower
  envelope of ``receive time - stamp``, with round trips to remove the transport delay;
* :func:`correlation_offset`: between two recordings of one signal, by cross-correlation.
"""

from ._correlation import CorrelationOffset, correlation_offset
from ._envelope import ClockEstimate, ClockMapper, lower_envelope
from ._round_trip import RoundTripOffset, round_trip_offset

__all__ = [
    "ClockEstimate",
    "ClockMapper",
    "CorrelationOffset",
    "RoundTripOffset",
    "correlation_offset",
    "lower_envelope",
    "round_trip_offset",
]
