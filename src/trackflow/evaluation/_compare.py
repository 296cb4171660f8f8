"""Trajectory comparison: absolute and relative pose error (APE, RPE) of an estimate vs a reference.

The definitions follow the common practice of trajectory evaluation tools (Sturm et al.,
"A benchmark for the evaluation of RGB-D SLAM systems", IROS 2012) and evo's choices, so
figures agree with evo given the same association, alignment, pose relation and pairs
(``docs/cli.md``, "trackflow compare"):

* **Association** (:func:`associate`): for every sample of the recording with fewer samples,
  the sample of the other recording nearest in time (after adding ``t_offset`` to the
  estimate's times), if within ``t_max_diff``. Times are compared as float64 seconds.
* **Alignment** (:func:`trackflow.math.umeyama`, fitted to the associated positions, or to the
  first ``n_to_align`` of them): ``"se3"`` a rigid motion, ``"sim3"`` a similarity,
  ``"scale"`` the similarity's scale alone (positions scaled about the world origin, no
  rotation or translation); ``"origin"`` maps the first estimated pose onto the first
  reference pose; ``"none"``. The alignment ``T_ref_est`` is applied to every estimated pose:
  ``P'_i = S P_i`` (position scaled by ``s``).
* **APE**: the error pose between ``P'_i`` and the reference pose ``Q_i`` (``T_world_body``):
  translation ``t(P'_i) - t(Q_i)`` (also per world axis), rotation ``R(Q_i)^T R(P'_i)``.
* **RPE** over the pairs ``(i, j)`` of :func:`trackflow.evaluation._pairs.rpe_pairs`:
  ``E = (Q_i^-1 Q_j)^-1 (P'_i^-1 P'_j)``.
* Each error pose gives one number per **pose relation** (``trans_part`` [m], ``angle_deg``
  ...; :mod:`trackflow.evaluation._pairs`), summarised by :class:`Stats`.
* **Uncertainty**: when the estimate carries covariances, the APE position errors are also
  weighed by them: NEES ``e^T C^-1 e`` with ``C`` the position block rotated by the alignment
  (and scaled by ``s^2``), and the fraction inside its 95 % chi-square(3) bound.

Memory: the per-pair work runs in blocks of ``BLOCK`` pairs; what is kept for the whole
comparison is the association's indices, the associated positions (reference and aligned
estimate) and one float64 array per metric.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..errors import InputError
from ..io import PoseStream
from ..math import (
    quat_between,
    quat_conjugate,
    quat_from_matrix,
    quat_multiply,
    quat_rotate,
    quat_to_matrix,
    umeyama,
)
from ._compare_result import CompareResult, ErrorSeries
from ._pairs import (
    APE_RELATIONS,
    DELTA_UNITS,
    POSE_RELATIONS,
    check_delta,
    metric_name,
    relation_errors,
    rpe_pairs,
)

__all__ = ["ALIGNMENTS", "CompareSettings", "associate", "compare_trajectories"]

#: Names accepted by ``align=``.
ALIGNMENTS = ("none", "se3", "sim3", "scale", "origin")
#: The relations reported when none are asked for: translation [m] and angle [deg].
DEFAULT_RELATIONS = ("trans_part", "angle_deg")
#: Pairs per block of the per-pair work (bounds the temporaries: about 1 KB per pair).
BLOCK = 1 << 16


@dataclass(frozen=True)
class CompareSettings:
    """Every setting of a comparison, checked once (:func:`compare_trajectories`).

    Attributes
    ----------
    t_max_diff : float
        Association tolerance [s], ``>= 0``.
    t_offset : float
        Added to the estimate's times for the association [s].
    align : {"none", "se3", "sim3", "scale", "origin"}
    n_to_align : int or None
        Fit the alignment to the first ``n`` associated pairs only (``>= 3``; se3, sim3 and
        scale only); ``None``: all.
    delta : float
        RPE step, in ``delta_unit``: frames (an integer >= 1), metres travelled, degrees
        (``<= 180``) or radians (``<= pi``).
    delta_unit : {"f", "m", "d", "r"}
    delta_tol : float
        All pairs by path or angle: accepted relative deviation from ``delta`` (``>= 0``).
    all_pairs : bool
        RPE from every pose instead of consecutive segments.
    pairs_from_reference : bool
        Choose the RPE pairs on the reference instead of the (aligned) estimate.
    pose_relations : tuple of str
        The relations to report (``POSE_RELATIONS``), each for APE and RPE
        (``point_distance_error_ratio``: RPE only).
    """

    t_max_diff: float = 0.01
    t_offset: float = 0.0
    align: str = "none"
    n_to_align: int | None = None
    delta: float = 1
    delta_unit: str = "f"
    delta_tol: float = 0.1
    all_pairs: bool = False
    pairs_from_reference: bool = False
    pose_relations: tuple = DEFAULT_RELATIONS

    def __post_init__(self):
        if not (np.isfinite(self.t_max_diff) and self.t_max_diff >= 0):
            raise InputError(f"t_max_diff must be >= 0 s, got {self.t_max_diff}")
        if not np.isfinite(self.t_offset):
            raise InputError(f"t_offset must be finite, got {self.t_offset}")
        if self.align not in ALIGNMENTS:
            raise InputError(f"align must be one of {ALIGNMENTS}, got {self.align!r}")
        if self.n_to_align is not None:
            n = self.n_to_align
            if isinstance(n, bool) or int(n) != n or n < 3:
                raise InputError(f"n_to_align must be an integer >= 3 (pairs), got {n}")
            if self.align not in ("se3", "sim3", "scale"):
                raise InputError(
                    f"n_to_align needs align 'se3', 'sim3' or 'scale' (a fit); align is "
                    f"{self.align!r}"
                )
            object.__setattr__(self, "n_to_align", int(n))
        if self.delta_unit not in DELTA_UNITS:
            raise InputError(f"delta unit must be one of {DELTA_UNITS}, got {self.delta_unit!r}")
        object.__setattr__(self, "delta", check_delta(self.delta, self.delta_unit))
        if not (np.isfinite(self.delta_tol) and self.delta_tol >= 0):
            raise InputError(f"delta_tol must be >= 0, got {self.delta_tol}")
        rel = self.pose_relations
        rel = (rel,) if isinstance(rel, str) else tuple(rel)
        bad = [r for r in rel if r not in POSE_RELATIONS]
        if bad or not rel or len(set(rel)) != len(rel):
            raise InputError(
                f"pose relations must be distinct names of {POSE_RELATIONS}, got {list(rel)}"
            )
        object.__setattr__(self, "pose_relations", rel)

    def as_dict(self) -> dict:
        """Plain data, with the units in the names of the times."""
        d = asdict(self)
        d["t_max_diff_s"] = d.pop("t_max_diff")
        d["t_offset_s"] = d.pop("t_offset")
        d["pose_relations"] = list(self.pose_relations)
        return d


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


def _blocks(n: int):
    return (slice(i, min(i + BLOCK, n)) for i in range(0, n, BLOCK))


def _alignment(cfg: CompareSettings, ref: PoseStream, est: PoseStream, ir, ie, pq, pe) -> dict:
    """``{"method", "rotation", "translation", "scale", "n_aligned"}`` mapping the estimate's
    world onto the reference's (module docstring)."""
    rot, trans, scale, n = np.eye(3), np.zeros(3), 1.0, None
    if cfg.align in ("se3", "sim3", "scale"):
        n = len(pq) if cfg.n_to_align is None else cfg.n_to_align
        if n > len(pq):
            raise InputError(
                f"n_to_align {n} exceeds the {len(pq)} associated pairs; give at most {len(pq)}"
            )
        if len(pq) < 3:
            raise InputError(f"an alignment needs at least 3 associated pairs, got {len(pq)}")
        fit = umeyama(pq[:n], pe[:n], with_scale=cfg.align != "se3")  # T_ref_est
        scale = float(fit.scale)
        if cfg.align != "scale":
            rot, trans = fit.rotation, fit.translation
    elif cfg.align == "origin":
        rot = quat_to_matrix(ref.quaternion[ir[0]]) @ quat_to_matrix(est.quaternion[ie[0]]).T
        trans = pq[0] - rot @ pe[0]
    return {"method": cfg.align, "rotation": rot, "translation": trans, "scale": scale,
            "n_aligned": n}  # fmt: skip


