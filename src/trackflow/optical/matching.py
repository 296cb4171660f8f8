"""Finding known rigid marker models among unlabelled 3D points (with ghosts and gaps).

Hypotheses come from triangles of the model: measured point triples whose three distances
match a model triangle within ``tolerance`` give a pose (closed form); the pose is verified
by counting the model's markers that land near a measured point. The best hypothesis of each
model is refined by :func:`~trackflow.optical.absolute_orientation.fit_pose` with the points'
covariances, markers whose residual fails the chi-square gate are dropped.

Several bodies are identified greedily, the best-supported first, each point used once.
A model that fits two disjoint places equally well is *ambiguous* and not reported, unless
a prediction (the pose Kalman filter's, with its covariance) decides: hypotheses whose pose
is inconsistent with the prediction (NIS above the gate) are discarded, and ties go to the
one nearer the prediction. This is the matching heuristic the paper asks of the filter.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..errors import InputError
from ..filters import chi2_gate
from ..math import UncertainPose, kernels_for, quat_rminus, umeyama
from .absolute_orientation import PoseFit, fit_pose
from .correspondence import PointCandidates
from .models import MarkerModel

__all__ = ["BodyMatch", "identify", "pose_nis"]


@dataclass
class BodyMatch:
    """One identified body.

    Attributes
    ----------
    model : MarkerModel
    points : ndarray (M,) of int
        Index of the candidate point matched to each marker, -1 if the marker is not seen.
    fit : PoseFit
        ``T_world_body`` with covariance, from the matched points.
    """

    model: MarkerModel
    points: np.ndarray
    fit: PoseFit

    @property
    def n_markers(self) -> int:
        return int((self.points >= 0).sum())


def pose_nis(a: UncertainPose, b: UncertainPose) -> float:
    """Mahalanobis distance squared between two poses with covariances ``a.C + b.C``, the
    difference in ``a``'s error convention (``t_b = t_a + dt``, ``R_b = R_a Exp(dtheta)``)."""
    e = np.concatenate([b.position - a.position, quat_rminus(b.quaternion, a.quaternion)])
    S = a.covariance + b.covariance
    return float(e @ np.linalg.solve(S, e))


#: the backend seam's kernels of this module (compiled with numba when it is installed)
KERNELS = ("_seed_triangles",)
KERNEL_SOURCES = ()


def _seed_triangles(E, S, seed_i, seed_a, per_seed):
    """For every seed (point i = marker a), up to ``per_seed`` triangles (i, k, l) = (a, c, d)
    whose three distances all match, the best supported (``S[k, c] + S[l, d]``) first."""
    P, M = S.shape
    n = len(seed_i)
    tri_p = np.empty((n * per_seed, 3), np.int64)
    tri_m = np.empty((n * per_seed, 3), np.int64)
    out = 0
    ks = np.empty(P * M, np.int64)
    cs = np.empty(P * M, np.int64)
    for s in range(n):
        i, a = seed_i[s], seed_a[s]
        m = 0
        for k in range(P):
            for c in range(M):
                if E[i, k, a, c]:
                    ks[m] = k
                    cs[m] = c
                    m += 1
        cand_u = []
        cand_v = []
        cand_s = []
        for u in range(m):
            for v in range(u + 1, m):
                if ks[u] != ks[v] and cs[u] != cs[v] and E[ks[u], ks[v], cs[u], cs[v]]:
                    cand_u.append(u)
                    cand_v.append(v)
                    cand_s.append(S[ks[u], cs[u]] + S[ks[v], cs[v]])
        if len(cand_s) == 0:
            continue
        order = np.argsort(-np.array(cand_s))
        for j in range(min(per_seed, len(order))):
            u, v = cand_u[order[j]], cand_v[order[j]]
            tri_p[out, 0], tri_p[out, 1], tri_p[out, 2] = i, ks[u], ks[v]
            tri_m[out, 0], tri_m[out, 1], tri_m[out, 2] = a, cs[u], cs[v]
            out += 1
    return tri_p[:out], tri_m[:out]


