"""``trackflow evaluate``: prediction-error tables (thesis 9.2.1, tables 9.2-9.5)."""

from __future__ import annotations

import json
import sys

from ..errors import InputError
from ._common import (
    add_input,
    add_learned_orders,
    load,
    parse_horizons,
    parse_orders,
)
from ._progress import FinishingStream


def register(subparsers):
    p = subparsers.add_parser(
        "evaluate",
        help="prediction error of the tuned Kalman filter vs linear extrapolation and none",
        description="Tune on the first part of a recording, then score predictions "
        "h ahead of every later sample against the interpolated recording.",
    )
    add_input(p)
    p.add_argument("--horizons", default="10,20,50,100,200", help="milliseconds, comma-separated")
    p.add_argument(
        "--tune-fraction",
        type=float,
        default=0.5,
        help="fraction of the duration to tune on (0 = no tuning, default model); "
        "the rest is scored",
    )
    p.add_argument("--tune-horizons", default="50,100", help="horizons the tuning cost uses (ms)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    add_learned_orders(p)
    add_imu_options(p)
    p.set_defaults(func=run)
    return p


def add_imu_options(p) -> None:
    """``--imu``, ``--pose-rate``, ``--origins``, ``--imu-mode`` (``docs/inertial.md``)."""
    p.add_argument(
        "--imu",
        default=None,
        help="IMU recording on the same body (EuRoC IMU csv or BROAD .mat; a BROAD .mat "
        "carries both: pass it twice): adds the IMU-aided predictor kalman_imu",
    )
    p.add_argument("--pose-rate", type=float, default=None, help="thin the poses to this rate [Hz]")
    p.add_argument(
        "--origins",
        choices=("poses", "anytime"),
        default="poses",
        help="with --imu: predict right after each tracker pose, or at every sample time of "
        "the recording from the data up to then (an application asking at any time)",
    )
    p.add_argument(
        "--imu-mode", choices=("strapdown", "gyro"), default="strapdown", help="IMU filter variant"
    )


def describe_model(d: dict) -> str:
    """One line naming the chosen filter: family, derivative counts or learned order."""
    fam = d.get("family") or d.get("kind")
    if fam == "partwise":
        return (
            f"position: {describe_model(d['position'])}; "
            f"orientation: {describe_model(d['orientation'])}"
        )
    if fam in ("twist_ar",) or d.get("kind") == "twist_ar":
        return f"learned increment model of order {d.get('order')}"
    return (
        f"derivative model ({d.get('n_dp')} position, {d.get('n_do')} orientation "
        f"derivatives, {d.get('kind')} noise)"
    )


def run(args) -> int:
    from ..evaluation import Trajectory, evaluate_recording

    stream = load(args, min_samples=10)
    recording = Trajectory.from_stream(stream)
    progress = None if args.quiet else FinishingStream(sys.stderr)
    if args.imu is not None or args.pose_rate is not None:
        report = evaluate_imu_file(stream, recording, args, progress)
    else:
        report = evaluate_recording(
            recording,
            horizons=parse_horizons(args.horizons),
            tune_fraction=args.tune_fraction,
            tune_horizons=parse_horizons(args.tune_horizons),
            ar_orders=parse_orders(args.learned_orders),
            progress=progress,
        )
    if args.json:
        print(json.dumps(report.as_dict(), indent=2))
    else:
        print(f"kalman = {describe_model(report.predictor.as_dict())}")
        print(report.table())
    return 0


def evaluate_imu_file(stream, recording, args, progress):
    """``--imu``: read the IMU and score with and without it (times from the poses' origin)."""
    from ..evaluation import ImuSamples, evaluate_with_imu
    from ..io import read_imu

    if args.imu is None:
        raise InputError("--pose-rate needs --imu (the pose-only evaluation uses every sample)")
    imu, _ = read_imu(args.imu, clean=args.clean)
    t = (imu.t_ns - int(stream.t_ns[0])).astype(float) * 1e-9
    return evaluate_with_imu(
        recording,
        ImuSamples.check(t, imu.gyro, imu.accel),
        pose_rate_hz=args.pose_rate,
        horizons=parse_horizons(args.horizons),
        tune_fraction=args.tune_fraction,
        tune_horizons=parse_horizons(args.tune_horizons),
        origins=args.origins,
        mode=args.imu_mode,
        ar_orders=parse_orders(args.learned_orders),
        progress=progress,
    )