def _series(kind: str, relations, t: np.ndarray, errors: dict) -> dict:
    out = {}
    for rel in relations:
        if rel not in errors:
            continue
        name, unit = metric_name(kind, rel)
        tt, e = errors[rel] if isinstance(errors[rel], tuple) else (t, errors[rel])
        out[name] = ErrorSeries(name, kind, rel, unit, tt, e)
    return out


def compare_trajectories(
    ref: PoseStream, est: PoseStream, *, labels=("reference", "estimate"), **settings
) -> CompareResult:
    """APE and RPE of ``est`` against ``ref`` (both ``T_world_body``; module docstring).

    Parameters
    ----------
    ref, est : PoseStream
        Reference and estimate, positions [m], quaternions ``(x, y, z, w)``.
    labels : tuple of two str
        Their names in tables, plots and saved results.
    **settings
        The fields of :class:`CompareSettings` (``t_max_diff``, ``t_offset``, ``align``,
        ``n_to_align``, ``delta``, ``delta_unit``, ``delta_tol``, ``all_pairs``,
        ``pairs_from_reference``, ``pose_relations``), or ``settings=CompareSettings(...)``.

    Returns
    -------
    CompareResult

    Raises
    ------
    InputError
        No associated pairs, fewer than 3 for an alignment, an RPE step that gives no pair, or
        bad settings.
    """
    cfg = settings.pop("settings", None)
    if cfg is None:
        try:
            cfg = CompareSettings(**settings)
        except TypeError as exc:
            raise InputError(f"compare_trajectories: {exc}") from None
    elif settings:
        raise InputError(f"pass settings= or keywords, not both: {sorted(settings)}")
    tr = np.asarray(ref.t_ns) * 1e-9
    te = np.asarray(est.t_ns) * 1e-9
    ir, ie = associate(tr, te, cfg.t_max_diff, cfg.t_offset)
    if not len(ir):
        raise InputError(
            f"no associated poses: reference {tr[0]:.9g}..{tr[-1]:.9g} s, estimate "
            f"{te[0]:.9g}..{te[-1]:.9g} s (+ offset {cfg.t_offset:g} s) with --t-max-diff "
            f"{cfg.t_max_diff:g} s"
        )
    del te
    t_pairs = tr[ir] - tr[0]
    del tr
    k = len(ir)
    if cfg.delta_unit == "f" and cfg.delta >= k:
        raise InputError(
            f"delta {cfg.delta} needs more than {cfg.delta} associated poses; there are {k}"
        )
    qr_all, qe_all = np.asarray(ref.quaternion), np.asarray(est.quaternion)
    ref_xyz = np.asarray(ref.position)[ir]
    est_xyz = np.asarray(est.position)[ie]
    al = _alignment(cfg, ref, est, ir, ie, ref_xyz, est_xyz)
    rot, trans, scale = al["rotation"], al["translation"], al["scale"]
    q_align = quat_from_matrix(rot)
    for s in _blocks(k):  # in place: P' = s R p + t
        est_xyz[s] = scale * est_xyz[s] @ rot.T + trans

    # APE, block by block
    ape_rel = [r for r in cfg.pose_relations if r in APE_RELATIONS]
    ape = {r: np.empty(k) for r in ape_rel}
    nees = np.empty(k) if est.covariance is not None else None
    for s in _blocks(k):
        dq = quat_between(qr_all[ir[s]], quat_multiply(q_align, qe_all[ie[s]]))
        e = est_xyz[s] - ref_xyz[s]
        dt = np.linalg.norm(e, axis=1)
        for r in ape_rel:
            ape[r][s] = relation_errors(r, dq, dt)
        if nees is not None:
            c = scale**2 * rot @ np.asarray(est.covariance)[ie[s]][:, :3, :3] @ rot.T
            nees[s] = np.einsum("ni,ni->n", e, np.linalg.solve(c, e[..., None])[..., 0])

    # RPE pairs, chosen on the aligned estimate (or the reference)
    p_sel, q_src, idx = (ref_xyz, qr_all, ir) if cfg.pairs_from_reference else (est_xyz, qe_all, ie)
    q_sel = q_src[idx] if cfg.delta_unit in ("d", "r") else None
    pi, pj = rpe_pairs(p_sel, q_sel, cfg.delta, cfg.delta_unit, all_pairs=cfg.all_pairs,
                       delta_tol=cfg.delta_tol)  # fmt: skip
    del q_sel
    rpe_t = t_pairs[pi]
    m = len(pi)
    rpe = {r: np.empty(m) for r in cfg.pose_relations}
    ref_dist = np.empty(m) if "point_distance_error_ratio" in rpe else None
    for s in _blocks(m):
        i, j = pi[s], pj[s]
        qri, qei = qr_all[ir[i]], quat_multiply(q_align, qe_all[ie[i]])
        q_rel_r = quat_between(qri, qr_all[ir[j]])
        q_rel_e = quat_between(qei, quat_multiply(q_align, qe_all[ie[j]]))
        step_r = ref_xyz[j] - ref_xyz[i]
        step_e = est_xyz[j] - est_xyz[i]
        t_rel_r = quat_rotate(quat_conjugate(qri), step_r)
        t_rel_e = quat_rotate(quat_conjugate(qei), step_e)
        dq = quat_between(q_rel_r, q_rel_e)
        dt = np.linalg.norm(t_rel_e - t_rel_r, axis=1)
        dist = (np.linalg.norm(step_r, axis=1), np.linalg.norm(step_e, axis=1))
        for r in cfg.pose_relations:
            rr = "point_distance" if r == "point_distance_error_ratio" else r
            rpe[r][s] = relation_errors(rr, dq, dt, dist)
        if ref_dist is not None:
            ref_dist[s] = dist[0]
    notes = []
    if ref_dist is not None:
        moved = np.flatnonzero(ref_dist)
        if len(moved) < m:
            notes.append(
                f"point_distance_error_ratio leaves out {m - len(moved)} of {m} RPE pairs "
                "whose reference positions coincide"
            )
        rpe["point_distance_error_ratio"] = (
            rpe_t[moved],
            rpe["point_distance_error_ratio"][moved] / ref_dist[moved] * 100.0,
        )

    series = _series("ape", ape_rel, t_pairs, ape)
    series.update(_series("rpe", cfg.pose_relations, rpe_t, rpe))
    if "trans_part" in cfg.pose_relations:
        for a, axis in enumerate("xyz"):
            name = f"ape_{axis}_m"
            series[name] = ErrorSeries(name, "axis", axis, "m", t_pairs,
                                       est_xyz[:, a] - ref_xyz[:, a])  # fmt: skip
    return CompareResult(
        series=series,
        t=t_pairs,
        rpe_t=rpe_t,
        ref_xyz=ref_xyz,
        est_xyz=est_xyz,
        alignment=al,
        n_ref=len(ref),
        n_est=len(est),
        settings=cfg.as_dict(),
        nees=nees,
        labels=tuple(labels),
        notes=notes,
    )
