"""``trackflow filter``: run a pose Kalman filter, write filtered poses with covariances."""

from __future__ import annotations

import numpy as np

from ..evaluation import default_predictor
from ..filters import MotionModel, run_filter
from ..io import PoseStream, write_stream
from ..math import Pose, UncertainPose
from ._common import add_input, load
from .cmd_convert import add_output


def register(subparsers):
    p = subparsers.add_parser("filter", help="Kalman-filter a recording (motion model)")
    add_input(p)
    add_output(p)
    p.add_argument("--n-dp", type=int, default=2, help="position derivatives")
    p.add_argument("--n-do", type=int, default=1, help="orientation derivatives")
    p.add_argument(
        "--noise",
        default=None,
        help="comma-separated white-noise densities per level (position levels, then "
        "orientation levels); default: 30 on each highest level",
    )
    p.add_argument("--horizon", type=float, default=0.0, help="predict this many ms ahead")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    stream = load(args.file, args.format, args.clean)
    if args.noise is None:
        noise = [0.0] * args.n_dp + [30.0] + [0.0] * args.n_do + [30.0]
    else:
        noise = [float(v) for v in args.noise.split(",")]
    model = MotionModel(args.n_dp, args.n_do, noise=noise, kind="white_noise")
    times = (stream.t_ns - stream.t_ns[0]).astype(float) * 1e-9
    if stream.covariance is None:
        guess = default_predictor(times, stream.position, stream.quaternion)
        cov = np.broadcast_to(guess.measurement_covariance(), (len(times), 6, 6))
    else:
        cov = stream.covariance
    poses = UncertainPose(Pose(stream.position, stream.quaternion), np.array(cov))
    h = args.horizon / 1e3
    res = run_filter(times, poses, model, horizons=(h,))
    out = res.predictions[h] if h > 0 else res.filtered
    write_stream(args.output, PoseStream.from_poses(stream.source, stream.target, stream.t_ns,
                                                    out), format=args.to)  # fmt: skip
    return 0
