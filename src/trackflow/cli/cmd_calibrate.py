"""``trackflow calibrate``: clock offset, hand-eye, alignment, sensor noise and pivot calibration.

Each action is a thin layer over one function of :mod:`trackflow.calibration`; results print
as text or ``--json``, and ``--fragment OUT.yaml`` writes a setup fragment (``include:`` it
from a setup), ``--report DIR`` a JSON report with residual plots.
"""

from __future__ import annotations

import contextlib
import json
from pathlib import Path

from ..errors import ConfigError, InputError
from ._common import add_input, load


def register(subparsers):
    p = subparsers.add_parser(
        "calibrate",
        help="calibrate with uncertainty: clock offset, hand-eye, align, noise, pivot",
        description="Calibration from recordings, each result with its covariance.",
    )
    sub = p.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    _register_clock(sub)
    _register_hand_eye(sub)
    _register_align(sub)
    _register_noise(sub)
    _register_pivot(sub)
    return p


def _add_pair(p, a="a", b="b"):
    add_input(p, a)
    add_input(p, b, suffix="2")
    p.add_argument("--max-offset", type=float, default=1.0, help="offset search range, seconds")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--fragment", type=Path, help="write a setup fragment (YAML) here")
    p.add_argument("--report", type=Path, help="write report.json and residual plots here")
    p.add_argument("--sensor-name", default="sensor", help="sensor name used in the fragment")
    p.add_argument("--force", action="store_true", help="replace an existing fragment or report")


def _print(d: dict, as_json: bool) -> None:
    if as_json:
        print(json.dumps(d, indent=2))
        return
    for k, v in d.items():
        if k == "covariance":
            continue  # in --json and the fragment; too long for the text summary
        if isinstance(v, dict):
            v = ", ".join(f"{kk}={vv}" for kk, vv in v.items() if kk != "covariance")
        print(f"{k:<20} {v}")


def _emit(args, result: dict, note: str, write_report, statics=(), sensors=()) -> int:
    """The tail of every ``calibrate`` subcommand: the setup fragment (``--fragment``: static
    edges and sensor updates), the report directory (``--report``: ``write_report(dir)``), then
    the result as text or ``--json``."""
    from ..calibration.fragment import write_fragment

    if args.fragment:
        write_fragment(
            args.fragment, statics=statics, sensors=sensors, note=note, overwrite=args.force
        )
    if args.report:
        with _report_dir(args) as d:
            write_report(d)
    _print(result, args.json)
    return 0


def _residual_report(directory, data, residuals, inliers, title, times=None) -> None:
    """``report.json`` and ``residuals.png`` for residuals (M, 3) or (M, 6) [m, rad]."""
    import numpy as np

    from ..calibration.report import plot_residuals, write_json

    write_json(directory, data)
    r = np.asarray(residuals, float)
    if r.shape[1] == 3:
        r = np.concatenate([r, np.zeros_like(r)], axis=1)
    ok = np.ones(len(r), bool) if inliers is None else np.asarray(inliers)
    t = np.arange(len(r), dtype=float) if times is None else np.asarray(times)
    xlabel = "sample" if times is None else "time [s]"
    plot_residuals(Path(directory) / "residuals.png", t, r, ok, title, xlabel)


# -- clock-offset ---------------------------------------------------------------------------


def _register_clock(sub):
    p = sub.add_parser(
        "clock-offset",
        help="offset (and drift) of B's clock to A's, with standard error",
        description="t_A = t_B + offset_s. Cross-correlates angular speed (or speed), then "
        "refines jointly with the rotation between the two bodies.",
    )
    _add_pair(p)
    p.add_argument("--drift", action="store_true", help="also estimate a linear clock drift")
    p.add_argument("--signal", choices=("auto", "angular", "linear"), default="auto")
    p.set_defaults(func=run_clock)


def run_clock(args) -> int:
    from ..calibration import estimate_clock_offset
    from ..calibration.fragment import sensor_update
    from ..calibration.report import write_clock_report

    a, b = load(args, "a"), load(args, "b", suffix="2")
    r = estimate_clock_offset(
        a, b, max_offset_s=args.max_offset, drift=args.drift, signal=args.signal
    )
    return _emit(
        args, r.as_dict(), f"clock offset of {args.b} to {args.a}",
        lambda d: write_clock_report(d, r),
        sensors=[sensor_update(args.sensor_name, r.offset_s)],
    )  # fmt: skip


# -- hand-eye -------------------------------------------------------------------------------


