"""The optical tracker end to end on frames rendered from real recordings (docs/optical.md).

Four calibrated cameras (1280x1024, about 56 degrees field of view, OpenCV distortion) watch
three bodies with 20 markers each, two of them with nearly the same model (two markers moved
by 2 cm). The bodies move along three real hand-held recordings (``ar_table/table_0{1,2,3}``
of ``../shared/data``, detrended by 4 s so the walking stays inside the capture volume). The
frames have 0.1 px centroid jitter, read noise, a person walking through the volume, a glass
wall mirroring every marker, fixed and flickering reflections, 1 % marker dropouts, and two
full occlusions (body A hidden for 0.8 s, body B for 0.5 s).

The tracker first measures its centroid noise on the first two seconds of frames (the
residuals of the triangulated markers about the fitted bodies), then tracks the whole sequence
from scratch with it.
Written: ``docs/optical_*.png`` and the figures as JSON on stdout (``--json``).

    python experiments/optical_pipeline.py [--seconds 10] [--json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from trackflow.math import quat_conjugate, quat_log, quat_multiply
from trackflow.optical.pipeline import OpticalTracker, TrackerConfig
from trackflow.optical.scene import shared_data_dir, three_body_scene

ROOT = Path(__file__).resolve().parents[1]
DATA = shared_data_dir(ROOT)
RATE_HZ = 120.0
START_S = 5.0


def scene(seed: int = 0, hidden=()):
    """The experiment's scene: :func:`three_body_scene` with 20 markers per body."""
    rig, models, r = three_body_scene(DATA, 20, seed)
    r.settings.hidden = list(hidden)
    return rig, models, r


def pose_error(est, truth) -> np.ndarray:
    """(dt, dtheta) with t_true = t + dt, R_true = R Exp(dtheta) (docs/conventions.md)."""
    dq = quat_multiply(quat_conjugate(est.quaternion), truth.quaternion)
    return np.concatenate([truth.position - est.position, quat_log(dq)])


def run(seconds: float, sigma_px: float, hidden, seed: int = 0):
    rig, models, renderer = scene(seed=seed, hidden=hidden)
    tracker = OpticalTracker(rig, models, TrackerConfig(sigma_px=sigma_px))
    n = int(seconds * RATE_HZ)
    names = [m.name for m in models]
    rec = {k: {"t": [], "err": [], "cov": [], "mode": [], "wrong": []} for k in names}
    t_track = 0.0
    first = None
    for i in range(n):
        t = START_S + i / RATE_HZ
        frame = renderer.render(t)
        if first is None:
            first = frame
        t0 = time.perf_counter()
        res = tracker.process(t, frame.images)
        t_track += time.perf_counter() - t0
        for name in names:
            b = res.bodies[name]
            r = rec[name]
            r["t"].append(t)
            r["mode"].append(b.mode)
            if b.pose is None:
                r["err"].append(np.full(6, np.nan))
                r["cov"].append(np.full((6, 6), np.nan))
                r["wrong"].append(False)
                continue
            r["err"].append(pose_error(b.pose, frame.poses[name]))
            r["cov"].append(b.pose.covariance)
            own = np.linalg.norm(b.pose.position - frame.poses[name].position)
            other = min(
                np.linalg.norm(b.pose.position - frame.poses[o].position)
                for o in names
                if o != name
            )
            r["wrong"].append(bool(own > 0.01 or other < own))
    for r in rec.values():
        for k in ("t", "err", "cov"):
            r[k] = np.asarray(r[k])
    return tracker, rec, t_track / n, first, rig, models


