"""Trajectory comparison: absolute and relative pose error (APE, RPE) of an estimate vs a reference.

The definitions follow the common practice of trajectory evaluation tools (Sturm et al.,
"A benchmark for the evaluation of RGB-D SLAM systems", IROS 2012), so figures agree with such
tools given the same association and alignment:

* **Association** (:func:`associate`): for every sample of the recording with fewer samples,
  the sample of the other recording nearest in time (after adding ``t_offset`` to the
  estimate's times), if within ``t_max_diff``. Times are compared as float64 seconds.
* **Alignment** (:func:`trackflow.math.umeyama`): ``"se3"`` a rigid motion, ``"sim3"`` a
  similarity, fitted by least squares to the associated positions (Umeyama 1991);
  ``"origin"`` maps the first estimated pose onto the first reference pose; ``"none"``. The
  alignment ``T_ref_est`` is applied to every estimated pose: ``P'_i = S P_i`` (position
  scaled by ``s`` for Sim(3)).
* **APE**: ``E_i = Q_i^-1 P'_i`` for reference poses ``Q_i`` (``T_world_body``); translation
  error ``|t(E_i)| = |t(P'_i) - t(Q_i)|`` [m], rotation error ``angle(E_i)`` [deg]. Per-axis
  errors are ``t(P'_i) - t(Q_i)`` in the reference's world frame.
* **RPE** over ``delta`` samples: ``E_i = (Q_i^-1 Q_{i+d})^-1 (P'_i^-1 P'_{i+d})`` for
  ``i = 0, d, 2d, ...``; translation ``|t(E_i)|`` [m] and rotation ``angle(E_i)`` [deg].
* **Statistics** (:class:`Stats`): RMSE, mean, median, standard deviation (population), min,
  max and the sum of squares.
* **Uncertainty**: when the estimate carries covariances, the APE position errors are also
  weighed by them: NEES ``e^T C^-1 e`` with ``C`` the position block rotated by the alignment
  (and scaled by ``s^2``), and the fraction inside its 95 % chi-square(3) bound.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..io import PoseStream
from ..math import quat_from_matrix, quat_to_matrix, umeyama

__all__ = ["ALIGNMENTS", "CompareResult", "Stats", "associate", "compare_trajectories"]

#: Names accepted by ``align=``.
ALIGNMENTS = ("none", "se3", "sim3", "origin")


@dataclass(frozen=True)
class Stats:
    """Summary statistics of a set of non-negative errors (or signed, for per-axis errors)."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float
    n: int

    @classmethod
    def of(cls, e) -> Stats:
        e = np.asarray(e, dtype=float).reshape(-1)
        if not e.size:
            nan = float("nan")
            return cls(nan, nan, nan, nan, nan, nan, 0.0, 0)
        return cls(
            float(np.sqrt(np.mean(e * e))), float(np.mean(e)), float(np.median(e)),
            float(np.std(e)), float(np.min(e)), float(np.max(e)), float(np.dot(e, e)), e.size,
        )  # fmt: skip

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def associate(
    t_ref: np.ndarray, t_est: np.ndarray, t_max_diff: float = 0.01, t_offset: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(i_ref, i_est)`` of associated samples (see the module docstring).

    Parameters
    ----------
    t_ref, t_est : ndarray, shape (N,), (M,)
        Increasing times [s] (float64).
    t_max_diff : float
        Largest accepted time difference [s].
    t_offset : float
        Added to the estimate's times before matching [s].
    """
    if not (np.isfinite(t_max_diff) and t_max_diff >= 0):
        raise InputError(f"t_max_diff must be >= 0 s, got {t_max_diff}")
    if not np.isfinite(t_offset):
        raise InputError(f"t_offset must be finite, got {t_offset}")
    est_longer = len(t_est) > len(t_ref)
    short, long_ = (t_ref, t_est) if est_longer else (t_est, t_ref)
    long_ = long_ + (t_offset if est_longer else -t_offset)
    if not len(long_) or not len(short):
        return np.zeros(0, int), np.zeros(0, int)
    j = np.clip(np.searchsorted(long_, short, side="right"), 0, len(long_) - 1)
    up = long_[j] - short
    lo = np.where(j > 0, short - long_[np.maximum(j - 1, 0)], np.inf)
    inside = (short >= long_[0] - t_max_diff) & (short <= long_[-1] + t_max_diff)
    take_up = (up <= t_max_diff) & (up < lo)
    take_lo = ~take_up & (lo <= t_max_diff) & (lo <= up)
    ok = inside & (take_up | take_lo)
    i_short = np.flatnonzero(ok)
    i_long = np.where(take_up, j, j - 1)[ok]
    return (i_short, i_long) if est_longer else (i_long, i_short)


def _matrices(stream: PoseStream, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return quat_to_matrix(np.asarray(stream.quaternion)[idx]), np.asarray(stream.position)[idx]


def _angle_deg(r: np.ndarray) -> np.ndarray:
    """Rotation angles of matrices (..., 3, 3) in degrees (robust near 0 and 180)."""
    q = quat_from_matrix(r)
    return np.degrees(2.0 * np.arctan2(np.linalg.norm(q[..., :3], axis=-1), np.abs(q[..., 3])))


@dataclass
class CompareResult:
    """APE/RPE of an estimate against a reference (see the module docstring).

    Attributes
    ----------
    t : ndarray (K,)
        Reference times of the associated pairs, seconds since the first reference sample.
    ape_trans, ape_rot_deg : ndarray (K,)
        APE translation [m] and rotation [deg] per pair.
    ape_axes : ndarray (K, 3)
        ``t(P') - t(Q)`` per pair, world axes of the reference [m].
    rpe_t : ndarray (J,)
        Reference times of the first pose of each RPE pair [s].
    rpe_trans, rpe_rot_deg : ndarray (J,)
    ref_xyz, est_xyz : ndarray (K, 3)
        Associated reference and aligned estimated positions [m].
    alignment : dict
        ``{"method", "rotation" (3x3), "translation" (3,), "scale"}``.
    nees : ndarray (K,) or None
        Position NEES per pair when the estimate has covariances.
    """

    t: np.ndarray
    ape_trans: np.ndarray
    ape_rot_deg: np.ndarray
    ape_axes: np.ndarray
    rpe_t: np.ndarray
    rpe_trans: np.ndarray
    rpe_rot_deg: np.ndarray
    ref_xyz: np.ndarray
    est_xyz: np.ndarray
    alignment: dict
    n_ref: int
    n_est: int
    delta: int
    nees: np.ndarray | None = None
    settings: dict = field(default_factory=dict)

    def stats(self) -> dict:
        """``{"ape_trans_m", "ape_rot_deg", "rpe_trans_m", "rpe_rot_deg", "ape_x_m", ...}``."""
        out = {
            "ape_trans_m": Stats.of(self.ape_trans).as_dict(),
            "ape_rot_deg": Stats.of(self.ape_rot_deg).as_dict(),
            "rpe_trans_m": Stats.of(self.rpe_trans).as_dict(),
            "rpe_rot_deg": Stats.of(self.rpe_rot_deg).as_dict(),
        }
        for k, axis in enumerate("xyz"):
            out[f"ape_{axis}_m"] = Stats.of(self.ape_axes[:, k]).as_dict()
        if self.nees is not None:
            from scipy.stats import chi2

            out["ape_position_nees"] = {
                "mean": float(np.mean(self.nees)),
                "expected": 3.0,
                "inside_95_percent": float(np.mean(self.nees <= chi2.ppf(0.95, 3))),
            }
        return out

    def as_dict(self, arrays: bool = False) -> dict:
        """Plain data (JSON serialisable); with ``arrays`` every per-pair error too."""
        a = self.alignment
        out = {
            "pairs": int(len(self.t)),
            "reference_samples": self.n_ref,
            "estimate_samples": self.n_est,
            "settings": dict(self.settings),
            "alignment": {
                "method": a["method"],
                "rotation": np.asarray(a["rotation"]).tolist(),
                "translation": np.asarray(a["translation"]).tolist(),
                "scale": a["scale"],
            },  # fmt: skip
            "stats": self.stats(),
        }
        if arrays:
            out["arrays"] = {
                "t_s": self.t.tolist(),
                "ape_trans_m": self.ape_trans.tolist(),
                "ape_rot_deg": self.ape_rot_deg.tolist(),
                "ape_xyz_m": self.ape_axes.tolist(),
                "rpe_t_s": self.rpe_t.tolist(),
                "rpe_trans_m": self.rpe_trans.tolist(),
                "rpe_rot_deg": self.rpe_rot_deg.tolist(),
                "ref_xyz_m": self.ref_xyz.tolist(),
                "est_xyz_m": self.est_xyz.tolist(),
            }
            if self.nees is not None:
                out["arrays"]["ape_position_nees"] = self.nees.tolist()
        return out

    def table(self) -> str:
        """Human-readable summary: one row per metric."""
        rows = [
            f"{len(self.t)} associated pairs ({self.n_ref} reference, {self.n_est} estimate "
            f"samples); alignment {self.alignment['method']}"
            + (
                f", scale {self.alignment['scale']:.6g}"
                if self.alignment["method"] == "sim3"
                else ""
            ),  # fmt: skip
            f"{'metric':<18}{'rmse':>11}{'mean':>11}{'median':>11}{'std':>11}{'min':>11}"
            f"{'max':>11}",
        ]
        for name, st in self.stats().items():
            if "nees" in name:
                rows.append(
                    f"position NEES: mean {st['mean']:.3g} (3 if consistent), "
                    f"{100 * st['inside_95_percent']:.1f} % inside the 95 % bound"
                )
                continue
            rows.append(
                f"{name:<18}" + "".join(f"{st[k]:11.6f}" for k in
                                       ("rmse", "mean", "median", "std", "min", "max"))
            )  # fmt: skip
        return "\n".join(rows)


def compare_trajectories(
    ref: PoseStream,
    est: PoseStream,
    *,
    t_max_diff: float = 0.01,
    t_offset: float = 0.0,
    align: str = "none",
    delta: int = 1,
) -> CompareResult:
    """APE and RPE of ``est`` against ``ref`` (both ``T_world_body``; module docstring).

    Parameters
    ----------
    ref, est : PoseStream
    t_max_diff : float
        Association tolerance [s].
    t_offset : float
        Added to the estimate's times for the association [s].
    align : {"none", "se3", "sim3", "origin"}
    delta : int
        RPE step in associated pairs (``>= 1``).

    Raises
    ------
    ValueError
        No associated pairs, fewer than 3 for an alignment, or bad settings.
    """
    if align not in ALIGNMENTS:
        raise InputError(f"align must be one of {ALIGNMENTS}, got {align!r}")
    if int(delta) != delta or delta < 1:
        raise InputError(f"delta must be an integer >= 1, got {delta}")
    tr = np.asarray(ref.t_ns) * 1e-9
    te = np.asarray(est.t_ns) * 1e-9
    ir, ie = associate(tr, te, t_max_diff, t_offset)
    if not len(ir):
        raise InputError(
            f"no associated poses: reference {tr[0]:.9g}..{tr[-1]:.9g} s, estimate "
            f"{te[0]:.9g}..{te[-1]:.9g} s (+ offset {t_offset:g} s) with --t-max-diff "
            f"{t_max_diff:g} s"
        )
    if delta >= len(ir):
        raise InputError(
            f"delta {delta} needs more than {delta} associated poses; there are {len(ir)}"
        )
    rq, pq = _matrices(ref, ir)
    re_, pe = _matrices(est, ie)
    rot, trans, scale = np.eye(3), np.zeros(3), 1.0
    if align in ("se3", "sim3"):
        fit = umeyama(pq, pe, with_scale=align == "sim3")  # T_ref_est
        rot, trans, scale = fit.rotation, fit.translation, fit.scale
    elif align == "origin":
        rot = rq[0] @ re_[0].T
        trans = pq[0] - rot @ pe[0]
    re_ = rot @ re_
    pe = scale * pe @ rot.T + trans
    ape_axes = pe - pq
    e_rot = np.einsum("nji,njk->nik", rq, re_)
    k = np.arange(0, len(ir) - delta, delta)
    rel_q_r = np.einsum("nji,njk->nik", rq[k], rq[k + delta])
    rel_q_t = np.einsum("nji,nj->ni", rq[k], pq[k + delta] - pq[k])
    rel_p_r = np.einsum("nji,njk->nik", re_[k], re_[k + delta])
    rel_p_t = np.einsum("nji,nj->ni", re_[k], pe[k + delta] - pe[k])
    nees = None
    if est.covariance is not None:
        c = scale**2 * rot @ np.asarray(est.covariance)[ie][:, :3, :3] @ rot.T
        nees = np.einsum("ni,ni->n", ape_axes, np.linalg.solve(c, ape_axes[..., None])[..., 0])
    t0 = tr[0]
    return CompareResult(
        t=tr[ir] - t0,
        ape_trans=np.linalg.norm(ape_axes, axis=1),
        ape_rot_deg=_angle_deg(e_rot),
        ape_axes=ape_axes,
        rpe_t=tr[ir][k] - t0,
        rpe_trans=np.linalg.norm(rel_p_t - rel_q_t, axis=1),
        rpe_rot_deg=_angle_deg(np.einsum("nji,njk->nik", rel_q_r, rel_p_r)),
        ref_xyz=pq,
        est_xyz=pe,
        alignment={"method": align, "rotation": rot, "translation": trans, "scale": scale},
        n_ref=len(ref),
        n_est=len(est),
        delta=int(delta),
        nees=nees,
        settings={"t_max_diff_s": t_max_diff, "t_offset_s": t_offset, "delta": int(delta)},
    )
