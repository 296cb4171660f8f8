"""Realistic infrared frames of marker bodies moving along real recorded trajectories.

What a retro-reflective marker tracker's cameras see: dark images with one bright blob per
visible marker, whose size follows the distance (ball diameter over depth, blurred by the
optics), whose brightness falls with the square of the distance, and whose centre jitters by
``sigma_px`` (the centroid noise the bars are stated at). On top:

* occlusion: a marker is seen only within ``visibility_deg`` of its outward normal (the body
  hides its back side), moving vertical cylinders (people) block lines of sight, and whole
  bodies can be hidden for scheduled intervals (a hand over the target);
* missing markers: each marker image drops out with probability ``dropout``;
* ghosts: fixed reflections per camera, random flicker blobs, and mirror images of the
  markers in a reflective plane (glass), which triangulate to a consistent mirrored body;
* merged blobs where markers overlap in an image, saturation at 255, read noise.

The trajectories come from real recordings (:func:`trajectory_from_stream`), shifted into the
capture volume; the truth of every frame is returned with it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.special import ndtr

from ..errors import ExtrapolationError, InputError
from ..math import Pose
from .camera import CameraRig
from .models import MarkerModel

__all__ = [
    "Cylinder",
    "Frame",
    "FrameRenderer",
    "RenderSettings",
    "trajectory_from_stream",
]


@dataclass
class Cylinder:
    """A vertical cylinder (a person) moving on a circle: centre ``center + radius_path *
    (cos, sin)(omega t + phase)``, from the floor to ``height`` [m]."""

    center: tuple[float, float] = (0.0, 0.0)
    radius_path: float = 1.2
    omega: float = 0.5
    phase: float = 0.0
    radius: float = 0.2
    height: float = 1.8

    def axis(self, t: float) -> np.ndarray:
        a = self.omega * t + self.phase
        return np.array(self.center) + self.radius_path * np.array([np.cos(a), np.sin(a)])


@dataclass
class RenderSettings:
    """Parameters of the rendered infrared frames (defaults: a typical mocap camera)."""

    sigma_px: float = 0.1  # centroid jitter of every blob [px]
    blur_px: float = 0.6  # optics blur (Gaussian sigma) [px]
    peak: float = 180.0  # peak grey level of a 1 cm-blob image at 2.5 m
    background: float = 6.0
    read_noise: float = 1.5
    visibility_deg: float = 80.0
    dropout: float = 0.01
    static_ghosts: int = 2  # fixed reflections per camera
    flicker_ghosts: float = 0.3  # mean random ghost blobs per camera and frame
    mirror: tuple[tuple[float, float, float], float] | None = ((1.0, 0.0, 0.0), -1.8)
    mirror_gain: float = 0.6  # brightness of the mirror images
    occluders: list[Cylinder] = field(default_factory=list)
    hidden: list[tuple[str, float, float]] = field(default_factory=list)  # (body, t0, t1)


@dataclass
class Frame:
    """One synchronised set of images and its truth.

    Attributes
    ----------
    t : float
        Exposure time [s].
    images : list of ndarray (H, W) uint8
    poses : dict name -> Pose
        True ``T_world_body``.
    blob_uv : list of ndarray (K_c, 2)
        True (jittered) centre of every blob drawn in each camera [px].
    blob_label : list of ndarray (K_c,) of int
        ``body_index * 1000 + marker`` for marker images, -1 for ghosts.
    """

    t: float
    images: list[np.ndarray]
    poses: dict[str, Pose]
    blob_uv: list[np.ndarray]
    blob_label: list[np.ndarray]


def trajectory_from_stream(
    stream, center=(0.0, 0.0, 1.0), t_start: float | None = None, detrend_s: float | None = None
):
    """``T_world_body(t)`` from a recorded :class:`trackflow.io.PoseStream`.

    The recording's positions are shifted so that their mean lies at ``center`` [m] and its
    time so that ``t = 0`` is ``t_start`` (default: the first sample); between samples the pose
    is interpolated (linear position, slerp). ``detrend_s`` removes the centred moving average
    of the position over that many seconds: a person walking around a room keeps the hand's
    motion (everything faster than about ``1 / detrend_s`` Hz) inside a small capture volume;
    orientations are kept as recorded. Returns ``f(t: float) -> Pose``.
    """
    t = (np.asarray(stream.t_ns) - np.asarray(stream.t_ns)[0]) * 1e-9
    if t_start is not None:
        t = t - float(t_start)
    p = np.asarray(stream.position, dtype=float)
    if detrend_s is not None:
        from scipy.ndimage import uniform_filter1d

        n = max(1, int(round(detrend_s / np.median(np.diff(t)))))
        p = p - uniform_filter1d(p, n, axis=0, mode="nearest")
    p = p - p.mean(axis=0) + np.asarray(center, dtype=float)
    poses = Pose(p, np.asarray(stream.quaternion, dtype=float), normalize=True)

    def at(time: float) -> Pose:
        if not t[0] <= time <= t[-1]:
            raise ExtrapolationError("the trajectory", time, t[0], t[-1], "outside the recording")
        i = int(np.clip(np.searchsorted(t, time) - 1, 0, len(t) - 2))
        s = (time - t[i]) / (t[i + 1] - t[i])
        return poses[i].interpolate(poses[i + 1], s)

    at.duration = float(t[-1])  # type: ignore[attr-defined]
    return at


def _occluded(c: np.ndarray, X: np.ndarray, cyl: Cylinder, t: float) -> np.ndarray:
    """Whether the segments camera centre ``c`` -> points ``X`` (N, 3) pass through ``cyl``."""
    a = cyl.axis(t)
    d = X[:, :2] - c[:2]
    f = c[:2] - a
    A = np.einsum("ni,ni->n", d, d)
    B = 2 * (d @ f)
    Cc = f @ f - cyl.radius**2
    disc = B * B - 4 * A * Cc
    hit = np.zeros(len(X), bool)
    ok = disc > 0
    sq = np.sqrt(np.where(ok, disc, 0.0))
    for s in ((-B - sq) / (2 * A), (-B + sq) / (2 * A)):
        z = c[2] + s * (X[:, 2] - c[2])
        hit |= ok & (s > 0) & (s < 1) & (z > 0) & (z < cyl.height)
    return hit


class FrameRenderer:
    """Renders frames of several bodies for a camera rig.

    Parameters
    ----------
    rig : CameraRig
    models : sequence of MarkerModel
    trajectories : mapping name -> callable ``t -> Pose``
        ``T_world_body(t)`` of each model (e.g. :func:`trajectory_from_stream`).
    settings : RenderSettings
    seed : int
        All randomness (noise, jitter, dropouts, ghosts) comes from one seeded generator.
    """

    def __init__(
        self,
        rig: CameraRig,
        models: Sequence[MarkerModel],
        trajectories: Mapping[str, Callable[[float], Pose]],
        settings: RenderSettings | None = None,
        seed: int = 0,
    ):
        self.rig = rig
        self.models = list(models)
        missing = {m.name for m in self.models} - set(trajectories)
        if missing:
            raise InputError(f"no trajectory for models {sorted(missing)}")
        self.trajectories = dict(trajectories)
        self.settings = settings or RenderSettings()
        self.rng = np.random.default_rng(seed)
        s = self.settings
        self._bank = []
        self._static = []
        for cam in rig:
            w, h = cam.size
            noise = self.rng.normal(s.background, s.read_noise, (h + 64, w + 64))
            self._bank.append(np.clip(np.round(noise), 0, 255).astype(np.uint8))
            self._static.append(self.rng.uniform([8, 8], [w - 9, h - 9], (s.static_ghosts, 2)))

    # -- blobs ------------------------------------------------------------------------------
    def _marker_blobs(self, t: float, poses: dict[str, Pose]):
        """Per camera: centres, sigmas, fluxes and labels of the marker (and mirror) images."""
        s = self.settings
        cosv = np.cos(np.radians(s.visibility_deg))
        pts, nrm, lab, diam, gain = [], [], [], [], []
        for b, m in enumerate(self.models):
            if any(name == m.name and t0 <= t <= t1 for name, t0, t1 in s.hidden):
                continue
            T = poses[m.name]
            pts.append(T.transform_points(m.points))
            nrm.append(m.normals @ T.rotation_matrix.T)
            lab.append(b * 1000 + np.arange(len(m)))
            diam.append(np.full(len(m), m.marker_diameter))
            gain.append(np.ones(len(m)))
        if not pts:
            empty = [np.zeros((0, 2))] * len(self.rig)
            return (
                empty,
                [np.zeros(0)] * len(self.rig),
                [np.zeros(0)] * len(self.rig),
                [np.zeros(0, int)] * len(self.rig),
            )
        X, N, L = np.concatenate(pts), np.concatenate(nrm), np.concatenate(lab)
        Dm, G = np.concatenate(diam), np.concatenate(gain)
        if s.mirror is not None:
            n = np.asarray(s.mirror[0], float)
            n /= np.linalg.norm(n)
            dist = X @ n - s.mirror[1]
            X = np.concatenate([X, X - 2 * dist[:, None] * n])
            N = np.concatenate([N, N - 2 * (N @ n)[:, None] * n])
            L = np.concatenate([L, np.full(len(L), -1)])
            Dm = np.concatenate([Dm, Dm])
            G = np.concatenate([G, np.full(len(G), s.mirror_gain)])
        out = ([], [], [], [])
        for cam in self.rig:
            c = cam.center
            view = c - X
            depth = np.linalg.norm(view, axis=1)
            vis = np.einsum("ni,ni->n", N, view) > cosv * depth
            for cyl in s.occluders:
                vis &= ~_occluded(c, X, cyl, t)
            vis &= self.rng.random(len(X)) >= s.dropout
            uv = cam.project(X[vis])
            z = (X[vis] - c) @ cam.R_cam_world[2]
            inside = cam.in_image(uv, margin=3.0) & (z > 0.1)
            f = np.sqrt(cam.K[0, 0] * cam.K[1, 1])
            r_px = 0.5 * f * Dm[vis][inside] / z[inside]
            sig = np.sqrt((0.5 * r_px) ** 2 + s.blur_px**2)
            flux = s.peak * 2 * np.pi * sig**2 * G[vis][inside] * (2.5 / z[inside]) ** 2
            jit = self.rng.normal(0.0, s.sigma_px, (int(inside.sum()), 2))
            out[0].append(uv[inside] + jit)
            out[1].append(sig)
            out[2].append(flux)
            out[3].append(L[vis][inside])
        return out

    def _draw(self, img: np.ndarray, uv: np.ndarray, sig: np.ndarray, flux: np.ndarray) -> None:
        """Add Gaussian blobs (pixel-integrated) to ``img`` (uint8, in place, saturating)."""
        if not len(uv):
            return
        h, w = img.shape
        half = int(np.ceil(4 * sig.max())) + 1
        off = np.arange(-half, half + 1)
        cx, cy = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
        xs = cx[:, None] + off  # (B, P)
        ys = cy[:, None] + off
        wx = ndtr((xs + 0.5 - uv[:, :1]) / sig[:, None]) - ndtr(
            (xs - 0.5 - uv[:, :1]) / sig[:, None]
        )
        wy = ndtr((ys + 0.5 - uv[:, 1:]) / sig[:, None]) - ndtr(
            (ys - 0.5 - uv[:, 1:]) / sig[:, None]
        )
        val = flux[:, None, None] * wy[:, :, None] * wx[:, None, :]  # (B, P, P)
        Y = np.broadcast_to(ys[:, :, None], val.shape)
        X = np.broadcast_to(xs[:, None, :], val.shape)
        ok = (X >= 0) & (X < w) & (Y >= 0) & (Y < h) & (val > 0.05)
        flat, inv = np.unique(Y[ok] * w + X[ok], return_inverse=True)
        add = np.bincount(inv, weights=val[ok])
        pix = img.reshape(-1)
        pix[flat] = np.clip(np.round(pix[flat] + add), 0, 255).astype(np.uint8)

    def render(self, t: float) -> Frame:
        """The frame exposed at time ``t`` [s]."""
        s = self.settings
        poses = {m.name: self.trajectories[m.name](t) for m in self.models}
        uv_m, sig_m, flux_m, lab_m = self._marker_blobs(t, poses)
        images, all_uv, all_lab = [], [], []
        for c, cam in enumerate(self.rig):
            w, h = cam.size
            ox, oy = self.rng.integers(0, 64, 2)
            img = self._bank[c][oy : oy + h, ox : ox + w].copy()
            k = self.rng.poisson(s.flicker_ghosts)
            g_uv = np.concatenate(
                [self._static[c], self.rng.uniform([8, 8], [w - 9, h - 9], (k, 2))]
            )
            g_sig = np.full(len(g_uv), 1.0)
            g_flux = np.full(len(g_uv), s.peak * 2 * np.pi * 0.8)
            uv = np.concatenate([uv_m[c], g_uv])
            self._draw(
                img, uv, np.concatenate([sig_m[c], g_sig]), np.concatenate([flux_m[c], g_flux])
            )
            images.append(img)
            all_uv.append(uv)
            all_lab.append(np.concatenate([lab_m[c], np.full(len(g_uv), -1)]))
        return Frame(float(t), images, poses, all_uv, all_lab)