def _register_hand_eye(sub):
    p = sub.add_parser(
        "hand-eye",
        help="A X = X B / A X = Z B with covariance and the clock offset",
        description="ROBOT is T_base_tool, SENSOR is T_world_body of a body rigidly attached "
        "to the tool: X = T_tool_body, Z = T_base_world, t_robot = t_sensor + offset_s. The "
        "robot-world form is used when the two streams have different base frames: X and the "
        "offset from short motion pairs (a drifting sensor world does not bias them), then Z "
        "from the absolute poses; robot-world-joint fits all on absolute poses.",
    )
    _add_pair(p, "robot", "sensor")
    p.add_argument(
        "--form", choices=("auto", "robot-world", "robot-world-joint", "hand-eye"), default="auto"
    )
    p.add_argument("--offset", type=float, default=None, help="known clock offset, seconds")
    p.add_argument(
        "--fixed-offset", action="store_true", help="do not refine the offset (needs --offset)"
    )
    p.add_argument("--drift", action="store_true", help="also estimate a linear clock drift")
    p.add_argument(
        "--use",
        type=Path,
        help="evaluate a stored calibration (a --json output) on these recordings; "
        "nothing is re-estimated unless --refit",
    )
    p.add_argument(
        "--refit",
        metavar="PART",
        help="with --use: keep X (and its covariance) from the file and refit PART on these "
        "recordings; 'world' refits Z and the clock offset (a tracker whose world frame is "
        "re-created each session). Prints a full calibration (--json, --fragment, --report)",
    )
    p.add_argument("--min-pair-angle", type=float, default=5.0, help="degrees (motion pairs)")
    p.add_argument("--max-pair-span", type=float, default=2.0, help="seconds (motion pairs)")
    p.set_defaults(func=run_hand_eye)


def load_calibration(path: Path) -> dict:
    """Read a ``calibrate hand-eye --json`` file; ``ValueError`` naming the file if malformed.

    Returns ``{"X": UncertainPose, "Z": UncertainPose or None, "offset_s": float}`` (a missing
    covariance reads as zeros)."""
    from ..calibration.hand_eye import pose_from_json

    try:
        d = json.loads(Path(path).read_text())
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path}: not JSON: {exc}") from exc
    if not isinstance(d, dict) or "X" not in d or "offset_s" not in d:
        raise ConfigError(f"{path}: expected the keys of 'calibrate hand-eye --json' (X, offset_s)")
    X = pose_from_json(d["X"], f"{path}: X")
    Z = None if d.get("Z") is None else pose_from_json(d["Z"], f"{path}: Z")
    return {"X": X, "Z": Z, "offset_s": float(d["offset_s"])}


def run_hand_eye(args) -> int:
    from ..calibration import evaluate_hand_eye, solve_hand_eye
    from ..calibration.reuse import check_refit, refit_calibration

    if args.refit is not None:
        if not args.use:
            raise InputError("--refit needs --use CALIB.json (the calibration whose X is kept)")
        check_refit(args.refit)
        if args.drift or args.form != "auto":
            raise InputError(
                "--refit world keeps X and fits Z and a constant offset: --form and --drift "
                "do not apply"
            )
    if args.fixed_offset and args.offset is None:
        raise InputError("--fixed-offset needs --offset")
    robot, sensor = load(args, "robot"), load(args, "sensor", suffix="2")
    if args.use:
        c = load_calibration(args.use)
        if args.refit is not None:
            r = refit_calibration(
                robot, sensor, c["X"], refit=args.refit, offset_s=args.offset,
                estimate_offset=not args.fixed_offset, max_offset_s=args.max_offset,
                min_pair_angle_deg=args.min_pair_angle, max_pair_span_s=args.max_pair_span,
            )  # fmt: skip
            return _emit_hand_eye(args, r, robot, sensor, f"{args.use} refitted to")
        offset = c["offset_s"] if args.offset is None else args.offset
        X, Z = c["X"].pose, None if c["Z"] is None else c["Z"].pose
        out = evaluate_hand_eye(
            robot, sensor, X, Z, offset,
            min_pair_angle_deg=args.min_pair_angle, max_pair_span_s=args.max_pair_span,
        )  # fmt: skip
        out["offset_s"] = offset
        _print(out, args.json)
        return 0
    r = solve_hand_eye(
        robot,
        sensor,
        form=args.form,
        offset_s=args.offset,
        estimate_offset=not args.fixed_offset,
        estimate_drift=args.drift,
        max_offset_s=args.max_offset,
        min_pair_angle_deg=args.min_pair_angle,
        max_pair_span_s=args.max_pair_span,
    )
    return _emit_hand_eye(args, r, robot, sensor, "hand-eye calibration from")


def _emit_hand_eye(args, r, robot, sensor, what: str) -> int:
    """``_emit`` of a :class:`HandEyeResult`: X and Z as static edges, the offset as the
    sensor's update, the report with the residual plot."""
    from ..calibration.fragment import sensor_update, static_edge
    from ..calibration.report import write_hand_eye_report

    statics = [static_edge("hand_eye_X", robot.target, sensor.target, r.X)]
    if r.Z is not None:
        statics.append(static_edge("hand_eye_Z", robot.source, sensor.source, r.Z))
    return _emit(
        args, r.to_json(), f"{what} {args.robot} and {args.sensor}",
        lambda d: write_hand_eye_report(d, r), statics=statics,
        sensors=[sensor_update(args.sensor_name, r.offset_s)],
    )  # fmt: skip


