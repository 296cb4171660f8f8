"""The optical tracker: infrared frames to body poses with covariance, guided by the filter.

Per frame (Dorfmueller-Ulhaas, section 2 and figure 5):

1. blobs are segmented in every image (:func:`~trackflow.optical.blobs.detect_blobs`);
2. every tracked body's pose Kalman filter predicts the pose at the exposure time; its
   markers are projected into the images with their predicted pixel covariance, and blobs
   inside a marker's chi-square gate are assigned to it (a blob claimed by two markers, or a
   marker with two blobs in its gate, is left out): this labels the blobs, so no epipolar
   search or model matching is needed, and blobs that do not belong to a body are ignored;
3. each body's labelled markers are triangulated from the predicted positions (Gauss-Newton,
   3x3 covariance each), and the pose is solved by absolute orientation with its 6x6
   covariance; markers failing their reprojection or residual gates are dropped, and a pose
   inconsistent with the prediction (NIS) is rejected;
4. bodies that are not tracked (start, after a full occlusion) are searched among the
   remaining blobs: epipolar correspondence, triangulation and identification by the marker
   models' distances, with the stale predictions deciding ties between similar bodies;
5. each measured pose updates its body's filter, and is reported with its covariance.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..filters import MotionModel, PoseKalmanFilter, chi2_gate
from ..math import Pose, UncertainPose, kernels_for, skew
from . import _kernels
from ._kernels import pack_cameras
from .blobs import detect_blobs
from .camera import CameraRig
from .correspondence import match_epipolar
from .matching import identify, pose_nis
from .models import MarkerModel

__all__ = ["BodyResult", "FrameResult", "OpticalTracker", "TrackerConfig"]


@dataclass
class TrackerConfig:
    """Settings of :class:`OpticalTracker` (units: pixels, metres, seconds).

    ``sigma_px`` is the centroid noise of one blob coordinate; it sets every covariance and
    gate, so it should be measured (:meth:`OpticalTracker.pixel_sigma_estimate`).
    ``search_interval_s`` spaces the (costly) searches for bodies that are not tracked: 0
    searches every frame; more bounds the time spent on bodies that are out of view, for a
    recovery delayed by up to that interval.
    """

    threshold: float = 20.0
    background: float = 6.0
    min_area: int = 2
    max_area: int = 2000
    sigma_px: float = 0.12
    epipolar_px: float = 1.5
    support_px: float = 1.5
    tolerance_m: float = 0.004
    min_markers: int = 4
    min_fraction: float = 0.3
    min_markers_tracked: int = 3
    gate_probability: float = 0.9999
    motion: MotionModel = field(
        default_factory=lambda: MotionModel(n_dp=1, n_do=1, noise=(0.0, 4.0, 0.0, 20.0))
    )
    lost_after_s: float = 0.25
    search_interval_s: float = 0.02
    merged_area_ratio: float = 1.6
    max_prediction_sigma_m: float = 0.005

    def __post_init__(self):
        if not self.sigma_px > 0:
            raise InputError(f"sigma_px must be > 0, got {self.sigma_px}")
        if not self.background < self.threshold:
            raise InputError("background must be below threshold")
        if self.min_markers_tracked < 3 or self.min_markers < 3:
            raise InputError("a pose needs at least 3 markers")
        if not 0.0 < self.gate_probability < 1.0:
            raise InputError(f"gate_probability must be in (0, 1), got {self.gate_probability}")


@dataclass
class BodyResult:
    """One body in one frame.

    Attributes
    ----------
    pose : UncertainPose or None
        Measured ``T_world_body`` with its 6x6 covariance (``None``: not measured).
    filtered : UncertainPose or None
        The filter's estimate after this frame; for a lost body its prediction (``None`` while
        never measured).
    mode : str
        ``"tracked"`` (guided by the prediction), ``"found"`` (searched) or ``"lost"``.
    n_markers : int
        Markers used for the pose.
    """

    pose: UncertainPose | None
    filtered: UncertainPose | None
    mode: str
    n_markers: int = 0


@dataclass
class FrameResult:
    t: float
    bodies: dict[str, BodyResult]
    n_blobs: int


class _Track:
    __slots__ = ("filter", "last_t")

    def __init__(self, motion: MotionModel):
        self.filter = PoseKalmanFilter(motion, history=0.5, gate_probability=None)
        self.last_t: float | None = None


class OpticalTracker:
    """Infrared frames (or blob centroids) to poses of known marker bodies.

    Parameters
    ----------
    rig : CameraRig
    models : sequence of MarkerModel
    config : TrackerConfig, optional
    """

    def __init__(
        self, rig: CameraRig, models: Sequence[MarkerModel], config: TrackerConfig | None = None
    ):
        self.rig = rig
        self.models = list(models)
        names = [m.name for m in self.models]
        if not names or len(set(names)) != len(names):
            raise InputError(f"need marker models with unique names, got {names}")
        self.config = config or TrackerConfig()
        c = self.config
        self._gate2 = chi2_gate(c.gate_probability, 2)
        self._gate3 = chi2_gate(c.gate_probability, 3)
        self._gate6 = chi2_gate(c.gate_probability, 6)
        gates = [chi2_gate(c.gate_probability, d) for d in range(1, 2 * len(rig))]
        self._chi_gates = np.array([np.inf, *gates])
        self._packed = pack_cameras(rig)
        self.reset()

    def reset(self) -> None:
        """Forget all tracks and statistics."""
        self.tracks = {m.name: _Track(self.config.motion) for m in self.models}
        self.stats = {
            "frames": 0,
            "tracked": 0,
            "found": 0,
            "lost": 0,
            "rejected_prediction": 0,
            "searches": 0,
            "rejected_blobs": 0,
        }
        self._last_t: float | None = None
        self._res = [0.0, 0]  # triangulation chi2 at sigma_px, degrees of freedom
        self._fit_res = [0.0, 0]  # absolute-orientation chi2, degrees of freedom
        self._last_search: float | None = None

    # -- public -----------------------------------------------------------------------------
    def process(self, t: float, images: Sequence[np.ndarray]) -> FrameResult:
        """Track one synchronised set of images exposed at ``t`` [s]."""
        if len(images) != len(self.rig):
            raise InputError(f"need {len(self.rig)} images (one per camera), got {len(images)}")
        c = self.config
        blobs = [
            detect_blobs(img, c.threshold, c.background, c.min_area, c.max_area) for img in images
        ]
        return self.process_blobs(t, [b.uv for b in blobs], [b.area for b in blobs])

    def process_blobs(
        self, t: float, blobs: Sequence[np.ndarray], areas: Sequence[np.ndarray] | None = None
    ) -> FrameResult:
        """Track one frame given the blob centroids (K_c, 2) [px] of every camera, and
        optionally their areas (K_c,) [px]: a tracked marker's blob more than
        ``merged_area_ratio`` times the median area of its body's blobs in that image is taken
        for two merged markers and not used."""
        if len(blobs) != len(self.rig):
            raise InputError(f"need blobs of {len(self.rig)} cameras, got {len(blobs)}")
        if not np.isfinite(t) or (self._last_t is not None and t <= self._last_t):
            raise InputError(f"frame time {t} is not after the previous frame ({self._last_t})")
        self._last_t = float(t)
        blobs = [np.asarray(b, dtype=float).reshape(-1, 2) for b in blobs]
        if areas is None:
            areas = [np.ones(len(b)) for b in blobs]
        areas = [np.asarray(a, dtype=float).reshape(-1) for a in areas]
        if len(areas) != len(blobs) or any(len(a) != len(b) for a, b in zip(areas, blobs)):
            raise InputError("areas must give one value per blob of every camera")
        finite = [np.all(np.isfinite(b), axis=1) for b in blobs]
        bad = int(sum((~f).sum() for f in finite))
        if bad:
            self.stats["rejected_blobs"] += bad  # non-finite centroids: counted, not used
            blobs = [b[f] for b, f in zip(blobs, finite)]
            areas = [a[f] for a, f in zip(areas, finite)]
        self._areas = np.concatenate(areas) if areas else np.zeros(0)
        self.stats["frames"] += 1
        used = [np.zeros(len(b), bool) for b in blobs]
        results: dict[str, BodyResult] = {}
        preds: dict[str, UncertainPose] = {}
        guided = []
        for m in self.models:
            tr = self.tracks[m.name]
            if tr.last_t is None:
                continue
            p = tr.filter.predict(t)
            preds[m.name] = p
            live = t - tr.last_t <= self.config.lost_after_s
            sig = np.sqrt(np.linalg.eigvalsh(p.covariance[:3, :3])[-1])
            if live and sig <= self.config.max_prediction_sigma_m:
                guided.append(m)
        if guided:
            self._guided(t, guided, preds, blobs, used, results)
        todo = [m for m in self.models if m.name not in results]
        due = self._last_search is None or t - self._last_search >= self.config.search_interval_s
        if todo and due:
            self._last_search = t
            self._search(t, todo, preds, blobs, used, results)
        for m in self.models:
            if m.name not in results:
                self.stats["lost"] += 1
                results[m.name] = BodyResult(None, preds.get(m.name), "lost")
        return FrameResult(float(t), results, int(sum(len(b) for b in blobs)))

    def pixel_sigma_estimate(self, level: str = "points") -> float:
        """Centroid noise [px] implied by the residuals of the tracked markers seen so far
        (NaN before any): ``sigma_px * sqrt(sum chi2 / sum dof)``.

        ``level="points"``: the reprojection residuals of the triangulated markers (2 n - 3
        degrees of freedom each). ``level="poses"``: the residuals of the triangulated markers
        about the fitted rigid model (3 M - 6 per pose), which checks the point covariances
        that the pose covariance is made from.
        """
        if level not in ("points", "poses"):
            raise InputError(f"level must be 'points' or 'poses', got {level!r}")
        chi, dof = self._res if level == "points" else self._fit_res
        return float(self.config.sigma_px * np.sqrt(chi / dof)) if dof else float("nan")

    # -- guided --------------------------------------------------------------------------
    def _predicted_markers(self, model: MarkerModel, pred: UncertainPose):
        R = pred.pose.rotation_matrix
        X = model.points @ R.T + pred.position
        J = np.empty((len(model), 3, 6))
        J[:, :, :3] = np.eye(3)
        J[:, :, 3:] = -R @ skew(model.points)
        return X, J @ pred.covariance @ np.swapaxes(J, 1, 2)

    def _guided(self, t, models, preds, blobs, used, results) -> None:
        c = self.config
        Xs, Cs = [], []
        for m in models:
            X, C = self._predicted_markers(m, preds[m.name])
            Xs.append(X)
            Cs.append(C)
        X = np.concatenate(Xs)
        C = np.ascontiguousarray(np.concatenate(Cs))
        start = np.concatenate([[0], np.cumsum([len(b) for b in blobs])]).astype(np.int64)
        allb = np.ascontiguousarray(np.concatenate(blobs)) if start[-1] else np.zeros((0, 2))
        P, R, tt = self._packed
        s2 = c.sigma_px**2
        k = kernels_for(_kernels)
        uv_obs, claim = k.guided_assign(P, R, tt, X, C, allb, start, s2, self._gate2)
        if c.merged_area_ratio:
            owner = np.repeat(np.arange(len(models)), [len(m) for m in models])
            k.drop_merged(
                uv_obs, claim, owner, len(models), self._areas, start, c.merged_area_ratio
            )
        Xr, cov, chi2, n_views = k.refine_points_packed(P, R, tt, X, uv_obs, s2, 1)
        dof = 2 * n_views - 3
        with np.errstate(invalid="ignore"):
            good = (n_views >= 2) & (
                chi2 <= self._chi_gates[np.clip(dof, 0, len(self._chi_gates) - 1)]
            )
        q0 = 0
        for m in models:
            sl = slice(q0, q0 + len(m))
            q0 += len(m)
            res = self._pose_from_markers(m, Xr[sl], cov[sl], good[sl].copy(), preds[m.name])
            if res is None:
                continue
            pose, ok = res
            self._fit_res[0] += self._fit_last[0]
            self._fit_res[1] += self._fit_last[1]
            q_used = np.flatnonzero(ok) + sl.start
            self._res[0] += float(chi2[q_used].sum())
            self._res[1] += int(dof[q_used].sum())
            mark = np.zeros(len(X) + 1, bool)
            mark[q_used] = True
            hit = mark[claim]  # claim -1 indexes the False sentinel
            for ci in range(len(self.rig)):
                used[ci] |= hit[start[ci] : start[ci + 1]]
            self._update(m, t, pose, "tracked", int(ok.sum()), results)

    def _pose_from_markers(self, m, X, C, ok, pred):
        """Robust absolute orientation on labelled markers; ``None`` if too few or the pose
        contradicts the prediction."""
        c = self.config
        for _ in range(len(m)):
            if ok.sum() < c.min_markers_tracked:
                return None
            try:
                t, q, cov, pc = kernels_for(_kernels).fit_pose_cov(m.points[ok], X[ok], C[ok], 2)
            except np.linalg.LinAlgError:  # degenerate (e.g. three nearly collinear markers)
                return None
            worst = int(np.argmax(pc))
            if pc[worst] <= self._gate3:
                break
            ok[np.flatnonzero(ok)[worst]] = False
        else:
            return None
        if not (np.all(np.isfinite(cov)) and np.linalg.eigvalsh(cov)[0] > 0):
            return None
        self._fit_last = (float(pc.sum()), 3 * int(ok.sum()) - 6)
        pose = UncertainPose(Pose(t, q, normalize=True), cov)
        if pred is not None and pose_nis(pred, pose) > self._gate6:
            self.stats["rejected_prediction"] += 1
            return None
        return pose, ok

    # -- search -----------------------------------------------------------------------------
    def _search(self, t, models, preds, blobs, used, results) -> None:
        c = self.config
        self.stats["searches"] += 1
        cand = match_epipolar(
            self.rig, blobs, c.sigma_px, c.epipolar_px, c.support_px, c.gate_probability, used
        )
        if len(cand) < 3:
            return
        found = identify(
            cand,
            models,
            tolerance=c.tolerance_m,
            min_markers=c.min_markers,
            min_fraction=c.min_fraction,
            predictions={m.name: preds[m.name] for m in models if m.name in preds},
            gate_probability=c.gate_probability,
        )
        for name, match in found.items():
            m = next(mm for mm in models if mm.name == name)
            self._update(m, t, match.fit.pose, "found", match.n_markers, results)

    # -- filter -------------------------------------------------------------------------------
    def _update(self, m, t, pose, mode, n, results) -> None:
        tr = self.tracks[m.name]
        if mode == "found" and (tr.last_t is None or t - tr.last_t > self.config.lost_after_s):
            tr.filter.reset()  # a new track: the old motion state is stale
        tr.filter.update_pose(t, pose)
        tr.last_t = t
        self.stats[mode] += 1
        results[m.name] = BodyResult(pose, tr.filter.predict(t), mode, n)
