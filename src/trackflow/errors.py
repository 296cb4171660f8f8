"""The errors trackflow raises: each says what was asked and why it could not be done.

Every error of trackflow derives from :class:`TrackflowError` and from the builtin exception it
stands for (``ValueError``, ``RuntimeError``, ``ImportError``), so ``except ValueError`` keeps
working and ``except TrackflowError`` catches every mistake a user can make, while a bug
(``KeyError``, ``AttributeError`` ...) is not caught by it. The command line turns a
``TrackflowError`` into one line on standard error (``--debug`` shows the traceback).

====================  ============  =========================================================
error                 builtin       raised when
====================  ============  =========================================================
InputError            ValueError    an argument or a value in the data is not acceptable
ConfigError           ValueError    a key of a file (setup, agent, optical, model): file, line
FormatError           ValueError    a recording or packet cannot be read: file and line, or
                                    sensor and packet
PlanError             ValueError    a query has no answer in the graph (no path, unknown
                                    frame, edge or query)
ExtrapolationError    ValueError    a time outside the data was asked for
NumericalError        ValueError    a computation on acceptable input found no answer
                                    (singular, degenerate, did not converge)
StateError            RuntimeError  an object was asked for something its state cannot give
ServiceError          RuntimeError  a process, server or network trackflow runs failed
MissingExtraError     ImportError   an optional dependency is not installed: names the extra
====================  ============  =========================================================
"""

from __future__ import annotations

__all__ = [
    "ConfigError",
    "ExtrapolationError",
    "FormatError",
    "InputError",
    "MissingExtraError",
    "NumericalError",
    "PlanError",
    "ServiceError",
    "StateError",
    "TrackflowError",
    "where",
]


def where(file=None, line: int | None = None, key: str | None = None) -> str:
    """``"file:line: key"`` with the parts that are known (``""`` when none is)."""
    head = "" if file is None else str(file)
    if line:
        head = f"{head}:{int(line)}" if head else f"line {int(line)}"
    if key:
        head = f"{head}: {key}" if head else str(key)
    return head


class TrackflowError(Exception):
    """Base of every error trackflow raises on purpose (a user's mistake, not a bug)."""

    def __reduce__(self):
        # errors cross process boundaries (worker pools); subclasses have their own __init__
        # arguments, so a copy is rebuilt from the message and the attributes, not by __init__
        return _rebuild, (type(self), self.args, self.__dict__)


def _rebuild(cls, args, state):
    err = cls.__new__(cls, *args)
    err.args = args
    err.__dict__.update(state)
    return err


class InputError(TrackflowError, ValueError):
    """An argument, or a value in the data given, that trackflow cannot accept."""


class ConfigError(InputError):
    """A file of settings (setup, agent, optical, calibration, model file) that is wrong.

    Parameters
    ----------
    message : str
        Why the key is wrong.
    file, line, key : optional
        Where: the file, the 1-based line and the key; the message is prefixed with the known
        parts (``setup.yaml:12: sensors[0].rate_hz: must be > 0``).
    """

    def __init__(self, message: str, file=None, line: int | None = None, key=None):
        self.file = None if file is None else str(file)
        self.line = int(line) if line else None
        self.key = None if key is None else str(key)
        self.reason = message
        head = where(self.file, self.line, self.key)
        super().__init__(f"{head}: {message}" if head else message)


class FormatError(InputError):
    """A recording, file or network packet whose content cannot be read.

    Parameters
    ----------
    message : str
        What is wrong with the content.
    file, line : optional
        Where, for a file.
    sensor, packet : optional
        Where, for a live input: the sensor (or input) and the packet (a count or an id).
    """

    def __init__(self, message: str, file=None, line: int | None = None, sensor=None, packet=None):
        self.file = None if file is None else str(file)
        self.line = int(line) if line else None
        self.sensor = sensor
        self.packet = packet
        self.reason = message
        head = where(self.file, self.line)
        if sensor is not None:
            head = f"{head}: " if head else ""
            head += f"sensor {sensor!s}" + ("" if packet is None else f", packet {packet!s}")
        super().__init__(f"{head}: {message}" if head else message)


class PlanError(TrackflowError, ValueError):
    """A query that the graph cannot answer: no path, or an unknown frame, edge or query."""


class ExtrapolationError(TrackflowError, ValueError):
    """A time outside the data was asked for (tf2's message, in trackflow's units).

    Parameters
    ----------
    what : str
        What was asked (``"T_world_head"``, ``"the estimate"``).
    asked_s : float
        The time asked for [s].
    first_s, last_s : float or None
        Oldest and newest time of the data [s] (both ``None``: no data at all; one ``None``:
        that side is open).
    note : str
        Why the data ends there (``"the history keeps 2 s"``).

    Times that look like Unix time (after 2001) are shown as UTC clock times.
    """

    def __init__(self, what: str, asked_s: float, first_s=None, last_s=None, note: str = ""):
        self.what, self.asked_s, self.first_s, self.last_s = what, asked_s, first_s, last_s
        if first_s is None and last_s is None:
            msg = f"{what} at {_clock(asked_s)}: no data yet"
        elif last_s is not None and asked_s > last_s:
            msg = (
                f"{what} at {_clock(asked_s)} would need extrapolation "
                f"{_ms(asked_s - last_s)} into the future; newest data {_clock(last_s)}"
            )
        else:
            msg = (
                f"{what} at {_clock(asked_s)} would need extrapolation "
                f"{_ms(first_s - asked_s)} into the past; oldest data {_clock(first_s)}"
            )
        super().__init__(f"{msg}; {note}" if note else msg)


def _ms(dt_s: float) -> str:
    return f"{dt_s * 1e3:.3g} ms"


def _clock(t_s: float) -> str:
    """``12:00:01.250`` (UTC) for Unix times, else seconds with microsecond digits."""
    if t_s > 1e9:  # after 2001-09-09: a wall clock stamp
        import datetime

        d = datetime.datetime.fromtimestamp(t_s, datetime.UTC)
        return d.strftime("%H:%M:%S.") + f"{d.microsecond // 1000:03d}"
    return f"{t_s:.6f} s"


class NumericalError(TrackflowError, ValueError):
    """A computation on acceptable input that found no answer (singular, degenerate, diverged)."""


class StateError(TrackflowError, RuntimeError):
    """An object asked for something its present state cannot give (not initialised ...)."""


class ServiceError(TrackflowError, RuntimeError):
    """A process, server or network trackflow started or joined did not do its part."""


class MissingExtraError(TrackflowError, ImportError):
    """An optional dependency is not installed; the message names the pip extra.

    Parameters
    ----------
    module : str
        The module that could not be imported (``"zenoh"``).
    extra : str
        trackflow's extra that installs it (``"distributed"``).
    feature : str
        What needs it (``"trackflow agent"``).
    """

    def __init__(self, module: str, extra: str, feature: str):
        self.module, self.extra, self.feature = module, extra, feature
        super().__init__(
            f"{feature} needs the Python package {module!r}, which is not installed: "
            f"pip install 'trackflow[{extra}]'",
            name=module,
        )
