"""Reproduce section 3.3 of Dorfmueller-Ulhaas (seed 000) with trackflow's relative-motion EKF.

Experiments (the paper's figures 8-15):

1. ideal simulated motion: omega = (0, 0, 0.02) rad/s, a = (0, 0, 0.001) m/s^2,
   v0 = (0, 0, 0.2) m/s, dt = 20 ms, three body points (the unit axes, eq. 11);
2. the same with rectangular (uniform) perturbations of the kinematics per frame:
   omega +- 1e-3, v +- 1e-2, a +- 1e-5;
3. an abrupt change of motion at frame 10 to omega = (0.005, -0.01, -0.02),
   v = (0.2, 0.1, -0.2), a = (0.001, 0.0008, -0.001), on perturbed data (figures 12-15).

Plus one real recording (``ar_table/table_01.txt`` by default) with synthetic pose noise, to
show the filter on real motion: accuracy of filtered and 50 ms predicted poses.

Usage::

    .venv/bin/python experiments/dorfmueller_sim.py [--out out/experiments] [--json]
        [--seed 0] [--data /work/shared/data] [--recording ar_table/table_01.txt]

``--json`` prints one JSON object (``iterations_to_converge``, ``iterations_to_realign``,
``w_final`` plus details) and writes no figures.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from trackflow import Pose, UncertainPose
from trackflow.filters.relative_motion.ekf import (
    RelativeMotionEKF,
    RelativeMotionState,
    motion_matrices,
    predict,
    predict_pose,
    process_noise,
    update,
)
from trackflow.math import (
    quat_angle,
    quat_conjugate,
    quat_exp,
    quat_from_matrix,
    quat_log,
    quat_multiply,
)

DT = 0.02
SET1 = {
    "omega": np.array([0.0, 0.0, 0.02]),
    "v": np.array([0.0, 0.0, 0.2]),
    "a": np.array([0.0, 0.0, 0.001]),
}
SET2 = {
    "omega": np.array([0.005, -0.01, -0.02]),
    "v": np.array([0.2, 0.1, -0.2]),
    "a": np.array([0.001, 0.0008, -0.001]),
}
# half-widths of the rectangular perturbations of section 3.3
RANGES = np.repeat([1e-3, 1e-2, 1e-5], 3)
CHANGE_FRAME = 10
N_FRAMES = 20  # frames 0..N_FRAMES; the paper plots about 10 (fig. 9-11) and 20 (fig. 13-15)

# Filter tuning (the paper gives none). Points are exact up to 1e-9 m; the perturbations are
# white per interval and enter as "motion noise" (their uniform variance range^2 / 3); the state
# random walk per frame is the omega and v perturbation range, and 1 m/s^2 for a so that a can
# follow a change at all (a is not observable under the v perturbations anyway, see the doc).
POINT_SIGMA = 1e-9
PRIOR_SIGMA = np.repeat([1.0, 1.0, 1.0], 3)
STEP_SIGMA = np.repeat([1e-3, 1e-2, 1.0], 3)  # per frame: omega [rad/s], v [m/s], a [m/s^2]
TOLERANCE = 0.10  # converged when |x_hat - x| <= 10% of |x| (x = omega, v or a)

# synthetic pose noise added to the real recording: (label, position sigma [m], angle sigma [deg])
NOISE_LEVELS = (("1mm/0.5deg", 1e-3, 0.5), ("0.25mm/0.05deg", 2.5e-4, 0.05))

PAPER = {
    "converge": "omega converges to (0, 0, 0.02) after three iterations (ideal and noisy, fig. 9)",
    "velocity": "v stable after three iterations, v_z grows linearly (fig. 10)",
    "accel": "a stable after three iterations, more sensitive to noise (fig. 11)",
    "realign": "after the change at frame 10 the filter realigns after three to four iterations; "
    "a needs about five; stable only after frame 13 (fig. 13-14)",
    "overshoot": "predicted pose overshoots in frames 10-12 (rotation) and 9-13 (translation) "
    "(fig. 15)",
}


# -- simulation ----------------------------------------------------------------------------------
def simulate(rng: np.random.Generator | None, change: bool):
    """Poses (R, t) of frames 0..N_FRAMES and the true kinematics of each interval.

    The body starts at the identity pose. Interval k (frame k -> k+1) moves by Theorem 1 with
    the nominal (omega, v_k, a), ``v_{k+1} = v_k + a dt``, plus, if ``rng`` is given, uniform
    perturbations of the ranges above drawn afresh for every interval (so the perturbations
    accumulate in the pose, as in the paper's figure 8 (b)). With ``change`` the interval
    starting at frame CHANGE_FRAME and all later ones use SET2 (v restarting at SET2["v"]).
    """
    R, t = np.eye(3), np.zeros(3)
    Rs, ts, truth = [R], [t], []
    kin = SET1
    v = kin["v"].copy()
    for k in range(N_FRAMES):
        if change and k == CHANGE_FRAME:
            kin = SET2
            v = kin["v"].copy()
        nominal = np.concatenate([kin["omega"], v, kin["a"]])
        s = nominal + (rng.uniform(-RANGES, RANGES) if rng is not None else 0.0)
        W, V, A = motion_matrices(s[0:3], DT)
        R, t = W @ R, W @ t + V @ s[3:6] + A @ s[6:9]
        Rs.append(R)
        ts.append(t)
        truth.append(nominal)
        v = v + kin["a"] * DT
    return np.array(Rs), np.array(ts), np.array(truth)


def run_sim_filter(Rs, ts, noisy: bool, step_sigma=STEP_SIGMA, point_sigma=POINT_SIGMA):
    """Feed the simulated points to the EKF (world origin, as in the paper).

    Returns the posterior means (one per interval), the predictions ``s_{t+1|t}`` (what the
    paper's figures 9-14 show) and the one-step predicted poses (figure 15).
    """
    state = RelativeMotionState(np.zeros(9), np.diag(PRIOR_SIGMA**2))
    Q = process_noise(DT, *(np.asarray(step_sigma)[[0, 3, 6]] / np.sqrt(DT)))
    motion_noise = np.diag(RANGES**2 / 3.0) if noisy else None
    Cx = point_sigma**2 * np.eye(18)
    post_means, pred_means, pred_poses, nis = [], [], [], []
    for k in range(1, len(ts)):
        prev = np.eye(3) @ Rs[k - 1].T + ts[k - 1]
        curr = np.eye(3) @ Rs[k].T + ts[k]
        post, info = update(state, prev, curr, Cx, DT, motion_noise)
        state = predict(post, DT, Q)
        post_means.append(post.mean)
        pred_means.append(state.mean)
        nis.append(info.nis)
        pose_k = UncertainPose(Pose(ts[k], quat_from_matrix(Rs[k])), 1e-14 * np.eye(6))
        pred_poses.append(predict_pose(state, pose_k, DT, "world"))
    return np.array(post_means), np.array(pred_means), pred_poses, np.array(nis)


def iterations_within(estimates, truths, tol, first=0, last=None):
    """1-based count of updates from ``first`` until |est - truth| <= tol for all up to ``last``.

    Returns None if the estimate is not within ``tol`` at ``last``.
    """
    err = np.linalg.norm(estimates - truths, axis=-1)[first:last]
    bad = np.nonzero(err > tol)[0]
    if len(bad) == 0:
        return 1
    if bad[-1] == len(err) - 1:
        return None
    return int(bad[-1]) + 2


def sim_experiments(seed: int, step_sigma=STEP_SIGMA, point_sigma=POINT_SIGMA):
    rng = np.random.default_rng(seed)
    out = {}
    for name, noisy, change in (
        ("ideal", False, False),
        ("noisy", True, False),
        ("change_ideal", False, True),
        ("change_noisy", True, True),
    ):
        Rs, ts, truth = simulate(rng if noisy else None, change)
        post, pred, pred_poses, nis = run_sim_filter(Rs, ts, noisy, step_sigma, point_sigma)
        tol = TOLERANCE * np.linalg.norm(truth[:, 0:3], axis=-1)
        end = CHANGE_FRAME if change else None
        r = {
            "Rs": Rs,
            "ts": ts,
            "truth": truth,
            "post": post,
            "pred": pred,
            "pred_poses": pred_poses,
            "nis": nis,
            "converge_omega": iterations_within(post[:, 0:3], truth[:, 0:3], tol[0], 0, end),
            "converge_v": iterations_within(
                post[:, 3:6], truth[:, 3:6], TOLERANCE * np.linalg.norm(truth[0, 3:6]), 0, end
            ),
            "converge_a": iterations_within(
                post[:, 6:9], truth[:, 6:9], TOLERANCE * np.linalg.norm(truth[0, 6:9]), 0, end
            ),
        }
        if change:
            c = CHANGE_FRAME
            r["realign_omega"] = iterations_within(post[:, 0:3], truth[:, 0:3], tol[c], c)
            r["realign_v"] = iterations_within(
                post[:, 3:6], truth[:, 3:6], TOLERANCE * np.linalg.norm(SET2["v"]), c
            )
            r["realign_a"] = iterations_within(
                post[:, 6:9], truth[:, 6:9], TOLERANCE * np.linalg.norm(SET2["a"]), c
            )
            # one-step prediction error of the pose (figure 15)
            q_true = quat_from_matrix(Rs[2:])
            pp = pred_poses[:-1]
            r["pred_pos_err"] = np.array(
                [np.linalg.norm(p.position - t) for p, t in zip(pp, ts[2:])]
            )
            r["pred_rot_err"] = np.array(
                [float(quat_angle(p.quaternion, q)) for p, q in zip(pp, q_true)]
            )
        out[name] = r
    return out


# -- real recording ------------------------------------------------------------------------------
def read_tum(path: Path):
    """Tiny TUM reader: ``t tx ty tz qx qy qz qw`` per line, '#' comments; returns arrays."""
    rows = []
    with open(path, encoding="utf-8") as fh:
        for lineno, line in enumerate(fh, 1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            parts = s.split()
            if len(parts) < 8:
                raise ValueError(f"{path}:{lineno}: expected 8 columns, got {len(parts)}")
            try:
                rows.append([float(x) for x in parts[:8]])
            except ValueError as exc:
                raise ValueError(f"{path}:{lineno}: {exc}") from exc
    a = np.array(rows)
    q = a[:, 4:8] / np.linalg.norm(a[:, 4:8], axis=1, keepdims=True)
    return a[:, 0], a[:, 1:4], q


def real_experiment(
    path: Path, seed: int, n_max: int, horizon: float, pos_sigma, rot_sigma, start: int = 0
):
    """Filter noisy poses of a real recording; errors vs the (smoothed) recording itself.

    Uses frames ``start .. start + n_max``; noise N(pos_sigma) [m] on positions and
    N(rot_sigma) [rad] rotation vectors on the right; ``horizon`` [s] for the prediction.
    """
    t, p, q = read_tum(path)
    t, p, q = t[start : start + n_max], p[start : start + n_max], q[start : start + n_max]
    rng = np.random.default_rng(seed)
    n = len(t)
    dt = float(np.median(np.diff(t)))
    noisy_p = p + rng.normal(scale=pos_sigma, size=p.shape)
    noisy_q = quat_multiply(q, quat_exp(rng.normal(scale=rot_sigma, size=(n, 3))))
    C = np.diag([pos_sigma**2] * 3 + [rot_sigma**2] * 3)
    k_ahead = int(round(horizon / dt))
    results = {}
    for origin, steps in (
        ("world", (5.0, 5.0, 50.0)),
        ("body", (5.0, 5.0, 50.0)),
    ):
        Q = process_noise(dt, *steps)
        init = RelativeMotionState(np.zeros(9), np.diag([10.0] * 3 + [10.0] * 3 + [100.0] * 3))
        ekf = RelativeMotionEKF(init, Q, origin)
        filt_pos, filt_rot, pred_pos, pred_rot, nees = [], [], [], [], []
        hold_pos, hold_rot, meas_pos, meas_rot = [], [], [], []
        tic = time.perf_counter()
        prev_pose = None
        for k in range(n):
            pose = UncertainPose(Pose(noisy_p[k], noisy_q[k]), C)
            ekf.step(t[k], pose)
            if prev_pose is not None and k > 20:
                # filtered pose: previous measured pose moved by the posterior motion
                f = predict_pose(ekf.posterior, prev_pose, t[k] - t[k - 1], origin)
                filt_pos.append(np.linalg.norm(f.position - p[k]))
                filt_rot.append(float(quat_angle(f.quaternion, q[k])))
                meas_pos.append(np.linalg.norm(noisy_p[k] - p[k]))
                meas_rot.append(float(quat_angle(noisy_q[k], q[k])))
                j = k + k_ahead
                if j < n:
                    h = t[j] - t[k]
                    pr = ekf.predicted_pose(h)
                    pred_pos.append(np.linalg.norm(pr.position - p[j]))
                    pred_rot.append(float(quat_angle(pr.quaternion, q[j])))
                    hold_pos.append(np.linalg.norm(noisy_p[k] - p[j]))
                    hold_rot.append(float(quat_angle(noisy_q[k], q[j])))
                    nees.append(_nees(pr, p[j], q[j]))
            prev_pose = pose
        elapsed = time.perf_counter() - tic

        def rms(x):
            return float(np.sqrt(np.mean(np.square(x))))

        results[origin] = {
            "frames": n,
            "dt_s": dt,
            "meas_pos_mm": 1e3 * rms(meas_pos),
            "meas_rot_deg": np.degrees(rms(meas_rot)),
            "filt_pos_mm": 1e3 * rms(filt_pos),
            "filt_rot_deg": np.degrees(rms(filt_rot)),
            "pred_pos_mm": 1e3 * rms(pred_pos),
            "pred_rot_deg": np.degrees(rms(pred_rot)),
            "hold_pos_mm": 1e3 * rms(hold_pos),
            "hold_rot_deg": np.degrees(rms(hold_rot)),
            "pred_nees_mean": float(np.mean(nees)),
            "us_per_step": 1e6 * elapsed / n,
        }
    return results


def _nees(pred: UncertainPose, p_true, q_true) -> float:
    """NEES of a pose in trackflow's convention: e = (t_true - t, Log(R^T R_true))."""
    dtheta = quat_log(quat_multiply(quat_conjugate(pred.quaternion), q_true))
    e = np.concatenate([p_true - pred.position, dtheta])
    return float(e @ np.linalg.solve(pred.covariance, e))


# -- figures -------------------------------------------------------------------------------------
def write_figures(sim, out: Path) -> list[Path]:
    """PNGs of the quantities of the paper's figures 8-15."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    written = []
    labels = ("x", "y", "z")

    def save(fig, name):
        path = out / name
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)

    # fig. 8 and 12: trajectories of the three body points
    for fname, runs in (
        ("dorfmueller_fig08_motion.png", ("ideal", "noisy")),
        ("dorfmueller_fig12_change.png", ("change_noisy",)),
    ):
        fig = plt.figure(figsize=(5 * len(runs), 4.5))
        for j, run in enumerate(runs):
            r = sim[run]
            ax = fig.add_subplot(1, len(runs), j + 1, projection="3d")
            pts = np.einsum("kij,lj->kli", r["Rs"], np.eye(3)) + r["ts"][:, None, :]
            ax.plot(*r["ts"].T, "k.-", label="origin")
            for i, col in enumerate("rgb"):
                ax.plot(*pts[:, i].T, col + "o-", ms=3, label=f"P{i + 1}")
            ax.set_title(run)
            ax.set_xlabel("x [m]")
            ax.set_ylabel("y [m]")
            ax.set_zlabel("z [m]")
            ax.legend(fontsize=7)
        save(fig, fname)

    # fig. 9-11 (ideal vs noisy) and 13-14 (change): predicted state s_{t+1|t} vs truth
    for fname, runs, block, unit, title in (
        ("dorfmueller_fig09_omega.png", ("ideal", "noisy"), 0, "rad/s", "omega"),
        ("dorfmueller_fig10_velocity.png", ("ideal", "noisy"), 1, "m/s", "v"),
        ("dorfmueller_fig11_acceleration.png", ("ideal", "noisy"), 2, "m/s^2", "a"),
        ("dorfmueller_fig13_omega_change.png", ("change_noisy",), 0, "rad/s", "omega"),
        ("dorfmueller_fig14a_velocity_change.png", ("change_noisy",), 1, "m/s", "v"),
        ("dorfmueller_fig14b_acceleration_change.png", ("change_noisy",), 2, "m/s^2", "a"),
    ):
        fig, axes = plt.subplots(1, len(runs), figsize=(5.5 * len(runs), 3.8), squeeze=False)
        for ax, run in zip(axes[0], runs):
            r = sim[run]
            sl = slice(3 * block, 3 * block + 3)
            frames = np.arange(1, len(r["post"]) + 1)
            truth_next = np.vstack([r["truth"][1:], r["truth"][-1:]])  # s at the next interval
            for i, col in enumerate("rgb"):
                ax.plot(
                    frames, r["pred"][:, sl][:, i], col + "o-", ms=3, label=f"{title}_{labels[i]}"
                )
                ax.plot(frames, truth_next[:, sl][:, i], col + ":", lw=1)
            ax.set_xlabel("frame (update)")
            ax.set_ylabel(f"predicted {title} [{unit}]")
            ax.set_title(f"{run}: prediction (dotted: true)")
            if block == 2 and run != "ideal":
                ax.set_ylim(-3, 3)
            ax.legend(fontsize=7)
        save(fig, fname)

    # fig. 15: one-step predicted global rotation and translation vs truth (change run)
    r = sim["change_noisy"]
    pp = r["pred_poses"][:-1]
    frames = np.arange(2, len(r["ts"]))
    rv_pred = np.array([quat_log(p.quaternion) for p in pp])
    rv_true = quat_log(quat_from_matrix(r["Rs"][2:]))
    t_pred = np.array([p.position for p in pp])
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    for i, col in enumerate("rgb"):
        axes[0].plot(frames, rv_pred[:, i], col + "o-", ms=3, label=f"pred r_{labels[i]}")
        axes[0].plot(frames, rv_true[:, i], col + ":", lw=1)
        axes[1].plot(frames, t_pred[:, i], col + "o-", ms=3, label=f"pred t_{labels[i]}")
        axes[1].plot(frames, r["ts"][2:, i], col + ":", lw=1)
    axes[0].set_ylabel("rotation vector [rad]")
    axes[1].set_ylabel("translation [m]")
    for ax in axes:
        ax.set_xlabel("frame")
        ax.legend(fontsize=7)
        ax.axvline(CHANGE_FRAME, color="k", lw=0.5)
    axes[0].set_title("(a) predicted global rotation (dotted: true)")
    axes[1].set_title("(b) predicted global translation (dotted: true)")
    save(fig, "dorfmueller_fig15_predicted_pose.png")
    return written


# -- main ----------------------------------------------------------------------------------------
def summary(sim) -> dict:
    ideal, noisy, ch = sim["ideal"], sim["noisy"], sim["change_noisy"]
    a_err = np.linalg.norm(noisy["post"][3:, 6:9] - noisy["truth"][3:, 6:9], axis=-1)
    return {
        "iterations_to_converge": ideal["converge_omega"],
        "iterations_to_realign": ch["realign_omega"],
        "w_final": [float(x) for x in ideal["pred"][CHANGE_FRAME - 1, 0:3]],
        "tolerance_fraction": TOLERANCE,
        "converge": {
            run: {q: sim[run][f"converge_{q}"] for q in ("omega", "v", "a")}
            for run in ("ideal", "noisy")
        },
        "realign": {
            run: {q: sim[run][f"realign_{q}"] for q in ("omega", "v", "a")}
            for run in ("change_ideal", "change_noisy")
        },
        "w_final_noisy": [float(x) for x in noisy["pred"][CHANGE_FRAME - 1, 0:3]],
        "w_final_after_change": [float(x) for x in ch["pred"][-1, 0:3]],
        "noisy_a_error_rms": float(np.sqrt(np.mean(a_err**2))),
        "change_pred_pos_err_mm": [round(1e3 * float(x), 3) for x in ch["pred_pos_err"]],
        "change_pred_rot_err_mrad": [round(1e3 * float(x), 4) for x in ch["pred_rot_err"]],
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out/experiments"), help="PNG folder")
    ap.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data"
    )
    ap.add_argument("--recording", default="ar_table/table_01.txt")
    ap.add_argument("--frames", type=int, default=2000, help="frames of the recording to use")
    ap.add_argument("--no-real", action="store_true", help="skip the real recording")
    args = ap.parse_args(argv)

    sim = sim_experiments(args.seed)
    s = summary(sim)
    real = {}
    rec = args.data / args.recording
    if not args.no_real and rec.is_file():
        for label, ps, rs in NOISE_LEVELS:
            real[label] = real_experiment(rec, args.seed, args.frames, 0.05, ps, np.radians(rs))
        s["real"] = {"recording": args.recording, "frames": args.frames, **real}
    if args.json:
        print(json.dumps(s))
        return 0

    print(f"Dorfmueller-Ulhaas relative-motion EKF, section 3.3 (seed {args.seed})")
    print(f"tolerance: |x_hat - x| <= {TOLERANCE:.0%} of |x|; counts are updates (iterations)\n")
    rows = [
        ("omega converges (ideal)", PAPER["converge"], s["converge"]["ideal"]["omega"]),
        ("omega converges (noisy)", PAPER["converge"], s["converge"]["noisy"]["omega"]),
        (
            "v converges (ideal / noisy)",
            PAPER["velocity"],
            f"{s['converge']['ideal']['v']} / {s['converge']['noisy']['v']}",
        ),
        (
            "a converges (ideal / noisy)",
            PAPER["accel"],
            f"{s['converge']['ideal']['a']} / {s['converge']['noisy']['a']} "
            f"(noisy a error rms {s['noisy_a_error_rms']:.3f} m/s^2)",
        ),
        (
            "realign omega, v, a (noisy)",
            PAPER["realign"],
            "{omega}, {v}, {a}".format(**s["realign"]["change_noisy"]),
        ),
        (
            "realign omega, v, a (ideal)",
            PAPER["realign"],
            "{omega}, {v}, {a}".format(**s["realign"]["change_ideal"]),
        ),
        (
            "1-step predicted pose error",
            PAPER["overshoot"],
            "pos mm "
            + " ".join(f"{x:.2f}" for x in s["change_pred_pos_err_mm"][7:14])
            + f" (frames {CHANGE_FRAME - 1}..{CHANGE_FRAME + 5})",
        ),
    ]
    w = max(len(r[0]) for r in rows)
    for name, paper, ours in rows:
        print(f"{name:<{w}}  paper: {paper}\n{'':<{w}}  ours:  {ours}")
    print(f"\nomega after 9 updates (ideal): {np.round(s['w_final'], 6).tolist()}")
    print(f"omega after 9 updates (noisy): {np.round(s['w_final_noisy'], 6).tolist()}")
    if real:
        print(
            f"\nreal recording {args.recording}: first {args.frames} frames + Gaussian pose "
            "noise; RMS errors vs the recording; 50 ms prediction vs holding the last pose"
        )
        print(
            f"{'noise':<14} {'origin':<6} {'meas mm':>8} {'filt mm':>8} {'pred50 mm':>10} "
            f"{'hold50 mm':>10} {'meas deg':>9} {'filt deg':>9} {'pred50 deg':>11} "
            f"{'hold50 deg':>11} {'NEES(6)':>8} {'us/step':>8}"
        )
        for label, res in real.items():
            for origin, r in res.items():
                print(
                    f"{label:<14} {origin:<6} {r['meas_pos_mm']:8.2f} {r['filt_pos_mm']:8.2f} "
                    f"{r['pred_pos_mm']:10.2f} {r['hold_pos_mm']:10.2f} "
                    f"{r['meas_rot_deg']:9.3f} {r['filt_rot_deg']:9.3f} "
                    f"{r['pred_rot_deg']:11.3f} {r['hold_rot_deg']:11.3f} "
                    f"{r['pred_nees_mean']:8.2f} {r['us_per_step']:8.0f}"
                )
    for p in write_figures(sim, args.out):
        print(f"wrote {p}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
