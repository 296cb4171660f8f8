"""Thesis chapter 9 on real two-tracker recordings: simultaneity and static relationships.

Pustka evaluates measurement simultaneity (figs. 9.14-9.16: two trackers combined with a
constant time offset, corrected by prediction, corrected by smoothing) and the estimation of a
static relationship (fig. 9.17) on two real trackers. This script does both on

* ``quest_ur5e/quest2``: a Quest 2 headset carried by a UR5e robot; calibrated (hand-eye,
  clock offset) on the ``calib`` run and applied to ``traj1`` (also as a user reuses it:
  ``--use --refit world``, :func:`reuse_figures`);
* ``quest_ur5e/optitrack_unity_example``: the headset seen by OptiTrack and by itself.

Writes PNGs to ``docs/calibration/`` and prints the figures quoted in ``docs/calibration.md``
as JSON. Usage: ``python experiments/calibration_chapter9.py [--out DIR]``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

from trackflow.calibration import (
    estimate_clock_offset,
    evaluate_hand_eye,
    evaluate_with_world_fit,
    hand_eye_residuals,
    refit_calibration,
    solve_hand_eye,
)
from trackflow.calibration.hand_eye import FORMS
from trackflow.calibration.report import plot_residuals
from trackflow.evaluation import (
    Trajectory,
    default_predictor,
    predict_kalman,
    predict_linear,
    tune_model,
)
from trackflow.io import PoseStream, read_stream

ROOT = Path(__file__).resolve().parents[1]


def data_dir() -> Path:
    env = os.environ.get("TRACKFLOW_DATA")
    for c in ([Path(env)] if env else []) + [ROOT.parent / "shared" / "data"]:
        if (c / "README.md").is_file():
            return c
    return Path("/work/shared/data")


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def unity_to_right_handed(s: PoseStream, source: str, target: str) -> PoseStream:
    """Mirror a pose stream logged in Unity's left-handed frames in z (docs/formats.md)."""
    return s.with_(
        source=source,
        target=target,
        position=np.asarray(s.position) * np.array([1.0, 1.0, -1.0]),
        quaternion=np.asarray(s.quaternion) * np.array([-1.0, -1.0, 1.0, 1.0]),
    )


def _seconds(s: PoseStream, epoch: int) -> np.ndarray:
    return (np.asarray(s.t_ns, np.int64) - epoch) * 1e-9


def _interp(t, p, q, tq):
    """Linear/slerp interpolation of (p, q) at tq via the calibration's trajectory sampler."""
    from trackflow.calibration._sampling import make_trajectory

    tr = make_trajectory(t, p, q)
    smp = tr.sample(tq)
    return smp.p, smp.q, smp.valid


def tuned_predictor(stream: PoseStream, horizon: float):
    """The Kalman filter tuned (derivative models) for ``horizon`` on a recording."""
    t = _seconds(stream, int(stream.t_ns[0]))
    from trackflow.math import quat_make_continuous

    q = quat_make_continuous(np.asarray(stream.quaternion, float))
    recording = Trajectory.check(t, np.asarray(stream.position, float), q)
    res = tune_model(recording, horizons=(horizon, horizon + 0.03), ar_orders=())
    return res.predictor


