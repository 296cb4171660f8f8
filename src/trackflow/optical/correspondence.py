"""Which blobs in different cameras are images of the same marker: epipolar correspondence.

For every camera pair, blob pairs closer than ``epipolar_px`` to each other's epipolar line
are candidates; each candidate is triangulated and reprojected into the other cameras, where
the nearest blob within ``support_px`` joins it. Candidates are then accepted greedily, most
views first, each blob used once. A blob pair seen by only two cameras whose blobs also pair
with other blobs is *ambiguous* (several markers on one epipolar line): all its alternatives
are returned, marked with a common ``group``, for the model matching or the filter's
prediction to decide (Dorfmueller-Ulhaas, section 2: "the pose predicted by the Kalman filter
provides additional information preventing wrong matches").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..filters import chi2_gate
from ..math import skew
from .camera import CameraRig
from .triangulation import refine_points, triangulate_normalized

__all__ = ["PointCandidates", "match_epipolar"]


@dataclass
class PointCandidates:
    """3D points from blobs of several cameras.

    Attributes
    ----------
    X : ndarray (P, 3)
        World points [m].
    covariance : ndarray (P, 3, 3)
        From the pixel noise [m^2].
    chi2 : ndarray (P,)
        Reprojection chi-square.
    blobs : ndarray (P, C) of int
        Index of the blob used in each camera, -1 where none.
    group : ndarray (P,) of int
        -1 for an unambiguous point; otherwise the id of a set of mutually exclusive
        alternatives (they share blobs; at most one is real).
    """

    X: np.ndarray
    covariance: np.ndarray
    chi2: np.ndarray
    blobs: np.ndarray
    group: np.ndarray

    def __len__(self) -> int:
        return len(self.X)

    @property
    def ambiguous(self) -> np.ndarray:
        return self.group >= 0

    @classmethod
    def empty(cls, n_cameras: int) -> PointCandidates:
        return cls(
            np.zeros((0, 3)),
            np.zeros((0, 3, 3)),
            np.zeros(0),
            np.zeros((0, n_cameras), int),
            np.zeros(0, int),
        )

    def select(self, keep) -> PointCandidates:
        return PointCandidates(
            self.X[keep], self.covariance[keep], self.chi2[keep], self.blobs[keep], self.group[keep]
        )


def _essential(rig: CameraRig, a: int, b: int) -> np.ndarray:
    """``E`` with ``x_b^T E x_a = 0`` for normalised coordinates of cameras a and b."""
    ca, cb = rig[a], rig[b]
    R = cb.R_cam_world @ ca.R_cam_world.T
    t = cb.t_cam_world - R @ ca.t_cam_world
    return skew(t) @ R


def _line_distance(E: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """(Na, Nb) distance of ``xb`` to the epipolar lines of ``xa`` (normalised units)."""
    ha = np.concatenate([xa, np.ones((len(xa), 1))], axis=1)
    hb = np.concatenate([xb, np.ones((len(xb), 1))], axis=1)
    lines = ha @ E.T  # (Na, 3)
    num = np.abs(lines @ hb.T)
    return num / np.maximum(np.hypot(lines[:, :1], lines[:, 1:2]), 1e-300)


def _gather(blobs: list[np.ndarray], tracks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Values (C, T, 2) (pixels or normalised coordinates) and mask (C, T) of tracks (T, C) of
    blob indices."""
    C, T = tracks.shape[1], len(tracks)
    uv = np.full((C, T, 2), np.nan)
    for c in range(C):
        sel = tracks[:, c] >= 0
        if sel.any():
            uv[c, sel] = blobs[c][tracks[sel, c]]
    return uv, tracks.T >= 0


