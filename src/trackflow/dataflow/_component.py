"""Component base class with push and pull ports (thesis 2.4.3).

A component may have

* push inputs: ``push(m, port)`` is called by an upstream component's push output;
* a push output: :meth:`Component.emit` calls every connected consumer;
* pull inputs: upstream components whose ``pull(t_ns)`` it calls;
* a pull output: ``pull(t_ns)`` returns a :class:`Measurement` valid at ``t_ns`` or ``None``
  (counted as a rejection) when it cannot.

Components are wired by :class:`trackflow.dataflow.Network`, which also owns the clock.
"""

from __future__ import annotations

from ..errors import InputError
from ._events import ComponentStats, Measurement

__all__ = ["Component"]


class _Clock:
    """The time source a network hands to its components (``now_ns``)."""

    __slots__ = ("now_ns", "dispatch_wall_ns")

    def __init__(self):
        self.now_ns = 0
        self.dispatch_wall_ns = 0


class Component:
    """Base class of every dataflow component.

    Class attributes declare the port kinds: ``push_in`` (number of push input ports,
    ``-1`` = any number), ``pull_in`` (number of pull inputs, ``-1`` = any), ``push_out`` and
    ``pull_out`` (booleans).
    """

    push_in: int = 0
    pull_in: int = 0
    push_out: bool = False
    pull_out: bool = False
    kind: str = "component"

    def __init__(self, name: str):
        if not isinstance(name, str) or not name:
            raise InputError(f"component names must be non-empty strings, got {name!r}")
        self.name = name
        self.stats = ComponentStats()
        self.consumers: list[tuple[Component, int]] = []
        self.inputs: list[Component] = []
        self.clock = _Clock()

    # -- ports ----------------------------------------------------------------------------------
    def push(self, m: Measurement, port: int = 0) -> None:
        """Receive a pushed event on input ``port``."""
        raise InputError(f"component {self.name!r} ({self.kind}) has no push input")

    def pull(self, t_ns: int) -> Measurement | None:
        """Return the relationship valid at ``t_ns`` or ``None`` (a counted rejection)."""
        raise InputError(f"component {self.name!r} ({self.kind}) has no pull output")

    def emit(self, m: Measurement) -> None:
        """Send ``m`` to every push consumer."""
        self.stats.events_out += 1
        for consumer, port in self.consumers:
            consumer.push(m, port)

    def reset(self) -> None:
        """Forget runtime state (statistics and buffers) before a new run."""
        self.stats = ComponentStats()

    def finish(self) -> None:
        """Called once after a run (close files and the like); nothing by default."""

    def describe(self) -> str:
        """One line for plans and logs."""
        return f"{self.kind} {self.name}"

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r}>"
