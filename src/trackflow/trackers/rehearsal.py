"""Rehearsing a packet's path on twins shortly before the next packet is due.

A receiving thread that sleeps for the 4 ms between two 240 Hz frames finds the code of the
packet's path cold: on the shared virtual machines measured (``bench/trackers.py``,
``experiments/trackers_rehearsal.py``), the first packet after a sleep costs three to four
times what the same work costs back to back, and the work right after it still twice. The
cost follows the code more than the data: running the same code on other objects shortly
before the packet takes most of it away.

:class:`Rehearsal` is that run. It holds twins of an input's packet path (an input of the same
class and bodies, and per body a source feeding a copy of its one Kalman filter) and, when
called, decodes the input's last frame again and delivers it through them, as the live path
does. Nothing of the live network is touched: the twins' counts, filters and answers are
their own and are dropped. :class:`~trackflow.trackers.waiting.DueWait` calls it once per
frame, timed to be over ``rehearse_us`` (the input option) before the frame is due; the price
is CPU, about as much as the packets' own path again.
"""

from __future__ import annotations

from collections.abc import Mapping

from ..dataflow import KalmanFilter
from .inputs import LiveInput, SampleBlock
from .runtime import LiveSource, LiveSources, _dispatched

__all__ = ["Rehearsal"]


def _twin_filter(c: KalmanFilter) -> KalmanFilter:
    """A fresh filter computing what ``c`` computes (:meth:`KalmanFilter.same_filter`)."""
    return KalmanFilter(
        f"{c.name} (rehearsal)",
        c.motion,
        role=c.role,
        history_s=c.history_s,
        stamp_offset_ns=c.stamp_offset_ns,
        max_extrapolation_ns=c.max_extrapolation_ns,
        filter_factory=c.filter_factory,
    )


class Rehearsal:
    """Twins of an input's packet path, run on a frame the input received (module docstring).

    Parameters
    ----------
    inp : LiveInput
        The input whose path is rehearsed: its class, connection spec and bodies are copied
        (no socket is opened), and its handshake state (:attr:`LiveInput.handshake`) is
        mirrored before every run.
    sources : mapping
        ``{sensor name: LiveSource}`` of the live network; each of the input's sensors must
        feed exactly one plain :class:`KalmanFilter` (the path :class:`LiveSources` batches).
    answer : bool
        Whether the live path asks for the packet's answers (``deliver_block(...,
        answer=...)``); the rehearsal then does too, and drops them.

    Raises
    ------
    ValueError
        When a sensor of ``inp`` has no source, or its source feeds something else than one
        plain Kalman filter (naming the sensor).
    """

    def __init__(self, inp: LiveInput, sources: Mapping, answer: bool = False):
        self.input = inp
        twin = self.twin = type(inp)(inp.spec)
        twins = {}
        for b in inp.bodies:
            src = sources.get(b.name)
            consumers = [] if src is None else src.consumers
            if len(consumers) != 1 or type(consumers[0][0]) is not KalmanFilter:
                raise ValueError(
                    f"sensor {b.name!r}: a rehearsal needs a source feeding one Kalman filter"
                )
            twin.add_body(b.name, b.spec, b.nominal)
            s = twins[b.name] = LiveSource(f"{b.name} (rehearsal)")
            s.consumers.append((_twin_filter(consumers[0][0]), 0))
        self.sources = LiveSources(twins)
        self.names = [b.name for b in inp.bodies]
        self.answer = answer
        self.runs = 0  # frames rehearsed
        self.cut = 0  # rehearsals left after decoding: a datagram was waiting
        self._last: bytes | None = None

    def __call__(self, data: bytes, arrival_ns: int, waiting=None) -> None:
        """Rehearse the path of the frame ``data`` received at ``arrival_ns`` [ns, host
        clock]; a frame already rehearsed is skipped (a lost frame leaves the last one).
        ``waiting()``, if given, is asked between decoding and delivery: when a datagram is
        already waiting, the rest is left (counted in :attr:`cut`) so that it is not kept."""
        if data is self._last:
            return
        self._last = data
        twin, inp = self.twin, self.input
        for attr in inp.handshake:  # what the live input learnt from its server
            setattr(twin, attr, getattr(inp, attr))
        samples = twin.handle(data, arrival_ns)
        if not samples:  # a frame of no body (or another message): nothing to warm
            return
        if waiting is not None and waiting():
            self.cut += 1
            return
        answer = (arrival_ns, _drop) if self.answer else None
        if type(samples) is SampleBlock:  # NatNet, every body plainly valid: arrays
            names = list(map(self.names.__getitem__, samples.index))
            self.sources.deliver_block(names, samples, arrival_ns, answer=answer)
        else:  # (body index, sample) pairs, delivered in order as trackflow run does
            names = [self.names[i] for i, _ in samples]
            self.sources.deliver(_dispatched(names, samples, arrival_ns))
            if answer is not None:
                self.sources.filters.answer([self.sources.row[n] for n in names], answer)
        self.runs += 1


def _drop(answers) -> None:
    """The rehearsed answers: dropped."""