def summarise(rec, hidden) -> dict:
    out = {}
    for name, r in rec.items():
        ok = np.all(np.isfinite(r["err"]), axis=1)
        e, C = r["err"][ok], r["cov"][ok]
        nees = np.einsum("ni,nij,nj->n", e, np.linalg.inv(C), e)
        N = len(nees)
        pos_rms = float(np.sqrt((e[:, :3] ** 2).sum(axis=1).mean()))
        pos_bound = float(np.sqrt(np.trace(C[:, :3, :3], axis1=1, axis2=2).mean()))
        ori_rms = float(np.sqrt((e[:, 3:] ** 2).sum(axis=1).mean()))
        ori_bound = float(np.sqrt(np.trace(C[:, 3:, 3:], axis1=1, axis2=2).mean()))
        lo, hi = chi2.ppf([0.025, 0.975], 6 * N) / N
        rec_s = []
        for body, _t0, t1 in hidden:
            if body != name:
                continue
            after = np.flatnonzero((r["t"] > t1) & ok)
            rec_s.append(float(r["t"][after[0]] - t1) if len(after) else None)
        out[name] = {
            "frames": int(len(ok)),
            "measured": int(N),
            "pos_rms_mm": pos_rms * 1e3,
            "pos_bound_mm": pos_bound * 1e3,
            "pos_ratio": pos_rms / pos_bound,
            "ori_rms_deg": float(np.degrees(ori_rms)),
            "ori_bound_deg": float(np.degrees(ori_bound)),
            "ori_ratio": ori_rms / ori_bound,
            "nees_mean": float(nees.mean()),
            "nees_band_95": [float(lo), float(hi)],
            "nees_in_band": bool(lo <= nees.mean() <= hi),
            "frac_nees_below_chi2_95": float((nees < chi2.ppf(0.95, 6)).mean()),
            "identity_swaps": int(np.sum(r["wrong"])),
            "recovery_after_occlusion_s": rec_s,
            "modes": {m: int(r["mode"].count(m)) for m in ("tracked", "found", "lost")},
        }
    return out


def pooled(rec) -> dict:
    """Mean NEES and its 95 % band over the measured poses of all bodies together."""
    nees = []
    for r in rec.values():
        ok = np.all(np.isfinite(r["err"]), axis=1)
        e, C = r["err"][ok], r["cov"][ok]
        nees.append(np.einsum("ni,nij,nj->n", e, np.linalg.inv(C), e))
    nees = np.concatenate(nees)
    N = len(nees)
    lo, hi = chi2.ppf([0.025, 0.975], 6 * N) / N
    return {"measured": N, "nees_mean": float(nees.mean()), "nees_band_95": [float(lo), float(hi)],
            "nees_in_band": bool(lo <= nees.mean() <= hi)}  # fmt: skip


