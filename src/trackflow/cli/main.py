"""The ``trackflow`` command line: one error boundary over thin subcommands.

Each subcommand lives in a module ``trackflow.cli.cmd_<name>`` exposing
``register(subparsers) -> argparse.ArgumentParser`` whose parser sets ``func`` (via
``set_defaults``) to a callable ``func(args) -> int``. The callable only parses arguments, calls
one typed library function and prints its result. A user's mistake (a
:class:`trackflow.errors.TrackflowError`) and a failure of the system (``OSError``: a missing
file, a refused connection) are turned into ``trackflow: error: <message>`` and exit code 1
here, and nowhere else; hints that name a library argument (``pass topic=``) are rewritten to
name the flag (``pass --topic``). ``trackflow --debug ...`` prints their traceback too. Any
other exception is a bug of trackflow and leaves with its traceback.

The subcommand modules import the library (numpy, scipy, numba) only inside their ``run``
functions, so ``trackflow --help`` and argument errors answer without loading it.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import re
import sys
import traceback

from ..errors import TrackflowError
from ..scheduler import stop_signals as on_stop_signals

__all__ = ["main", "build_parser", "ArgumentParser"]

#: Library keyword -> command line flag, for hints in error messages.
FLAG_FOR_OPTION = {
    "clean": "--clean",
    "format": "--format",
    "topic": "--topic",
    "columns": "--columns",
    "time_unit": "--time-unit",
    "source": "--source",
    "target": "--target",
    "overwrite": "--force",
    "delimiter": "--delimiter",
    "msgtype": "--msgtype",
}


class _Formatter(argparse.ArgumentDefaultsHelpFormatter):
    """Show defaults in ``--help``, but not for flags and options without a default."""

    def _get_help_string(self, action):
        if action.default in (None, False, argparse.SUPPRESS) or "%(default)" in (
            action.help or ""
        ):
            return action.help
        return super()._get_help_string(action)


class ArgumentParser(argparse.ArgumentParser):
    """argparse with defaults in the help and negative numbers (``-2e9``) as option values."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _Formatter)
        super().__init__(*args, **kwargs)
        # argparse only knows -1 and -.5 as numbers; accept exponents and signs too
        self._negative_number_matcher = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-inf$")


class Terminated(BaseException):
    """Raised by the signal handler on SIGTERM/SIGHUP, so ``finally`` blocks clean up."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _raise_terminated(signum, frame):
    raise Terminated(signum)


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every ``cmd_*`` module registered, in name order."""
    from .. import __version__

    parser = ArgumentParser(
        prog="trackflow",
        description="Ubiquitous 6-DoF tracking with error handling.",
    )
    parser.add_argument("--version", action="version", version=f"trackflow {__version__}")
    parser.add_argument(
        "--debug", action="store_true", help="show the traceback of an error, not one line"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=ArgumentParser)
    sub.required = True
    package = importlib.import_module("trackflow.cli")
    names = sorted(
        m.name for m in pkgutil.iter_modules(package.__path__) if m.name.startswith("cmd_")
    )
    for name in names:
        importlib.import_module(f"trackflow.cli.{name}").register(sub)
    return parser


def flag_hints(message: str) -> str:
    """Rewrite library hints (``pass topic=``, ``clean=True``, ``option(s) ['topic']``) to flags."""
    for option, flag in FLAG_FOR_OPTION.items():
        message = re.sub(rf"\b{option}=True\b", flag, message)
        message = re.sub(rf"\b{option}=(?=[\s;,)]|$)", f"{flag} ", message)
        message = message.replace(f"'{option}'", flag)
    return message.replace("  ", " ")


def _message(exc: BaseException) -> str:
    return flag_hints(str(exc) or type(exc).__name__)


def _quiet_stdout() -> None:
    """After a broken pipe: point stdout at /dev/null so the interpreter's flush is silent."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def _announce_compilation(quiet: bool) -> None:
    """Say once, on standard error, when a command must wait for kernels to compile, or will
    run on the slow NumPy backend (said even with ``--quiet``: it changes how long a run takes
    by two orders of magnitude)."""
    from ..math._backend import SELECTED, numpy_reason, set_notice

    said = set()

    def notice(event: str, source: str) -> None:
        if event in said:
            return
        said.add(event)
        if event == "numpy":
            reason = numpy_reason()
            if reason == SELECTED:  # a command that runs NumPy on purpose (`demo`) is not slow
                return
            print(
                f"trackflow: {reason}, so the numerical kernels run as plain NumPy: "
                "filtering is about 100x slower than compiled (a minute of tracking data can "
                "take minutes). `pip install numba` (installed with trackflow where numba has "
                "wheels) makes it fast.",
                file=sys.stderr,
                flush=True,
            )
        elif not quiet:
            print(
                "trackflow: compiling numerical kernels for their first use (cached for later "
                "runs; `trackflow compile` does this ahead of time) ...",
                file=sys.stderr,
                flush=True,
            )

    set_notice(notice)


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    _announce_compilation(quiet=getattr(args, "quiet", False))
    with on_stop_signals(_raise_terminated):
        return _run(args)


def _run(args) -> int:
    """The subcommand, behind the one error boundary."""
    try:
        code = int(args.func(args) or 0)
        sys.stdout.flush()
        return code
    except BrokenPipeError:
        # `trackflow ... | head`: the reader is gone; that is not an error of ours
        _quiet_stdout()
        return 0
    except (TrackflowError, OSError) as exc:
        # The one error boundary: a clear message and exit code 1 (the traceback with --debug).
        # Anything else is a bug of trackflow and leaves with its traceback.
        if getattr(args, "debug", False):
            traceback.print_exc()
        print(f"trackflow: error: {_message(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("trackflow: interrupted", file=sys.stderr)
        return 130
    except Terminated as exc:
        print(f"trackflow: terminated by signal {exc.signum}", file=sys.stderr)
        return 128 + exc.signum


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