def _hypotheses(
    model: MarkerModel,
    X: np.ndarray,
    D: np.ndarray,
    tol: float,
    seeds: int = 200,
    per_seed: int = 4,
):
    """Poses (R (T, 3, 3), t (T, 3)) from measured triples matching model triangles.

    ``E[i, k, a, c]`` says that the distance of points i, k matches that of markers a, c.
    A point's support for a marker, ``S[i, a]``, counts the points at a matching distance;
    the best-supported (point, marker) seeds are extended by two of their matches that also
    match each other, giving triangles of correspondences.
    """
    dm = model.distances
    M, P = len(dm), len(X)
    D = np.where(np.eye(P, dtype=bool), np.inf, D)
    dmx = np.where(np.eye(M, dtype=bool), np.nan, dm)
    near = D < dm.max() + tol
    E = (np.abs(D[:, :, None, None] - dmx[None, None]) < tol) & near[:, :, None, None]
    S = E.any(axis=3).sum(axis=1)  # (P, M)
    flat = np.argsort(-S, axis=None)[:seeds]
    si, sa = np.divmod(flat, M)
    keep = S[si, sa] >= 2
    tp, tm = kernels_for(sys.modules[__name__])._seed_triangles(E, S, si[keep], sa[keep], per_seed)
    if not len(tp):
        return np.zeros((0, 3, 3)), np.zeros((0, 3))
    fits = umeyama(X[tp], model.points[tm], allow_collinear=True)  # T_world_body per triangle
    return fits.rotation, fits.translation