def match_epipolar(
    rig: CameraRig,
    blobs: list[np.ndarray],
    sigma_px: float = 0.1,
    epipolar_px: float = 1.5,
    support_px: float = 1.5,
    gate_probability: float = 0.999,
    exclude: list[np.ndarray] | None = None,
) -> PointCandidates:
    """Epipolar correspondence and triangulation of unlabelled blobs.

    Parameters
    ----------
    rig : CameraRig
    blobs : list of ndarray (K_c, 2)
        Blob centroids of each camera [px].
    sigma_px : float
        Centroid noise [px] (for the covariances and the reprojection gate).
    epipolar_px, support_px : float
        Largest distance to an epipolar line, and of a reprojection to a supporting blob [px].
    gate_probability : float
        Points whose reprojection chi-square exceeds this quantile are dropped.
    exclude : list of bool ndarray (K_c,), optional
        Blobs already explained (e.g. by predicted markers) that must not be used.

    Returns
    -------
    PointCandidates
    """
    C = len(rig)
    if len(blobs) != C:
        raise InputError(f"need one blob array per camera ({C}), got {len(blobs)}")
    blobs = [np.asarray(b, dtype=float).reshape(-1, 2) for b in blobs]
    free = [np.ones(len(b), bool) for b in blobs]
    if exclude is not None:
        free = [f & ~np.asarray(e, bool) for f, e in zip(free, exclude)]
    norm = [cam.normalize(b) for cam, b in zip(rig, blobs)]
    focal = [float(np.sqrt(cam.K[0, 0] * cam.K[1, 1])) for cam in rig]
    # 1. candidate pairs along epipolar lines
    pairs = []
    for a in range(C):
        for b in range(a + 1, C):
            ia, ib = np.flatnonzero(free[a]), np.flatnonzero(free[b])
            if not len(ia) or not len(ib):
                continue
            E = _essential(rig, a, b)
            d_b = _line_distance(E, norm[a][ia], norm[b][ib]) * focal[b]
            d_a = _line_distance(E.T, norm[b][ib], norm[a][ia]).T * focal[a]
            ok = np.maximum(d_a, d_b) < epipolar_px
            ka, kb = np.nonzero(ok)
            t = np.full((len(ka), C), -1)
            t[:, a], t[:, b] = ia[ka], ib[kb]
            pairs.append(t)
    if not pairs or not sum(len(p) for p in pairs):
        return PointCandidates.empty(C)
    tracks = np.concatenate(pairs)
    # 2. triangulate each pair, keep those in front of both cameras, collect support
    xn, mask = _gather(norm, tracks)
    X = triangulate_normalized(rig, xn, mask)
    proj = rig.project(X)  # (C, T, 2)
    front = np.all(np.isfinite(proj) | ~mask[..., None], axis=(0, 2)) & np.all(
        np.isfinite(X), axis=1
    )
    for c in range(C):
        idx = np.flatnonzero(free[c])
        if not len(idx):
            continue
        need = front & (tracks[:, c] < 0) & np.all(np.isfinite(proj[c]), axis=1)
        if not need.any():
            continue
        d = np.linalg.norm(proj[c, need][:, None] - blobs[c][idx][None], axis=-1)
        k = d.argmin(axis=1)
        hit = d[np.arange(len(k)), k] < support_px
        rows = np.flatnonzero(need)[hit]
        tracks[rows, c] = idx[k[hit]]
    tracks = tracks[front]
    if not len(tracks):
        return PointCandidates.empty(C)
    tracks = np.unique(tracks, axis=0)
    n_views = (tracks >= 0).sum(axis=1)
    # 3. refine and gate every distinct track
    uv, mask = _gather(blobs, tracks)
    xn, _ = _gather(norm, tracks)
    tri = refine_points(rig, triangulate_normalized(rig, xn, mask), uv, mask, sigma_px, 2)
    dof = np.maximum(2 * n_views - 3, 1)
    gates = np.array([chi2_gate(gate_probability, int(d)) for d in dof])
    ok = tri.valid & (tri.chi2 <= gates)
    order = np.lexsort((np.where(ok, tri.chi2 / dof, np.inf), -n_views))
    order = order[ok[order]]
    # 4. greedy acceptance: multi-view tracks first, each blob used once
    used = [np.zeros(len(b), bool) for b in blobs]
    accepted: list[int] = []
    two_view: list[int] = []
    for i in order:
        t = tracks[i]
        cams = np.flatnonzero(t >= 0)
        if any(used[c][t[c]] for c in cams):
            continue
        if n_views[i] >= 3:
            accepted.append(i)
            for c in cams:
                used[c][t[c]] = True
        else:
            two_view.append(i)
    # two-view tracks: unique ones accepted, clusters sharing blobs returned as alternatives
    group = np.full(len(tracks), -1)
    tv = [
        i
        for i in two_view
        if not any(used[c][tracks[i, c]] for c in np.flatnonzero(tracks[i] >= 0))
    ]
    parent = {i: i for i in tv}

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    owner: dict[tuple[int, int], int] = {}
    for i in tv:
        for c in np.flatnonzero(tracks[i] >= 0):
            key = (int(c), int(tracks[i, c]))
            if key in owner:
                parent[find(i)] = find(owner[key])
            else:
                owner[key] = i
    roots: dict[int, list[int]] = {}
    for i in tv:
        roots.setdefault(find(i), []).append(i)
    next_group = 0
    for members in roots.values():
        accepted.extend(members)
        if len(members) > 1:
            group[members] = next_group
            next_group += 1
    keep = np.array(sorted(accepted), dtype=int)
    return PointCandidates(
        tri.X[keep], tri.covariance[keep], tri.chi2[keep], tracks[keep], group[keep]
    )
