"""The one output policy of every writer: atomic, no silent overwrite, nothing left on failure.

Every writer in :mod:`trackflow.io` produces its file (or ROS 2 bag directory) through
:func:`atomic_output`:

1. the data go to a hidden temporary name in the *target directory*
   (``.<name>.tftmp-<pid>-<random>``), so the final rename never crosses a file system;
2. only a complete result is renamed to the final name (``os.replace``; for a directory that
   replaces an existing one, the old tree is moved aside first and removed afterwards), so a
   reader sees either the old file or the complete new one, never a partial one;
3. an existing final name is an error unless ``overwrite=True``. Without overwrite, a file is
   published with ``os.link`` (fails atomically if the name appeared meanwhile);
4. on any exception (and on ``SIGTERM``/``SIGHUP``/``SIGINT``, which the command line turns into
   exceptions) the temporary is removed. A ``SIGKILL`` cannot be caught: it leaves the hidden
   temporary (never the final name); the next write into that directory removes temporaries
   whose process no longer exists.

``path`` ``"-"`` means standard output: the result is built in a private temporary directory
and then copied to ``sys.stdout`` (text and binary formats alike).
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import shutil
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

from ..errors import InputError, StateError

__all__ = ["STDIO", "atomic_output", "remove_stale_temporaries"]

#: The path that stands for standard input (readers) or standard output (writers).
STDIO = "-"

_TMP = re.compile(r"^\.(?P<name>.+)\.tftmp-(?P<pid>\d+)-[0-9a-f]{8}$")


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_temporaries(directory) -> list[Path]:
    """Remove temporaries left in ``directory`` by killed writers (their process is gone).

    Returns the removed paths. Temporaries of running processes are left alone.
    """
    removed = []
    with contextlib.suppress(OSError):
        for entry in Path(directory).iterdir():
            m = _TMP.match(entry.name)
            if m and int(m["pid"]) != os.getpid() and not _alive(int(m["pid"])):
                _remove(entry)
                removed.append(entry)
    return removed


@contextlib.contextmanager
def atomic_output(path, *, overwrite: bool = False, directory: bool = False) -> Iterator[Path]:
    """Yield a temporary path to write to; publish it as ``path`` when the block succeeds.

    Parameters
    ----------
    path : str or Path
        Final name, or ``"-"`` for standard output (files only).
    overwrite : bool
        Replace an existing ``path``. Default: refuse with ``FileExistsError`` naming it.
    directory : bool
        The writer creates a directory at the yielded path (a ROS 2 bag) rather than a file.
        The yielded path does not exist yet in either case.

    Raises
    ------
    FileExistsError
        ``path`` exists and ``overwrite`` is false (checked before writing and at publication).
    """
    if str(path) == STDIO:
        if directory:
            raise InputError("a directory output (ROS 2 bag) cannot go to standard output")
        with tempfile.TemporaryDirectory(prefix="trackflow-") as d:
            tmp = Path(d) / "out"
            yield tmp
            _copy_to_stdout(tmp)
        return
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise FileNotFoundError(f"{path}: the directory {parent} does not exist")
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path}: exists already (pass overwrite=True to replace it)")
    remove_stale_temporaries(parent)
    holder = parent / f".{path.name}.tftmp-{os.getpid()}-{secrets.token_hex(4)}"
    if directory:  # a hidden folder holding the tree under its final name (bags name files so)
        holder.mkdir()
        tmp = holder / path.name
    else:
        tmp = holder
    try:
        yield tmp
        if not tmp.exists():
            raise StateError(f"{path}: the writer produced nothing")
        _publish(tmp, path, overwrite, directory)
    finally:
        _remove(holder)


def _publish(tmp: Path, path: Path, overwrite: bool, directory: bool) -> None:
    if not directory:
        if overwrite:
            os.replace(tmp, path)
            return
        try:
            os.link(tmp, path)  # atomic and never clobbers
        except FileExistsError:
            raise FileExistsError(
                f"{path}: exists already (pass overwrite=True to replace it)"
            ) from None
        except OSError:  # file systems without hard links
            if path.exists():
                raise FileExistsError(f"{path}: exists already") from None
            os.rename(tmp, path)
        return
    if path.exists():
        if not overwrite:
            raise FileExistsError(f"{path}: exists already (pass overwrite=True to replace it)")
        old = path.parent / f".{path.name}.tftmp-{os.getpid()}-{secrets.token_hex(4)}"
        os.rename(path, old)
        try:
            os.rename(tmp, path)
        except OSError:
            os.rename(old, path)
            raise
        _remove(old)
    else:
        os.rename(tmp, path)


def _copy_to_stdout(tmp: Path) -> None:
    out = getattr(sys.stdout, "buffer", None)
    sys.stdout.flush()
    with open(tmp, "rb") as f:
        if out is None:  # a text-only stdout (tests capturing output)
            sys.stdout.write(f.read().decode("utf-8", errors="replace"))
        else:
            shutil.copyfileobj(f, out)
            out.flush()