def simultaneity(robot, quest, X, offset, Z, predictor=None):
    """Errors of combining the two trackers at the sensor's samples (thesis 9.14-9.16).

    For each headset sample j (stamp s_j, robot-clock time tau_j = s_j + offset) the robot pose
    at tau_j is (a) taken at s_j, ignoring the offset; (b) predicted from the robot samples up to
    s_j to tau_j (Kalman filter, and linear extrapolation for comparison); (c) interpolated at
    tau_j (smoothing, non-causal). Error: A X against Z B.
    """
    epoch = int(min(robot.t_ns[0], quest.t_ns[0]))
    ta, tb = _seconds(robot, epoch), _seconds(quest, epoch)
    pa, qa = np.asarray(robot.position, float), np.asarray(robot.quaternion, float)
    from trackflow.math import quat_make_continuous

    qa = quat_make_continuous(qa)
    pb, qb = np.asarray(quest.position, float), np.asarray(quest.quaternion, float)
    tau = tb + offset
    keep = (tb > ta[0] + 1.0) & (tau < ta[-1] - 1.0)
    tb, tau, pb, qb = tb[keep], tau[keep], pb[keep], qb[keep]
    k = np.searchsorted(ta, tb, side="right") - 1  # latest robot sample at the stamp
    lead = tau - ta[k]
    # samples whose latest robot sample lies before a gap are left out of every method
    period = float(np.median(np.diff(ta)))
    ok = lead <= offset + 2.0 * period
    keep_idx = np.flatnonzero(ok)
    tb, tau, pb, qb, k, lead = (v[keep_idx] for v in (tb, tau, pb, qb, k, lead))
    Xt = (X.position, X.quaternion)
    Zt = (np.asarray(Z["position"]), np.asarray(Z["quaternion"]))

    def err(p, q):
        r = hand_eye_residuals(p, q, pb, qb, Xt, Zt)
        return np.linalg.norm(r[:, :3], axis=1) * 1e3, np.degrees(np.linalg.norm(r[:, 3:], axis=1))

    out = {}
    p, q, _ = _interp(ta, pa, qa, tb)
    out["uncorrected"] = err(p, q)
    hs = np.round(np.arange(lead.min() - 0.002, lead.max() + 0.002, 0.001), 4)
    pred = predictor if predictor is not None else default_predictor(ta, pa, qa)
    pk, qk, _ = predict_kalman(Trajectory.check(ta, pa, qa, gap_s=3.0 * period), pred, hs)
    h_idx = np.clip(np.round((lead - hs[0]) / 0.001).astype(int), 0, len(hs) - 1)
    out["prediction (Kalman)"] = err(pk[h_idx, k], qk[h_idx, k])
    pl = np.empty((len(k), 3))
    ql = np.empty((len(k), 4))
    for h in np.unique(h_idx):
        m = h_idx == h
        pp, qq = predict_linear(ta, pa, qa, hs[h])
        pl[m], ql[m] = pp[k[m]], qq[k[m]]
    out["prediction (linear)"] = err(pl, ql)
    p, q, _ = _interp(ta, pa, qa, tau)
    out["smoothing"] = err(p, q)
    return tb - tb[0], out


def plot_simultaneity(path, t, errs, title):
    plt = _pyplot()
    names = ["uncorrected", "prediction (Kalman)", "smoothing"]
    fig, ax = plt.subplots(len(names), 1, figsize=(8, 6.5), sharex=True, sharey=True)
    top = np.percentile(errs["uncorrected"][0], 99)
    for a, n in zip(ax, names):
        dp = errs[n][0]
        a.plot(t, dp, lw=0.6)
        a.set_title(f"{n}: RMS {np.sqrt(np.mean(dp**2)):.1f} mm", fontsize=9)
        a.set_ylabel("mm")
        a.set_ylim(0, 1.05 * top)
        a.grid(alpha=0.3)
    ax[-1].set_xlabel("time in traj1 [s]")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def static_convergence(robot, quest, lengths, form):
    """X estimated from the first L seconds of the calibration run, for each L."""
    rows = []
    for L in lengths:
        t0 = int(max(robot.t_ns[0], quest.t_ns[0]))
        r = robot[robot.t_ns < t0 + int(L * 1e9)]
        q = quest[quest.t_ns < t0 + int(L * 1e9)]
        try:
            res = solve_hand_eye(r, q, form=form)
        except ValueError as exc:
            rows.append({"length_s": L, "error": str(exc)})
            continue
        sig = np.sqrt(np.diag(res.X.covariance))
        rows.append({
            "length_s": L,
            "X_mm": (res.X.position * 1e3).tolist(),
            "X_sigma_mm": (sig[:3] * 1e3).tolist(),
            "offset_s": res.offset_s,
            "offset_sigma_s": res.offset_sigma_s,
        })  # fmt: skip
    return rows


