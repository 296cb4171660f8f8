"""The path switches of a live run's queries (failover, :class:`trackflow.dataflow.PathSwitch`):
kept per query, shown on the status lines, and recorded next to the answers.

Recording: ``out.switches.jsonl`` next to ``out.tfrec``, one JSON object per switch, written
(and flushed) as it happens, so a killed run keeps every switch up to its end::

    {"query": "head_pose", "t_ns": 1700000000123456789, "from": 0, "to": 1,
     "reason": "sensor natnet: no data for 212 ms"}

An answer at time ``t`` of a query came from the ``to`` path of the query's last switch at or
before ``t`` (path 0, the preferred one, before the first).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from ..dataflow import SwitchEvent
from ..errors import FormatError

__all__ = ["SwitchLog", "read_switch_log", "switch_log_path"]


def switch_log_path(record) -> Path:
    """``out.switches.jsonl`` next to the answers file ``out.tfrec``."""
    record = Path(record)
    stem = record.name[: -len(record.suffix)] if record.suffix else record.name
    return record.with_name(f"{stem}.switches.jsonl")


class SwitchLog:
    """Every query's switches in order; with ``path``, each one appended to that file."""

    def __init__(self, path: Path | None = None):
        self.path = path
        self.events: dict[str, list[SwitchEvent]] = {}
        self._shown = 0
        self._order: list[tuple[str, SwitchEvent]] = []
        self._file = None if path is None else open(path, "w", encoding="utf-8")

    def callback(self, query: str) -> Callable[[SwitchEvent], None]:
        """The ``on_switch`` of ``query``'s path switch."""

        def on_switch(event: SwitchEvent) -> None:
            self.events.setdefault(query, []).append(event)
            self._order.append((query, event))
            if self._file is not None:
                self._file.write(json.dumps({"query": query, **event.as_dict()}) + "\n")
                self._file.flush()

        return on_switch

    def new_lines(self) -> list[str]:
        """One status line per switch since the last call."""
        out = [
            f"query {q}: path {e.from_path} -> {e.to_path} ({e.reason})"
            for q, e in self._order[self._shown :]
        ]
        self._shown = len(self._order)
        return out

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def read_switch_log(path) -> dict[str, list[SwitchEvent]]:
    """The switches recorded in ``path`` by query (an empty mapping if the file is absent:
    a run without failover paths, or from before switches were recorded).

    Raises
    ------
    FormatError
        A line that is not a switch, naming the file and line.
    """
    path = Path(path)
    out: dict[str, list[SwitchEvent]] = {}
    if not path.exists():
        return out
    with open(path, encoding="utf-8") as f:
        for n, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                d = json.loads(line)
                event = SwitchEvent(int(d["t_ns"]), int(d["from"]), int(d["to"]), str(d["reason"]))
                query = str(d["query"])
            except (ValueError, KeyError, TypeError) as exc:
                raise FormatError(f"{path}:{n}: not a path switch ({exc})") from None
            out.setdefault(query, []).append(event)
    return out
