"""The trajectory processing options (evo_traj's) of ``compare`` and ``plot-traj``: one option
group, checked before any file is read, applied in one order. A command that accepts an
option applies it; none is accepted and then ignored.

Order: ``--merge`` (several files into one, by time), ``--transform-left`` /
``--transform-right``, ``--downsample``, ``--motion-filter``; then the command's association
(``compare``; ``plot-traj --sync``). ``--full-check`` reports every input as read.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass

__all__ = ["Processing", "add_processing", "check_text", "parse_processing", "process"]


def add_processing(p, *, sync: bool = False) -> None:
    """Add the processing group; ``sync`` adds ``--sync`` with its ``--t-max-diff`` and
    ``--t-offset`` (``compare`` always associates and has its own)."""
    g = p.add_argument_group(
        "trajectory processing (as evo_traj; order: merge, transforms, downsample, motion "
        "filter, then the association)"
    )
    g.add_argument(
        "--merge",
        action="store_true",
        help="the input files are one trajectory: merge them by time (compare: "
        "several EST; plot-traj: the FILES)",
    )
    g.add_argument(
        "--transform-left",
        metavar="FILE[#KEY]",
        help="left-multiply every estimated pose by this transform (T' = L T): a JSON 4x4 "
        "matrix, or {position, quaternion}; #KEY picks an entry, e.g. calib.json#Z",
    )
    g.add_argument(
        "--transform-right",
        metavar="FILE[#KEY]",
        help="right-multiply every estimated pose (T' = T R), e.g. calib.json#X",
    )
    g.add_argument(
        "--downsample",
        type=int,
        metavar="N",
        help="keep at most N poses of each input, evenly spaced",
    )
    g.add_argument(
        "--motion-filter",
        type=float,
        nargs=2,
        metavar=("DIST_M", "ANGLE_DEG"),
        help="keep a pose only when it moved DIST_M metres (path) or turned ANGLE_DEG degrees "
        "since the last kept one",
    )
    g.add_argument(
        "--full-check",
        action="store_true",
        help="check every input as read (stamps, quaternion norms, rows dropped) and print "
        "its figures (duration, path length, speeds)",
    )
    if sync:
        g.add_argument(
            "--sync", action="store_true", help="keep only the poses associated in time with --ref"
        )
        g.add_argument(
            "--t-max-diff",
            type=float,
            default=None,
            help="--sync: association tolerance [s] (default 0.01)",
        )
        g.add_argument(
            "--t-offset",
            type=float,
            default=None,
            help="--sync: added to the times of FILES, not --ref [s] (default 0)",
        )


@dataclass(frozen=True)
class Processing:
    """The processing options, checked (transforms loaded)."""

    merge: bool = False
    left: object = None  # trackflow.math.Pose
    right: object = None
    downsample: int | None = None
    motion_filter: tuple | None = None
    full_check: bool = False

    @property
    def transforms(self) -> bool:
        return self.left is not None or self.right is not None


def parse_processing(args) -> Processing:
    """Check the options before reading: transform files loaded, numbers in range."""
    from ..evaluation import load_transform
    from ..evaluation._pairs import check_motion_filter, downsample_ids

    if args.downsample is not None:
        downsample_ids(1, args.downsample)
    if args.motion_filter is not None:
        check_motion_filter(*args.motion_filter)
    tl, tr = args.transform_left, args.transform_right
    return Processing(
        merge=args.merge,
        left=None if tl is None else load_transform(tl),
        right=None if tr is None else load_transform(tr),
        downsample=args.downsample,
        motion_filter=None if args.motion_filter is None else tuple(args.motion_filter),
        full_check=args.full_check,
    )


def process(stream, proc: Processing, transform: bool = True):
    """``stream`` after the transforms (if ``transform``), downsampling and motion filter."""
    from ..evaluation import downsample_stream, motion_filter_stream, transform_stream

    if transform and proc.transforms:
        stream = transform_stream(stream, proc.left, proc.right)
    if proc.downsample is not None:
        stream = downsample_stream(stream, proc.downsample)
    if proc.motion_filter is not None:
        stream = motion_filter_stream(stream, *proc.motion_filter)
    return stream


def read_all(args, files, suffix: str = "", proc: Processing | None = None, name: str = "file"):
    """Read ``files`` with the reading options of ``args`` (``suffix``: the second input's);
    returns ``(streams, checks)`` with ``checks`` ``{file: check_stream(...)}`` under
    ``--full-check``."""
    from ..evaluation import check_stream
    from ._common import load

    streams, checks = [], {}
    for f in files:
        one = argparse.Namespace(**{**vars(args), name: f})
        s, report = load(one, name, suffix=suffix, min_samples=2, with_report=True)
        if proc is not None and proc.full_check:
            checks[f] = check_stream(s, report)
        streams.append(s)
    return streams, checks


def check_text(checks: dict) -> str:
    """``--full-check`` reports as text, one block per input."""
    out = []
    for f, c in checks.items():
        out.append(f"full check of {f}: {'valid' if c['valid'] else 'NOT VALID'}")
        out += [f"  {k}: {v}" for k, v in c["checks"].items()]
        for k, v in c.items():
            if k in ("valid", "checks"):
                continue
            if isinstance(v, dict):
                v = ", ".join(f"{a} {b:.6f}" for a, b in v.items())
            elif isinstance(v, float):
                v = f"{v:.6f}"
            elif isinstance(v, list):
                v = json.dumps([round(x, 6) for x in v])
            out.append(f"  {k}: {v}")
    return "\n".join(out)
