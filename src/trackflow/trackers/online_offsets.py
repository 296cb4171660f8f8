"""The relative delays of a live run's trackers, estimated while it runs and applied when the
setup opts in (the setup's ``online_offsets:`` block, :class:`trackflow.dataflow.OnlineOffsetSpec`;
thesis 10.3.6-10.3.7).

Every two sensors whose bodies are one (:func:`trackflow.calibration.rigid_pairs`) and whose
trackers are two connections get an :class:`~trackflow.calibration.OnlineClockOffset`: it
listens to both sensors' filters and, every ``every_s`` on a thread of its own (off the
dispatch path), estimates ``offset_ms``, the time of ``a`` minus the time of ``b`` of one
moment, on the exposure times as the run makes them.

**Applying** (``apply: true``). A tracker is one clock, so a correction belongs to a
connection (a :class:`~trackflow.trackers.live_input.LiveInput`), all its bodies at once.
The reference sensor's connection keeps its times; every other connection with a sensor
paired to one of the reference connection's is corrected by the inverse-variance mean of
those pairs' estimates, once the mean is certain (``sigma <= max_sigma_ms`` over at least
``min_span_s``) and moves the correction by more than ``max(min_step_ms, 2 sigma)``. The
correction is added to the connection's exposure times from its next packet on
(:meth:`LiveInput.request_shift`); at that packet, on the receiving thread, the pairs of
that connection forget what they held (it was on the old times), so the next estimate is
the residual on the corrected times, near zero once the correction is right.

What is recorded stays replayable to the bit: a sensor's input recording holds the
exposure times the run delivered, corrected, and each correction is a line of
``out.offsets.jsonl`` next to ``out.tfrec`` (written and flushed as it happens)::

    {"t_ns": 1700000000123456789, "sensors": ["vrpn"], "reference": "natnet",
     "step_ms": 15.02, "total_ms": 15.02, "estimate_ms": 15.02, "sigma_ms": 0.11}

``t_ns`` is the dispatch time of the first packet on the corrected times; the raw time of a
recorded sample is its recorded time less the ``total_ms`` in effect when it arrived.
"""

from __future__ import annotations

import json
import math
import threading
from pathlib import Path

from ..calibration import OnlineClockOffset, rigid_pairs
from ..dataflow import OnlineOffsetSpec, Setup
from ..errors import InputError

__all__ = ["OnlineOffsets", "offsets_log_path", "offset_text"]


def offsets_log_path(record) -> Path:
    """``out.offsets.jsonl`` next to the answers file ``out.tfrec``."""
    record = Path(record)
    stem = record.name[: -len(record.suffix)] if record.suffix else record.name
    return record.with_name(f"{stem}.offsets.jsonl")


def offset_text(r: dict) -> str:
    """One estimate of :meth:`OnlineOffsets.step` as a status line's text."""
    head = f"{r['a']} - {r['b']}: "
    if "why" in r:
        return head + r["why"]
    text = f"{r['offset_ms']:.1f} +- {r['sigma_ms']:.1f} ms over {r['span_s']:.0f} s"
    if r.get("applied_ms"):
        text += f" (after a correction of {r['applied_ms']:+.1f} ms)"
    return head + text