def plot_convergence(path, rows, reference_mm, title):
    plt = _pyplot()
    ok = [r for r in rows if "X_mm" in r]
    L = np.array([r["length_s"] for r in ok])
    X = np.array([r["X_mm"] for r in ok])
    S = np.array([r["X_sigma_mm"] for r in ok])
    fig, ax = plt.subplots(1, 3, figsize=(10, 3.2))
    for i, a in enumerate(ax):
        a.errorbar(L, X[:, i], yerr=2 * S[:, i], fmt="o-", capsize=3, label="estimate +- 2 sigma")
        if reference_mm is not None:
            a.axhline(reference_mm[i], color="C3", ls="--", label="independent run")
        a.set_xscale("log")
        a.set_xlabel("calibration data [s]")
        a.set_title(f"X {'xyz'[i]} [mm]", fontsize=9)
        a.grid(alpha=0.3)
    ax[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_bars(path, scores: dict, title):
    plt = _pyplot()
    names = list(scores)
    fig, ax = plt.subplots(figsize=(8, 3.2))
    colors = ["C0" if n.startswith("trackflow") else "0.6" for n in names]
    ax.bar(range(len(names)), [scores[n] for n in names], color=colors)
    ax.set_xticks(range(len(names)), names, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("traj1 RMS position residual [mm]")
    lo = min(scores.values())
    ax.set_ylim(0.9 * lo, 1.05 * max(scores.values()))
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_rate_window(path, scan: dict, poses: dict):
    """Rate-based offset against the rates' half window, with the pose-based offsets."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 3.2))
    for (name, row), c in zip(scan.items(), ("C0", "C1")):
        hw = [float(k) * 1e3 for k in row]
        ax.plot(hw, list(row.values()), "o-", color=c, label=f"{name}: angular rates")
        ax.axhline(poses[name], color=c, ls="--", lw=1, label=f"{name}: poses (hand-eye)")
    ax.set_xscale("log")
    ax.set_xlabel("half window of the rates' central differences [ms]")
    ax.set_ylabel("offset [ms]")
    ax.set_title("Quest 2 / UR5e: clock offset from rates vs from poses")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def reuse_figures(robot1, quest1, calib) -> dict:
    """``calibrate hand-eye --use calib.json --refit world`` on traj1 (X from ``calib``, Z and
    the offset refitted) against traj1's own default calibration and the stored world, each in
    the same measures: a solve's (``A X = Z B`` over the solvers' inliers, motion pairs) and
    every sample and pair without rejection (:func:`evaluate_hand_eye`)."""
    own = solve_hand_eye(robot1, quest1)
    reused = refit_calibration(robot1, quest1, calib.X)
    keys = ("offset_s", "offset_sigma_s", "residual_pos_mm", "residual_ori_deg",
            "pair_residual_pos_mm", "pair_residual_ori_deg", "n_used", "n_outliers", "n_pairs",
            "n_pair_outliers")  # fmt: skip
    out = {}
    for name, r in (("own", own), ("reused", reused)):
        out[name] = {k: getattr(r, k) for k in keys} | {
            "Z_mm": (r.Z.position * 1e3).tolist(),
            "Z_sd_mm": (np.sqrt(np.diag(r.Z.covariance))[:3] * 1e3).tolist(),
            "Z_sd_deg": np.degrees(np.sqrt(np.diag(r.Z.covariance))[3:]).tolist(),
            "all_blocks": evaluate_hand_eye(robot1, quest1, r.X.pose, r.Z.pose, r.offset_s),
        }
    out["stored"] = evaluate_hand_eye(robot1, quest1, calib.X.pose, calib.Z.pose, calib.offset_s)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "calibration")
    args = ap.parse_args(argv)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    D = data_dir() / "quest_ur5e"
    summary: dict = {}

    # --- Quest 2 / UR5e: calibrate on calib --------------------------------------------------
    robot, _ = read_stream(D / "quest2" / "robot_tcp_calib.tum.txt")
    quest, _ = read_stream(D / "quest2" / "calib.txt", clean=True)
    robot1, _ = read_stream(D / "quest2" / "robot_tcp_traj1.tum.txt")
    quest1, _ = read_stream(D / "quest2" / "traj1.txt", clean=True)
    from trackflow.calibration.report import write_clock_report, write_hand_eye_report

    clock = estimate_clock_offset(robot, quest, drift=True)
    write_clock_report(out / "quest_clock", clock)
    clock1 = estimate_clock_offset(robot1, quest1)
    res = {f: solve_hand_eye(robot, quest, form=f) for f in FORMS}
    summary["quest_default_form"] = solve_hand_eye(robot, quest).form
    # the rate-based offset against the half window of the rates' central differences
    summary["quest_rate_offset_vs_half_window_ms"] = {
        name: {f"{hw:.3f}": estimate_clock_offset(r, q, rate_half_window_s=hw).offset_s * 1e3
               for hw in (1 / 30, 0.05, 0.1, 0.2, 0.4)}
        for name, r, q in (("calib", robot, quest), ("traj1", robot1, quest1))
    }  # fmt: skip
    for f, r in res.items():
        write_hand_eye_report(out / f"quest_{f}", r)  # report.json + residuals.png
    summary["quest_clock_calib"] = {k: v for k, v in clock.as_dict().items()
                                    if k in ("offset_s", "offset_sigma_s", "drift",
                                             "drift_sigma", "peak_correlation")}  # fmt: skip
    summary["quest_clock_traj1"] = {"offset_s": clock1.offset_s, "offset_sigma_s": clock1.sigma_s}
    summary["quest_calib"] = {f: r.to_json() | {"n_outliers": r.n_outliers, "n_used": r.n_used,
                                                "X_sd_mm": (np.sqrt(np.diag(r.X.covariance))[:3]
                                                            * 1e3).tolist()}
                              for f, r in res.items()}  # fmt: skip
    for f in summary["quest_calib"]:
        for k in ("X", "Z"):
            if summary["quest_calib"][f][k] is not None:
                summary["quest_calib"][f][k].pop("covariance")
    he = res["hand-eye"]
    for f in FORMS:
        rd = solve_hand_eye(robot, quest, form=f, estimate_drift=True)
        summary[f"quest_calib_{f}_with_drift"] = {
            "offset_s": rd.offset_s, "offset_sigma_s": rd.offset_sigma_s, "drift": rd.drift,
            "drift_sigma": rd.drift_sigma, "X_mm": (rd.X.position * 1e3).tolist(),
            "residual_pos_mm": rd.residual_pos_mm,
        }  # fmt: skip
    # --- apply to traj1: X and offset from calib, the headset's world refitted --------------
    transfer = {f: evaluate_with_world_fit(robot1, quest1, r.X.pose, r.offset_s)
                for f, r in res.items()}  # fmt: skip
    summary["quest_traj1_transfer"] = {f: {k: v for k, v in d.items() if k != "Z"}
                                       for f, d in transfer.items()}  # fmt: skip
    own = solve_hand_eye(robot1, quest1, form="hand-eye")
    summary["quest_traj1_own_X_mm"] = (own.X.position * 1e3).tolist()
    summary["quest_traj1_own_X_sigma_mm"] = (np.sqrt(np.diag(own.X.covariance))[:3] * 1e3).tolist()
    summary["quest_traj1_own_offset_s"] = own.offset_s
    summary["quest_traj1_reuse"] = reuse_figures(robot1, quest1, res["robot-world"])
    plot_rate_window(out / "quest_rate_window.png", summary["quest_rate_offset_vs_half_window_ms"],
                     {"calib": res["hand-eye"].offset_s * 1e3,
                      "traj1": own.offset_s * 1e3})  # fmt: skip
    # --- figs 9.14-9.16 on traj1 -----------------------------------------------------------
    pred = tuned_predictor(robot, he.offset_s)  # tuned on the calibration run's robot
    t, errs = simultaneity(robot1, quest1, he.X, he.offset_s, transfer["hand-eye"]["Z"], pred)
    plot_simultaneity(out / "quest_simultaneity.png", t, errs,
                      f"Quest 2 + UR5e, traj1: clock offset {he.offset_s * 1e3:.0f} ms "
                      "(calibrated on calib)")  # fmt: skip
    summary["quest_simultaneity_rms"] = {
        n: {"pos_mm": float(np.sqrt(np.mean(e[0] ** 2))),
            "ori_deg": float(np.sqrt(np.mean(e[1] ** 2)))} for n, e in errs.items()
    }  # fmt: skip
    # --- fig 9.17: the static relationship from growing amounts of data ---------------------
    rows = static_convergence(robot, quest, (15, 30, 60, 120, 240), "hand-eye")
    plot_convergence(out / "quest_static_X.png", rows, own.X.position * 1e3,
                     "Quest 2 on UR5e: X = T_tool_headset from the first L s of calib")  # fmt: skip
    summary["quest_static_X"] = rows
    # --- OpenCV on the same stations and offset ---------------------------------------------
    sys.path.insert(0, str(ROOT / "bench"))
    try:
        from _opencv_hand_eye import opencv_solutions, stations

        off1 = clock1.offset_s
        scores = {f"trackflow {f}": evaluate_with_world_fit(robot1, quest1, r.X.pose, off1)[
            "residual_pos_mm"] for f, r in res.items()}  # fmt: skip
        for spacing in (0.5, 1.0, 2.0):
            for m, (X, _) in opencv_solutions(
                *stations(robot, quest, he.offset_s, spacing)
            ).items():
                s = evaluate_with_world_fit(robot1, quest1, X, off1)["residual_pos_mm"]
                scores[f"opencv {m}"] = min(scores.get(f"opencv {m}", np.inf), s)
        plot_bars(out / "quest_opencv.png", scores,
                  "calibrated on calib, scored on traj1 (X fixed, world refitted)")  # fmt: skip
        summary["quest_opencv_traj1_mm"] = scores
    except ImportError as exc:  # OpenCV is a dev/bench extra
        summary["quest_opencv_traj1_mm"] = f"skipped: {exc}"

    # --- OptiTrack vs the Quest's own tracking ----------------------------------------------
    opti, _ = read_stream(D / "optitrack_unity_example" / "opti.csv")
    unity, _ = read_stream(D / "optitrack_unity_example" / "unity.csv")
    opti = opti.with_(source="optitrack", target="rigid_body")
    unity = unity_to_right_handed(unity, "quest_world", "quest_headset")
    ou = {f: solve_hand_eye(opti, unity, form=f) for f in FORMS}
    for f, r in ou.items():
        plot_residuals(out / f"opti_unity_{f}_residuals.png", r.times_s, r.residuals,
                       r.inliers, f"OptiTrack vs Quest, {f}: {r.residual_pos_mm:.2f} mm, "
                       f"{r.residual_ori_deg:.3f} deg RMS")  # fmt: skip
    summary["opti_unity"] = {f: r.to_json() | {"n_outliers": r.n_outliers, "n_used": r.n_used}
                             for f, r in ou.items()}  # fmt: skip
    for f in summary["opti_unity"]:
        for k in ("X", "Z"):
            if summary["opti_unity"][f][k] is not None:
                summary["opti_unity"][f][k].pop("covariance")
    co = estimate_clock_offset(opti, unity)
    summary["opti_unity_clock"] = {"offset_s": co.offset_s, "offset_sigma_s": co.sigma_s}
    rw = ou["robot-world"]
    t2, errs2 = simultaneity(opti, unity, rw.X, rw.offset_s,
                             {"position": rw.Z.position, "quaternion": rw.Z.quaternion},
                             tuned_predictor(opti, max(rw.offset_s, 0.01)))  # fmt: skip
    plot_simultaneity(out / "opti_unity_simultaneity.png", t2, errs2,
                      f"OptiTrack + Quest: offset {rw.offset_s * 1e3:.1f} ms")  # fmt: skip
    summary["opti_unity_simultaneity_rms"] = {
        n: {"pos_mm": float(np.sqrt(np.mean(e[0] ** 2))),
            "ori_deg": float(np.sqrt(np.mean(e[1] ** 2)))} for n, e in errs2.items()
    }  # fmt: skip
    rows2 = static_convergence(opti, unity, (2, 4, 8, 13), "robot-world")
    plot_convergence(out / "opti_unity_static_X.png", rows2, None,
                     "OptiTrack rigid body to Quest headset, from the first L s")  # fmt: skip
    summary["opti_unity_static_X"] = rows2
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=float))
    print(json.dumps(summary, indent=2, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
