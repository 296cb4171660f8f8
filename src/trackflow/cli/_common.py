"""Helpers shared by the subcommands: reading and writing recordings, parsing lists.

Nothing here imports the library at module level (``--help`` must not load numpy/numba); the
names that argparse needs up front are mirrored below and checked against the library by
``tests/cli/test_cli_flags.py``.
"""

from __future__ import annotations

import argparse
import sys

from ..errors import InputError

__all__ = [
    "FORMATS",
    "LEARNED_ORDERS",
    "add_input",
    "add_output",
    "add_learned_orders",
    "load",
    "parse_columns",
    "parse_horizons",
    "parse_ints",
    "parse_orders",
    "save",
]

#: ``trackflow.io.FORMATS`` (mirrored so that parsing arguments does not import the library).
FORMATS = ("native", "tum", "euroc", "csv", "rosbag", "quest", "broad", "kitti")
#: ``trackflow.io.MESSAGE_TYPES`` (mirrored for the same reason).
ROS_MESSAGE_TYPES = (
    "PoseStamped",
    "PoseWithCovarianceStamped",
    "TransformStamped",
    "Odometry",
    "TFMessage",
)
#: ``trackflow.evaluation.LEARNED_ORDERS`` (mirrored for the same reason).
LEARNED_ORDERS = (3, 5, 10)
TIME_UNITS = ("s", "ms", "us", "ns")
#: Files larger than this get a "reading ..." line on standard error.
LARGE_FILE_BYTES = 20_000_000

__all__ = ["add_input", "load", "parse_horizons", "parse_ints", "parse_orders"]
#: Reader options a flag sets: dest -> library keyword.
_READ_OPTIONS = {
    "topic": "topic",
    "columns": "columns",
    "time_unit": "time_unit",
    "delimiter": "delimiter",
    "source": "source",
    "target": "target",
}


def add_input(
    parser: argparse.ArgumentParser, name: str = "file", suffix: str = "", nargs=None
) -> None:
    """Add a recording argument with its reading options.

    ``suffix`` distinguishes the options of a second input (``--format2``, ``--source2`` ...);
    ``nargs="+"`` takes several recordings (read with the same options).
    """
    parser.add_argument(
        name,
        nargs=nargs,
        help="recording ('-' reads standard input; format guessed from content/extension)"
        + ("; several with --merge" if nargs else ""),
    )
    parser.add_argument(
        f"--format{suffix}", choices=FORMATS, default=None, help="input format (default: guessed)"
    )
    if suffix:
        parser.add_argument(f"--source{suffix}", default=None, help="frame name of its source")
        parser.add_argument(f"--target{suffix}", default=None, help="frame name of its target")
        return
    parser.add_argument(
        "--clean",
        action="store_true",
        help="drop/repair malformed rows instead of failing (listed on stderr)",
    )
    g = parser.add_argument_group("reading options")
    g.add_argument("--topic", default=None, help="ROS bag topic (when a bag holds several)")
    g.add_argument(
        "--columns",
        default=None,
        help="CSV column mapping, e.g. 't=time,x=px,y=py,z=pz,qx=0,...' (names or 0-based "
        "indices; fields t x y z qx qy qz qw [confidence flags cov_i_j])",
    )
    g.add_argument("--time-unit", choices=TIME_UNITS, default=None, help="CSV time unit (s)")
    g.add_argument("--delimiter", default=None, help="CSV delimiter (,)")
    g.add_argument(
        "--source", default=None, help="frame name of the poses' reference (T_source_target)"
    )
    g.add_argument("--target", default=None, help="frame name of the tracked body")
    g.add_argument(
        "--quiet", action="store_true", help="no read report or progress on standard error"
    )


def add_output(p, name: str = "output") -> None:
    """Add an output argument with ``--to`` and ``--force`` (the one output policy)."""
    p.add_argument(name, help="output file ('-' writes standard output; format from --to or "
                   "the extension)")  # fmt: skip
    p.add_argument("--to", choices=FORMATS, default=None, help="output format")
    p.add_argument(
        "--msgtype",
        choices=ROS_MESSAGE_TYPES,
        default=None,
        help="ROS bag output: the message type (default PoseWithCovarianceStamped with a "
        "covariance, else PoseStamped; TFMessage writes /tf)",
    )
    p.add_argument(
        "--force", action="store_true", help="replace an existing output (default: refuse)"
    )


def parse_columns(text: str) -> dict[str, str | int]:
    """``"t=time,x=1"`` -> ``{"t": "time", "x": 1}`` (digits are 0-based column indices)."""
    out: dict[str, str | int] = {}
    for item in text.split(","):
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise InputError(f"--columns expects field=column pairs, got {item!r} in {text!r}")
        value = value.strip()
        out[key.strip()] = int(value) if value.isdigit() else value
    return out