class OnlineOffsets:
    """The online offsets of one live run (module docstring).

    Parameters
    ----------
    setup : Setup
        The run's setup; its pairs are those of sensors with an ``input:``.
    spec : OnlineOffsetSpec
        What to estimate and whether to apply it.
    log_path : path, optional
        Where each correction is written (``None``: not written).
    """

    def __init__(self, setup: Setup, spec: OnlineOffsetSpec, log_path=None):
        pairs = [
            (a, b) for a, b in rigid_pairs(setup.graph) if a in setup.inputs and b in setup.inputs
        ]
        self.spec = spec
        self.estimators = [
            OnlineClockOffset(a, b, window_s=spec.window_s, max_offset_s=spec.max_offset_s)
            for a, b in pairs
        ]
        paired = {n for p in pairs for n in p}
        self.reference = spec.reference or next((n for n in setup.inputs if n in paired), None)
        #: every correction applied, in order (the lines of the log)
        self.events: list[dict] = []
        self._lines: list[str] = []
        self._lock = threading.Lock()  # the lines: made on two threads, taken on a third
        self._latest: dict[str, dict] = {}  # sensor -> the newest estimate of a pair of it
        self._input_of: dict = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._log = None if log_path is None else open(log_path, "w", encoding="utf-8")

    def attach(self, net, inputs) -> None:
        """Listen to the sensors' filters in ``net`` (components ``kf_<sensor>``) and start
        the estimating thread; ``inputs`` are the run's connections (their bodies name
        the sensors)."""
        self.connect(inputs)
        for est in self.estimators:
            for name, add in ((est.a, est.add_a), (est.b, est.add_b)):
                kf = net.components.get(f"kf_{name}")
                if kf is None:
                    raise InputError(f"online offsets: sensor {name!r} has no filter in the run")
                kf.measured.listeners.append(add)
        self._thread = threading.Thread(target=self._loop, name="online-offsets", daemon=True)
        self._thread.start()

    def connect(self, inputs) -> None:
        """The run's connections (:class:`~trackflow.trackers.live_input.LiveInput`; their
        bodies name the sensors): what a correction moves."""
        self._input_of = {b.name: inp for inp in inputs for b in inp.bodies}

    def _loop(self) -> None:
        while not self._stop.wait(self.spec.every_s):
            self.step()

    def step(self) -> list[dict]:
        """Estimate every pair now (each with ``applied_ms``, the correction in effect on
        ``t_a - t_b``), apply what is certain when the spec says so, and queue a status
        line per pair (:meth:`new_lines`). Returns the estimates."""
        out = [self._estimate(est) for est in self.estimators]
        with self._lock:
            self._lines += [f"online offset {offset_text(r)}" for r in out]
            for r in out:
                if "offset_ms" in r:
                    self._latest[r["a"]] = self._latest[r["b"]] = r
        if self.spec.apply and self.reference is not None:
            self._apply(out)
        return out

    def _shift_ms(self, sensor: str) -> float:
        inp = self._input_of.get(sensor)
        return 0.0 if inp is None else inp.shift_ns * 1e-6

    def _estimate(self, est: OnlineClockOffset) -> dict:
        r = est.estimate()
        r["applied_ms"] = round(self._shift_ms(est.b) - self._shift_ms(est.a), 3)
        return r

    def _apply(self, estimates: list[dict]) -> None:
        """Correct every connection paired with the reference's by what its pairs agree on."""
        ref = self._input_of.get(self.reference)
        wanted: dict[int, list[tuple[float, float]]] = {}
        for r in estimates:
            if "offset_ms" not in r or not self._certain(r):
                continue
            ia, ib = self._input_of.get(r["a"]), self._input_of.get(r["b"])
            if ia is None or ib is None or ia is ib:
                continue
            if ia is ref:  # t_ref = t_b + offset: b's times move by +offset
                wanted.setdefault(id(ib), []).append((r["offset_ms"], r["sigma_ms"]))
            elif ib is ref:  # t_a = t_ref + offset: a's times move by -offset
                wanted.setdefault(id(ia), []).append((-r["offset_ms"], r["sigma_ms"]))
        inputs = {id(i): i for i in self._input_of.values()}
        for key, values in wanted.items():
            w = [1.0 / max(s, 1e-6) ** 2 for _, s in values]
            mean = sum(wi * x for wi, (x, _) in zip(w, values)) / sum(w)
            sigma = 1.0 / math.sqrt(sum(w))
            if abs(mean) <= max(self.spec.min_step_ms, 2.0 * sigma):
                continue
            inp = inputs[key]
            total_ns = inp.shift_ns + int(round(mean * 1e6))
            event = {"sensors": [b.name for b in inp.bodies], "reference": self.reference,
                     "step_ms": round(mean, 3), "total_ms": round(total_ns * 1e-6, 3),
                     "estimate_ms": round(mean, 3), "sigma_ms": round(sigma, 3)}  # fmt: skip
            inp.request_shift(total_ns, lambda t_ns, e=event, i=inp: self._applied(t_ns, e, i))

    def _certain(self, r: dict) -> bool:
        return r["sigma_ms"] <= self.spec.max_sigma_ms and r["span_s"] >= self.spec.min_span_s

    def _applied(self, t_ns: int, event: dict, inp) -> None:
        """On ``inp``'s receiving thread, before its first packet on the corrected times:
        its pairs forget the old times, and the correction is logged."""
        names = {b.name for b in inp.bodies}
        for est in self.estimators:
            if est.a in names or est.b in names:
                est.forget()
        event = {"t_ns": int(t_ns), **event}
        self.events.append(event)
        with self._lock:
            self._lines.append(
                f"online offset: {', '.join(event['sensors'])} corrected by "
                f"{event['step_ms']:+.2f} ms (in all {event['total_ms']:+.2f} ms against "
                f"{event['reference']})"
            )
        if self._log is not None:
            self._log.write(json.dumps(event) + "\n")
            self._log.flush()

    def latest(self) -> dict[str, dict]:
        """Each paired sensor's newest estimate (of one of its pairs): ``{"a", "b",
        "offset_ms", "sigma_ms", "span_s", "peak", "applied_ms"}`` (for a view)."""
        with self._lock:
            return dict(self._latest)

    def new_lines(self) -> list[str]:
        """The status lines since the last call (estimates and corrections)."""
        with self._lock:
            out, self._lines = self._lines, []
        return out

    def close(self) -> None:
        """Stop the estimating thread and close the log."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if self._log is not None:
            self._log.close()
            self._log = None

    def final(self) -> list[dict]:
        """The estimate of every pair over the run's last window (on the corrected times,
        with the correction in effect: ``applied_ms``)."""
        return [self._estimate(est) for est in self.estimators]