def _assign(pred: np.ndarray, X: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Each predicted marker (M, 3) to its nearest point within ``tol``, each point once."""
    d = np.linalg.norm(pred[:, None] - X[None], axis=-1)
    out = np.full(len(pred), -1)
    dist = np.full(len(pred), np.inf)
    order = np.argsort(d, axis=None)
    taken = np.zeros(len(X), bool)
    for flat in order:
        m, p = divmod(int(flat), len(X))
        if d[m, p] >= tol:
            break
        if out[m] >= 0 or taken[p]:
            continue
        out[m], dist[m] = p, d[m, p]
        taken[p] = True
    return out, dist


def _best_for_model(model, cand, avail, tol, min_markers, prediction, gate, chi_gate):
    """Best verified match of ``model`` on the available points, or ``None``; and whether a
    different place fitted as well (ambiguity)."""
    idx = np.flatnonzero(avail)
    if len(idx) < 3:
        return None, False
    X = cand.X[idx]
    D = np.linalg.norm(X[:, None] - X[None], axis=-1)
    R, t = _hypotheses(model, X, D, tol)
    if not len(R):
        return None, False
    pred = np.einsum("tij,mj->tmi", R, model.points) + t[:, None]  # (T, M, 3)
    dist, _ = cKDTree(X).query(pred, distance_upper_bound=tol)  # (T, M), inf beyond tol
    inl = dist < tol
    count = inl.sum(axis=1)
    sse = np.where(inl, dist**2, 0.0).sum(axis=1)
    order = np.lexsort((sse, -count))
    order = order[count[order] >= min(min_markers, len(model))]
    results = []
    seen_places: list[np.ndarray] = []
    size = float(model.distances.max())
    for h in order[:40]:
        if any(np.linalg.norm(t[h] - q) < 0.5 * size for q in seen_places):
            continue  # the same place as a better hypothesis
        seen_places.append(t[h])
        m = _refine(model, cand, idx, pred[h], tol, min_markers, chi_gate)
        if m is None:
            continue
        if prediction is not None and pose_nis(prediction, m.fit.pose) > gate:
            continue
        results.append(m)
        if len(results) == 2:
            break
    if not results:
        return None, False
    if len(results) == 1:
        return results[0], False
    a, b = results
    if prediction is not None:
        best = min(results, key=lambda r: pose_nis(prediction, r.fit.pose))
        return best, False
    return a, b.n_markers >= a.n_markers


def _refine(model, cand, idx, pred, tol, min_markers, chi_gate) -> BodyMatch | None:
    X = cand.X[idx]
    assign, _ = _assign(pred, X, tol)
    for _ in range(3):
        ok = assign >= 0
        if ok.sum() < max(3, min(min_markers, len(model))):
            return None
        pts = idx[assign[ok]]
        fit = fit_pose(model.points[ok], cand.X[pts], cand.covariance[pts])
        bad = fit.point_chi2 > chi_gate
        if bad.any():
            drop = np.flatnonzero(ok)[bad]
            assign[drop] = -1
            continue
        # re-assign with the refined pose (picks up markers the first guess missed)
        new, _ = _assign(fit.pose.pose.transform_points(model.points), X, tol)
        if np.array_equal(new, assign):
            points = np.full(len(model), -1)
            points[ok] = pts
            return BodyMatch(model, points, fit)
        assign = new
    return None


def _claimed_by_other(name, m, bests, predictions) -> bool:
    """Whether another model's best match sits at the same place with at least as many
    markers (similar models seeing only their common markers); a model with a prediction
    keeps the place if the other model has none."""
    size = float(m.model.distances.max())
    for other, (_, mo) in bests.items():
        if other == name or mo.n_markers < m.n_markers:
            continue
        if np.linalg.norm(mo.fit.pose.position - m.fit.pose.position) > 0.5 * size:
            continue
        if name in predictions and other not in predictions:
            continue
        return True
    return False


def identify(
    candidates: PointCandidates,
    models: Sequence[MarkerModel],
    tolerance: float = 0.004,
    min_markers: int = 4,
    min_fraction: float = 0.3,
    predictions: Mapping[str, UncertainPose] | None = None,
    gate_probability: float = 0.999,
) -> dict[str, BodyMatch]:
    """Identify rigid bodies among unlabelled 3D points.

    Parameters
    ----------
    candidates : PointCandidates
        Points with covariances (ghosts and alternatives of ambiguous correspondences
        included; at most one point of a ``group`` is used).
    models : sequence of MarkerModel
    tolerance : float
        Distance tolerance [m] for matching distances and verifying markers (a few sigma of
        the point noise plus the model's manufacturing error).
    min_markers, min_fraction : int, float
        Fewest matched markers to report a body: ``max(min_markers, ceil(min_fraction * M))``
        for a model of ``M`` markers (capped at ``M``). Four reject most chance fits of small
        models; large models need more, since some four of their markers are nearly coplanar
        and then also fit a mirror image of the body (a reflection in glass).
    predictions : mapping name -> UncertainPose, optional
        Predicted ``T_world_body`` of tracked bodies (e.g. ``PoseKalmanFilter.predict``):
        inconsistent hypotheses are discarded and ambiguities resolved towards it.
    gate_probability : float
        Chi-square gates for marker residuals (3 dof) and for the prediction (6 dof).

    Returns
    -------
    dict name -> BodyMatch
        Bodies found; a body missing from the dict was not found or was ambiguous.
    """
    if not 0.0 < tolerance < 1.0:
        raise InputError(f"tolerance must be in (0, 1) m, got {tolerance}")
    names = [m.name for m in models]
    if len(set(names)) != len(names):
        raise InputError(f"model names must be unique, got {names}")
    predictions = dict(predictions or {})
    unknown = set(predictions) - set(names)
    if unknown:
        raise InputError(f"predictions for unknown models {sorted(unknown)}")
    chi_gate = chi2_gate(gate_probability, 3)
    gate6 = chi2_gate(gate_probability, 6)
    avail = np.ones(len(candidates), bool)
    remaining = list(models)
    found: dict[str, BodyMatch] = {}
    cache: dict[str, tuple] = {}
    while remaining:
        bests = {}
        for model in remaining:
            hit = cache.get(model.name)
            if hit is None or (
                hit[0] is not None and not avail[hit[0].points[hit[0].points >= 0]].all()
            ):
                hit = _best_for_model(
                    model, candidates, avail, tolerance,
                    min(len(model), max(min_markers, int(np.ceil(min_fraction * len(model))))),
                    predictions.get(model.name), gate6, chi_gate,
                )  # fmt: skip
                cache[model.name] = hit
            m, ambiguous = hit
            if m is not None and not ambiguous:
                bests[model.name] = (model, m)
        best = None
        for name, (model, m) in bests.items():
            if _claimed_by_other(name, m, bests, predictions):
                continue  # another model explains this place as well: not decidable now
            key = (m.n_markers, -m.fit.chi2)
            if best is None or key > best[0]:
                best = (key, model, m)
        if best is None:
            break
        _, model, m = best
        found[model.name] = m
        remaining.remove(model)
        used = m.points[m.points >= 0]
        avail[used] = False
        groups = candidates.group[used]
        for g in groups[groups >= 0]:
            avail[candidates.group == g] = False  # the alternatives of a used point are ghosts
    return found
