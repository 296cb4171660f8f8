"""Rigid marker models: named bodies with retro-reflective markers at known body-frame points.

A body is identified among unlabelled 3D points by its inter-marker distances (invariant to
the pose), so a usable set of models has distinct distance patterns; :func:`model_separation`
measures how distinct two models are and :func:`random_model` makes well-separated layouts.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["MarkerModel", "model_separation", "random_model", "similar_model"]


@dataclass(frozen=True, eq=False)
class MarkerModel:
    """A rigid body with markers.

    Parameters
    ----------
    name : str
    points : array_like (M, 3)
        Marker centres in the body frame [m], ``M >= 3`` and not collinear.
    normals : array_like (M, 3), optional
        Outward unit directions of the markers (for rendering: a marker is seen from the
        half-space around its normal); default from the centroid outwards.
    marker_diameter : float
        Marker ball diameter [m].
    """

    name: str
    points: np.ndarray
    normals: np.ndarray | None = None
    marker_diameter: float = 0.014

    def __post_init__(self):
        p = np.asarray(self.points, dtype=float)
        if p.ndim != 2 or p.shape[1] != 3 or len(p) < 3 or not np.all(np.isfinite(p)):
            raise InputError(f"model {self.name!r}: points must be finite (M, 3) with M >= 3")
        c = p - p.mean(axis=0)
        sv = np.linalg.svd(c, compute_uv=False)
        if sv[1] < 1e-6:
            raise InputError(f"model {self.name!r}: markers are collinear")
        d = self._distances(p)
        iu = np.triu_indices(len(p), 1)
        if d[iu].min() < self.marker_diameter:
            raise InputError(
                f"model {self.name!r}: two markers closer than the marker diameter "
                f"({d[iu].min() * 1e3:.1f} mm < {self.marker_diameter * 1e3:.1f} mm)"
            )
        if self.normals is None:
            n = c / np.maximum(np.linalg.norm(c, axis=1, keepdims=True), 1e-12)
        else:
            n = np.asarray(self.normals, dtype=float)
            if n.shape != p.shape:
                raise InputError(f"model {self.name!r}: normals must have shape {p.shape}")
            n = n / np.linalg.norm(n, axis=1, keepdims=True)
        object.__setattr__(self, "points", p)
        object.__setattr__(self, "normals", n)
        object.__setattr__(self, "distances", d)

    @staticmethod
    def _distances(p: np.ndarray) -> np.ndarray:
        return np.linalg.norm(p[:, None] - p[None], axis=-1)

    def __len__(self) -> int:
        return len(self.points)

    @classmethod
    def from_dict(cls, item: Mapping, where: str = "<model>") -> MarkerModel:
        """From ``{name, markers_mm: [[x, y, z], ...]}`` or ``markers_m``, optional
        ``marker_diameter_mm``."""
        if not isinstance(item, Mapping) or "name" not in item:
            raise InputError(f"{where}: a marker model needs a name and markers_mm or markers_m")
        if "markers_mm" in item:
            pts = np.asarray(item["markers_mm"], dtype=float) * 1e-3
        elif "markers_m" in item:
            pts = np.asarray(item["markers_m"], dtype=float)
        else:
            raise InputError(f"{where}: model {item['name']!r} needs markers_mm or markers_m")
        diam = float(item.get("marker_diameter_mm", 14.0)) * 1e-3
        try:
            return cls(str(item["name"]), pts, marker_diameter=diam)
        except ValueError as e:
            raise InputError(f"{where}: {e}") from e

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "markers_mm": np.round(self.points * 1e3, 6).tolist(),
            "marker_diameter_mm": self.marker_diameter * 1e3,
        }


def model_separation(a: MarkerModel, b: MarkerModel) -> float:
    """How distinct two models are by their distances [m]: every marker has a profile (its
    sorted distances to the other markers); the result is the largest, over markers of ``a``,
    of the smallest profile difference (max-norm) to any marker of ``b``. 0 when every marker
    of ``a`` looks like one of ``b``; at least the shift of the moved markers for
    :func:`similar_model`."""
    pa = np.sort(a.distances, axis=1)[:, 1:]
    pb = np.sort(b.distances, axis=1)[:, 1:]
    k = min(pa.shape[1], pb.shape[1])
    diff = np.abs(pa[:, None, :k] - pb[None, :, :k]).max(axis=2)
    return float(diff.min(axis=1).max())


def random_model(
    name: str,
    n_markers: int,
    rng: np.random.Generator,
    extent=(0.12, 0.10, 0.05),
    min_separation: float = 0.03,
) -> MarkerModel:
    """Markers spread on the surface of an ellipsoid of semi-axes ``extent`` [m], at least
    ``min_separation`` apart (rejection sampling; a layout like a hand-held target)."""
    pts: list[np.ndarray] = []
    e = np.asarray(extent, dtype=float)
    for _ in range(100000):
        v = rng.normal(size=3)
        p = e * v / np.linalg.norm(v)
        if all(np.linalg.norm(p - q) >= min_separation for q in pts):
            pts.append(p)
            if len(pts) == n_markers:
                return MarkerModel(name, np.array(pts))
    raise InputError(f"cannot place {n_markers} markers {min_separation} m apart on {extent}")


def similar_model(
    model: MarkerModel, name: str, rng: np.random.Generator, n_moved: int = 2, shift: float = 0.02
) -> MarkerModel:
    """A copy of ``model`` with ``n_moved`` markers moved by ``shift`` [m] along the surface
    (the hard case for identification: all other distances are the same)."""
    p = model.points.copy()
    for i in rng.choice(len(p), size=n_moved, replace=False):
        t = rng.normal(size=3)
        t -= model.normals[i] * (t @ model.normals[i])
        p[i] += shift * t / np.linalg.norm(t)
    return MarkerModel(name, p, marker_diameter=model.marker_diameter)