def _reader_options(args, suffix: str = "") -> dict:
    opts = {}
    for dest, key in _READ_OPTIONS.items():
        value = getattr(args, dest + suffix, None)
        if value is not None:
            opts[key] = parse_columns(value) if key == "columns" else value
    return opts


def load(
    args, name: str = "file", suffix: str = "", min_samples: int = 1, with_report: bool = False
):
    """Read the recording of argument ``name`` with the options the user gave.

    The read report goes to standard error whenever the reader dropped, repaired or ignored
    anything, or guessed the format (unless ``--quiet``). Fewer than ``min_samples`` samples
    is an error naming the file and what was dropped. ``with_report``: ``(stream, report)``.
    """
    import os
    import time

    from ..io import read_stream

    path = getattr(args, name)
    fmt = getattr(args, "format" + suffix, None)
    quiet = getattr(args, "quiet", False)
    big = path != "-" and os.path.isfile(path) and os.path.getsize(path) > LARGE_FILE_BYTES
    if big and not quiet:
        print(f"trackflow: reading {path} ({os.path.getsize(path) / 1e6:.0f} MB) ...",
              end="", file=sys.stderr, flush=True)  # fmt: skip
    t0 = time.perf_counter()
    stream, report = read_stream(
        path, format=fmt, clean=getattr(args, "clean", False), **_reader_options(args, suffix)
    )
    if big and not quiet:
        print(f" {len(stream)} samples in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    # rescaling quaternions within the rounding of their printed digits is not news
    notes = [n for n in report.notes if "rounding tolerance" not in n]
    notable = report.dropped or report.normalized or report.truncated or notes
    if notable and not quiet:
        text = report.summary().replace(
            f"({report.format})",
            f"(read as {report.format}" + ("" if fmt else ", format guessed") + ")",
            1,
        )
        print("trackflow: " + text.replace("\n", "\n  "), file=sys.stderr)
    if len(stream) < min_samples:
        why = ", ".join(f"{len(v)} {k}" for k, v in report.dropped.items())
        dropped = f", dropped: {why}" if why else ""
        hint = "" if report.rows_read else " (no data rows)"
        raise InputError(
            f"{report.path}: {len(stream)} pose samples{hint}, this command needs at least "
            f"{min_samples} ({report.rows_read} rows read{dropped})"
        )
    return (stream, report) if with_report else stream


def save(args, stream, name: str = "output") -> None:
    """Write ``stream`` to argument ``name`` under the output policy (``--to``, ``--force``).

    A ROS 2 bag written under another name than the one given (``run.mcap`` is the bag
    directory ``run/``) is named on standard error, unless ``--quiet``.
    """
    import os

    from ..io import write_stream

    given = getattr(args, name)
    opts = {} if getattr(args, "msgtype", None) is None else {"msgtype": args.msgtype}
    written = write_stream(given, stream, format=args.to, overwrite=args.force, **opts)
    if isinstance(written, os.PathLike) and os.fspath(written) != os.fspath(given):
        if not getattr(args, "quiet", False):
            print(
                f"trackflow: wrote the ROS 2 bag directory {written}{os.sep} "
                f"(storage file {os.path.join(written, os.path.basename(given))}, "
                "metadata.yaml)",
                file=sys.stderr,
            )


def parse_horizons(text: str) -> tuple[float, ...]:
    """``"10,20,50"`` (milliseconds) -> horizons in seconds."""
    import math

    try:
        ms = [float(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise InputError(f"horizons must be comma-separated milliseconds, got {text!r}") from exc
    if not ms or any(not math.isfinite(v) or v <= 0 for v in ms):
        raise InputError(f"horizons must be positive milliseconds, got {text!r}")
    return tuple(v / 1e3 for v in ms)


def parse_ints(text: str) -> tuple[int, ...]:
    """``"1,2,3"`` -> ``(1, 2, 3)``; anything else is a ``ValueError``."""
    try:
        out = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError as exc:
        raise InputError(f"expected comma-separated integers, got {text!r}") from exc
    if not out:
        raise InputError(f"expected comma-separated integers, got {text!r}")
    return out


def add_learned_orders(p) -> None:
    """The ``--learned-orders`` option of ``tune`` and ``evaluate`` (see :func:`parse_orders`)."""
    p.add_argument(
        "--learned-orders",
        default=",".join(str(v) for v in LEARNED_ORDERS),
        help="orders of the learned increment models the tuning tries ('none': derivative "
        "models only)",
    )


def parse_orders(text: str) -> tuple[int, ...]:
    """``"3,5,10"`` -> ``(3, 5, 10)``; ``"none"`` -> ``()`` (no learned models)."""
    return () if text.strip().lower() == "none" else parse_ints(text)
