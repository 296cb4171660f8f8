"""``trackflow infer``: chain two recordings T_x_y and T_y_z into T_x_z (time-aligned)."""

from __future__ import annotations

from ..errors import InputError
from ._common import add_input, add_output, load, save
from ._progress import Progress


def register(subparsers):
    p = subparsers.add_parser(
        "infer",
        help="chain two recordings T_x_y @ T_y_z, time-aligned by pose Kalman filters",
        description="Each recording is Kalman-filtered and queried (smoothed) at the union of "
        "both recordings' timestamps; the aligned poses are composed with covariances. The "
        "first recording's target must be the second's source: name the frames with "
        "--source/--target and --source2/--target2 where the files do not.",
    )
    add_input(p, "first")
    add_input(p, "second", suffix="2")
    p.add_argument(
        "--interpolate",
        action="store_true",
        help="align by interpolating the second recording at the first's times instead",
    )
    add_output(p)
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..evaluation import infer_streams

    a = load(args, "first", min_samples=4)
    b = load(args, "second", suffix="2", min_samples=4)
    if a.target != b.source:
        raise InputError(
            f"cannot chain T_{a.source}_{a.target} ({args.first}) with T_{b.source}_{b.target} "
            f"({args.second}): the first's target must be the second's source; name the "
            "frames with --source/--target and --source2/--target2"
        )
    method = "interpolate" if args.interpolate else "filter"
    bar = Progress("inferring", 1, enabled=not args.quiet)

    def progress(done: int, total: int) -> None:
        bar.total = max(total, 1)
        bar.update(done)

    out = infer_streams(a, b, method=method, progress=progress)
    bar.close()
    save(args, out)
    return 0