def figures(rec, hidden, summary, first, rig, out_dir: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    # 1. a rendered frame: the camera seeing most blobs, whole and zoomed on one body
    cam = int(np.argmax([len(u) for u in first.blob_uv]))
    img, lab, uv = first.images[cam], first.blob_label[cam], first.blob_uv[cam]
    fig, axs = plt.subplots(1, 2, figsize=(11, 4.6), width_ratios=[1.25, 1])
    styles = ((0, "tab:red", "A"), (1, "tab:orange", "B"), (2, "tab:cyan", "C"))
    for ax in axs:
        ax.imshow(img, cmap="gray", vmin=0, vmax=120)
        for code, color, text in styles:
            sel = (lab >= 0) & (lab // 1000 == code)
            ax.scatter(
                uv[sel, 0], uv[sel, 1], s=70, facecolors="none", edgecolors=color, label=text
            )
        g = lab < 0
        ax.scatter(uv[g, 0], uv[g, 1], s=70, marker="s", facecolors="none", edgecolors="w",
                   label="ghost (mirror, reflection)")  # fmt: skip
    sel = (lab >= 0) & (lab // 1000 == np.bincount(lab[lab >= 0] // 1000).argmax())
    cx, cy = uv[sel].mean(axis=0)
    axs[1].set_xlim(cx - 45, cx + 45)
    axs[1].set_ylim(cy + 35, cy - 35)
    axs[0].set_title(f"camera {cam}, first frame ({img.shape[1]}x{img.shape[0]})")
    axs[1].set_title("zoom: marker blobs, true centres circled")
    axs[0].legend(loc="lower right", fontsize=7)
    fig.tight_layout()
    p = out_dir / "optical_frame.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    paths.append(p)
    # 2. position error of A with its 3-sigma band, and modes of all bodies
    fig, axs = plt.subplots(2, 1, figsize=(9, 6), sharex=True, height_ratios=[3, 1])
    r = rec["A"]
    sig = np.sqrt(np.stack([r["cov"][:, i, i] for i in range(3)], axis=1))
    for i, (c, n) in enumerate(zip(("tab:red", "tab:green", "tab:blue"), "xyz")):
        axs[0].plot(r["t"], r["err"][:, i] * 1e3, color=c, lw=0.7, label=f"error {n}")
        axs[0].fill_between(r["t"], -3e3 * sig[:, i], 3e3 * sig[:, i], color=c, alpha=0.12)
    axs[0].set_ylabel("position error of A [mm]")
    axs[0].legend(loc="upper right", fontsize=8, ncol=3)
    axs[0].set_title("measured pose minus truth, with the propagated 3-sigma band")
    codes = {"tracked": 2, "found": 1, "lost": 0}
    for k, name in enumerate(rec):
        m = np.array([codes[x] for x in rec[name]["mode"]])
        axs[1].scatter(rec[name]["t"], np.full(len(m), k), c=m, cmap="RdYlGn", vmin=0, vmax=2, s=2)
    for body, t0, t1 in hidden:
        k = list(rec).index(body)
        axs[1].plot([t0, t1], [k + 0.3, k + 0.3], color="k", lw=3)
    axs[1].set_yticks(range(len(rec)), list(rec))
    axs[1].set_xlabel("time [s] (green tracked, yellow found by search, red lost; bar: hidden)")
    fig.tight_layout()
    p = out_dir / "optical_errors.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)
    # 3. NEES histogram against chi-square(6)
    fig, ax = plt.subplots(figsize=(6, 4))
    allnees = []
    for r in rec.values():
        ok = np.all(np.isfinite(r["err"]), axis=1)
        e, C = r["err"][ok], r["cov"][ok]
        allnees.append(np.einsum("ni,nij,nj->n", e, np.linalg.inv(C), e))
    allnees = np.concatenate(allnees)
    x = np.linspace(0, 25, 200)
    ax.hist(allnees, bins=60, range=(0, 25), density=True, alpha=0.6, label="pose NEES, 3 bodies")
    ax.plot(x, chi2.pdf(x, 6), "k", label="chi-square, 6 dof")
    ax.set_xlabel("NEES")
    ax.set_title(f"mean NEES {allnees.mean():.2f} (6 expected)")
    ax.legend()
    fig.tight_layout()
    p = out_dir / "optical_nees.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)
    return [str(p.relative_to(ROOT)) for p in paths]


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--no-figures", action="store_true")
    args = ap.parse_args(argv)
    if not DATA.is_dir():
        raise SystemExit(f"the shared recordings are not at {DATA}")
    # 1. measure the centroid noise on the first two seconds
    cal, *_ = run(2.0, 0.12, hidden=())
    sigma = cal.pixel_sigma_estimate("poses")
    # 2. track from scratch with it, with two full occlusions
    hidden = [("A", START_S + 3.0, START_S + 3.8), ("B", START_S + 6.0, START_S + 6.5)]
    tracker, rec, s_per_frame, first, rig, models = run(args.seconds, sigma, hidden)
    summary = {
        "seconds": args.seconds,
        "sigma_px_measured": sigma,
        "sigma_px_points_level": cal.pixel_sigma_estimate("points"),
        "sigma_px_after": tracker.pixel_sigma_estimate("poses"),
        "tracker_ms_per_frame": s_per_frame * 1e3,
        "tracker_stats": tracker.stats,
        "bodies": summarise(rec, hidden),
    }
    summary["all_bodies"] = pooled(rec)
    if not args.no_figures:
        summary["figures"] = figures(rec, hidden, summary, first, rig, ROOT / "docs")
    print(json.dumps(summary, indent=1))
    return summary


if __name__ == "__main__":
    main()