# -- align ----------------------------------------------------------------------------------


def _register_align(sub):
    p = sub.add_parser(
        "align",
        help="align trajectory B to A (Umeyama + refinement) with covariance and offset",
        description="p_A(t) = s R p_B(t - offset) + t for positions of the same point; "
        "prints T_A_B with covariance, scale, offset and the RMSE after alignment.",
    )
    _add_pair(p)
    p.add_argument("--scale", action="store_true", help="also estimate a scale")
    p.add_argument("--offset", type=float, default=None, help="known clock offset, seconds")
    p.add_argument("--fixed-offset", action="store_true", help="do not refine the offset")
    p.set_defaults(func=run_align)


def run_align(args) -> int:
    from ..calibration import align_trajectories
    from ..calibration.fragment import sensor_update, static_edge

    a, b = load(args, "a"), load(args, "b", suffix="2")
    r = align_trajectories(
        a, b, with_scale=args.scale, offset_s=args.offset,
        estimate_offset=not args.fixed_offset, max_offset_s=args.max_offset,
    )  # fmt: skip
    title = f"alignment: {r.residual_rmse_mm:.2f} mm RMSE"
    return _emit(
        args, r.as_dict(), f"alignment of {args.b} to {args.a}",
        lambda d: _residual_report(d, r.as_dict(), r.residuals, r.inliers, title, r.times_s),
        statics=[static_edge("alignment", a.source, b.source, r.T)],
        sensors=[sensor_update(args.sensor_name, r.offset_s)],
    )  # fmt: skip


# -- noise ----------------------------------------------------------------------------------


def _register_noise(sub):
    p = sub.add_parser(
        "noise",
        help="per-axis measurement noise covariance from static segments or moving data",
    )
    add_input(p)
    p.add_argument("--method", choices=("static", "dynamic", "innovation"), default="static")
    p.add_argument("--max-speed", type=float, default=5.0, help="static: mm/s")
    p.add_argument("--max-rate", type=float, default=1.0, help="static: deg/s")
    p.add_argument("--min-segment", type=float, default=1.0, help="static: seconds")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--fragment", type=Path, help="write the sensor's covariance as a fragment")
    p.add_argument("--sensor-name", default="sensor", help="sensor name used in the fragment")
    p.add_argument("--report", type=Path, help="write report.json and an error plot here")
    p.add_argument("--force", action="store_true", help="replace an existing fragment or report")
    p.set_defaults(func=run_noise)


def run_noise(args) -> int:
    from ..calibration import sensor_noise
    from ..calibration.fragment import sensor_update

    r = sensor_noise(
        load(args), args.method,
        max_speed=args.max_speed * 1e-3, max_rate_deg=args.max_rate,
        min_segment_s=args.min_segment,
    )  # fmt: skip
    title = f"{args.method} noise samples"
    return _emit(
        args, r.as_dict(), f"{args.method} noise of {args.file}",
        lambda d: _residual_report(d, r.as_dict(), r.errors, None, title),
        sensors=[sensor_update(args.sensor_name, covariance=r.covariance)],
    )  # fmt: skip


# -- pivot ----------------------------------------------------------------------------------


def _register_pivot(sub):
    p = sub.add_parser("pivot", help="tip offset of a pointer tool pivoted about its tip")
    add_input(p)
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--fragment", type=Path, help="write the tip as a static edge (fragment)")
    p.add_argument("--tip-frame", default="tip", help="frame name of the tip in the fragment")
    p.add_argument("--report", type=Path, help="write report.json and a residual plot here")
    p.add_argument("--force", action="store_true", help="replace an existing fragment or report")
    p.set_defaults(func=run_pivot)


def run_pivot(args) -> int:
    import numpy as np

    from ..calibration import pivot_calibration
    from ..calibration.fragment import static_edge
    from ..math import Pose, UncertainPose

    stream = load(args)
    r = pivot_calibration(stream)
    cov = np.zeros((6, 6))
    cov[:3, :3] = r.covariance[:3, :3]
    tip = UncertainPose(Pose(r.tip, [0.0, 0.0, 0.0, 1.0]), cov)
    title = f"pivot: {r.residual_rms_mm:.2f} mm RMS"
    return _emit(
        args, r.as_dict(), f"pivot calibration of {args.file}",
        lambda d: _residual_report(d, r.as_dict(), r.residuals, r.inliers, title),
        statics=[static_edge("tip", stream.target, args.tip_frame, tip)],
    )  # fmt: skip


@contextlib.contextmanager
def _report_dir(args):
    """The report directory, written whole or not at all (the one output policy)."""
    from ..io import atomic_output

    with atomic_output(args.report, overwrite=args.force, directory=True) as tmp:
        tmp.mkdir()
        yield tmp
