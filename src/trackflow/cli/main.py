"""The ``trackflow`` command line: one error boundary over thin subcommands.

Each subcommand lives in a module ``trackflow.cli.cmd_<name>`` exposing
``register(subparsers) -> argparse.ArgumentParser`` whose parser sets ``func`` (via
``set_defaults``) to a callable ``func(args) -> int``. The callable only parses arguments, calls
one typed library function and prints its result. Library errors (``ValueError``,
``FileNotFoundError`` ...) are turned into ``trackflow: error: <message>`` and exit code 1 here,
and nowhere else.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every ``cmd_*`` module registered, in name order."""
    parser = argparse.ArgumentParser(
        prog="trackflow",
        description="Ubiquitous 6-DoF tracking with error handling.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    package = importlib.import_module("trackflow.cli")
    names = sorted(
        m.name for m in pkgutil.iter_modules(package.__path__) if m.name.startswith("cmd_")
    )
    for name in names:
        importlib.import_module(f"trackflow.cli.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, OSError, KeyError, RuntimeError) as exc:
        # The one error boundary: a clear message and exit code 1, no traceback.
        msg = str(exc) or type(exc).__name__
        if isinstance(exc, KeyError):
            msg = f"missing key {msg}"
        print(f"trackflow: error: {msg}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("trackflow: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
