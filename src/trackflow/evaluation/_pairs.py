"""Pose relations and the choice of RPE pose pairs, as trajectory evaluation tools define them.

**Pose relations** (``POSE_RELATIONS``): what one error number measures, for an error pose
``E`` (APE: between the estimated and the reference pose; RPE: between their motions over a
pair; module docstring of :mod:`trackflow.evaluation._compare`):

* ``trans_part``: ``|t(E)|`` [m].
* ``rot_part``: ``|R(E) - I|_F = 2 sqrt(2) sin(angle / 2)`` (no unit).
* ``full``: ``|E - I|_F`` of the 4x4 matrix, ``sqrt(rot_part^2 + trans_part^2)`` (no unit).
* ``angle_deg``, ``angle_rad``: the rotation angle of ``R(E)``, in ``[0, 180]`` deg or
  ``[0, pi]`` rad.
* ``point_distance``: APE ``|p'_i - q_i|`` (the same numbers as ``trans_part``); RPE
  ``| |q_j - q_i| - |p'_j - p'_i| |``, the error of the distance between the pair's positions
  [m].
* ``point_distance_error_ratio`` (RPE only): ``point_distance / |q_j - q_i|`` in percent;
  pairs whose reference positions coincide are left out.

**RPE pairs** (:func:`rpe_pairs`) of ``N`` poses, for a ``delta`` in a ``unit``:

* ``"f"`` (frames): ``(i, i + delta)`` for ``i = 0, delta, 2 delta, ...`` (consecutive) or for
  every ``i`` (all pairs).
* ``"m"`` (metres travelled): consecutive: walking the poses, a pair ends where the path
  travelled since its start (sum of straight steps) reaches ``delta``, and the next pair starts
  there. All pairs: for every start ``i``, the end ``j > i`` whose path is nearest ``delta``,
  kept if within ``delta_tol * delta``.
* ``"d"``, ``"r"`` (rotation, degrees or radians, ``delta <= 180`` deg): consecutive: as for
  metres with the summed angles between consecutive orientations. All pairs: every ``(i, j)``,
  ``i < j``, whose relative rotation angle is within ``delta_tol * delta`` of ``delta`` (this
  compares every pair: ``N^2 / 2`` angles).

The pairs are chosen on the estimate (aligned) unless ``from_reference``; the same indices
pair the reference.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..math import kernels_for
from . import _pair_kernels

__all__ = [
    "DELTA_UNITS",
    "POSE_RELATIONS",
    "accumulated_path",
    "downsample_ids",
    "metric_name",
    "motion_filter_ids",
    "rpe_pairs",
]

#: ``--pose-relation`` names (evo's), in the order of evo's list.
POSE_RELATIONS = (
    "full",
    "trans_part",
    "rot_part",
    "angle_deg",
    "angle_rad",
    "point_distance",
    "point_distance_error_ratio",
)
#: Relations of the APE (the ratio is defined for relative motion only).
APE_RELATIONS = POSE_RELATIONS[:-1]
#: RPE ``delta`` units: frames, metres travelled, degrees, radians.
DELTA_UNITS = ("f", "m", "d", "r")
DELTA_UNIT_NAMES = {"f": "frames", "m": "m", "d": "deg", "r": "rad"}

#: relation -> (metric name suffix, unit of the numbers)
_SUFFIX = {
    "trans_part": ("trans_m", "m"),
    "rot_part": ("rot_part", ""),
    "full": ("full", ""),
    "angle_deg": ("rot_deg", "deg"),
    "angle_rad": ("rot_rad", "rad"),
    "point_distance": ("dist_m", "m"),
    "point_distance_error_ratio": ("dist_ratio_pct", "%"),
}


def metric_name(kind: str, relation: str) -> tuple[str, str]:
    """``("ape_trans_m", "m")``: the metric's name (``kind`` ``"ape"`` or ``"rpe"``) and unit."""
    suffix, unit = _SUFFIX[relation]
    return f"{kind}_{suffix}", unit


def relation_errors(
    relation: str, dq: np.ndarray, dt: np.ndarray, dist: tuple | None = None
) -> np.ndarray:
    """Error numbers of one relation for error poses given by parts.

    Parameters
    ----------
    relation : str
        One of ``POSE_RELATIONS`` except ``point_distance_error_ratio`` (see :func:`rpe_ratio`).
    dq : ndarray, shape (K, 4)
        Rotation of the error pose, unit quaternion ``(x, y, z, w)``.
    dt : ndarray, shape (K,)
        ``|t(E)|`` [m].
    dist : tuple of two ndarray (K,), optional
        RPE: the distances ``|q_j - q_i|`` and ``|p'_j - p'_i|`` [m] (``point_distance``).

    Returns
    -------
    ndarray, shape (K,)
    """
    if relation == "trans_part" or (relation == "point_distance" and dist is None):
        return dt
    if relation == "point_distance":
        return np.abs(dist[0] - dist[1])
    angle = 2.0 * np.arctan2(np.linalg.norm(dq[:, :3], axis=1), np.abs(dq[:, 3]))
    if relation == "angle_rad":
        return angle
    if relation == "angle_deg":
        return np.degrees(angle)
    rot = 2.0 * np.sqrt(2.0) * np.sin(0.5 * angle)
    if relation == "rot_part":
        return rot
    if relation == "full":
        return np.sqrt(rot * rot + dt * dt)
    raise InputError(f"unknown pose relation {relation!r}; use one of {POSE_RELATIONS}")


def check_delta(delta: float, unit: str) -> float:
    """``delta`` checked for ``unit`` (an integer >= 1 for frames; > 0, and an angle at most
    180 deg / pi rad); ``InputError`` otherwise."""
    if unit not in DELTA_UNITS:
        raise InputError(f"delta unit must be one of {DELTA_UNITS}, got {unit!r}")
    try:
        d = float(delta)
    except (TypeError, ValueError) as exc:
        raise InputError(f"delta must be a number, got {delta!r}") from exc
    if not np.isfinite(d) or d <= 0:
        raise InputError(f"delta must be > 0, got {delta}")
    if unit == "f":
        if d != int(d):
            raise InputError(f"delta must be an integer >= 1 in frames (unit f), got {delta}")
        return int(d)
    top = {"m": np.inf, "d": 180.0, "r": np.pi}[unit]
    if d > top:
        raise InputError(
            f"delta must be at most {top:g} {DELTA_UNIT_NAMES[unit]} (an angle), got {delta}"
        )
    return d


def accumulated_path(p: np.ndarray) -> np.ndarray:
    """Path length [m] from the first position to each, (N,), of positions ``p`` (N, 3)."""
    out = np.zeros(len(p))
    if len(p) > 1:
        np.cumsum(np.linalg.norm(p[:-1] - p[1:], axis=1), out=out[1:])
    return out


def rpe_pairs(
    p: np.ndarray,
    q: np.ndarray,
    delta: float,
    unit: str = "f",
    *,
    all_pairs: bool = False,
    delta_tol: float = 0.1,
) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(i, j)`` (M,) of the RPE pairs of ``N`` poses (module docstring).

    Parameters
    ----------
    p : ndarray, shape (N, 3)
        Positions [m] (used by ``unit="m"``).
    q : ndarray, shape (N, 4)
        Unit quaternions ``(x, y, z, w)`` (used by ``"d"``, ``"r"``).
    delta : float
        Step: frames (integer), metres, degrees or radians.
    unit : {"f", "m", "d", "r"}
    all_pairs : bool
        Every start pose, not consecutive segments.
    delta_tol : float
        All pairs by path or angle: accepted relative deviation from ``delta``.

    Raises
    ------
    InputError
        A bad ``delta`` / ``unit``, or no pair at all.
    """
    delta = check_delta(delta, unit)
    if not (np.isfinite(delta_tol) and delta_tol >= 0):
        raise InputError(f"delta_tol must be >= 0, got {delta_tol}")
    n = len(p)
    if unit == "f":
        if delta >= n:
            raise InputError(
                f"delta {delta} needs more than {delta} associated poses; there are {n}"
            )
        i = np.arange(0, n - delta, 1 if all_pairs else delta)
        return i, i + delta
    k = kernels_for(_pair_kernels)
    if unit == "m":
        p = np.ascontiguousarray(p, dtype=float)
        if all_pairs:
            i, j = k.pairs_by_path_all(accumulated_path(p), float(delta), delta * delta_tol)
        else:
            ids = k.ids_by_path(p, float(delta))
            i, j = ids[:-1], ids[1:]
    else:
        rad = np.radians(delta) if unit == "d" else delta
        tol = delta * delta_tol
        tol = np.radians(tol) if unit == "d" else tol
        q = np.ascontiguousarray(q, dtype=float)
        if all_pairs:
            m = k.count_pairs_by_angle_all(q, rad - tol, rad + tol)
            i, j = np.empty(m, np.int64), np.empty(m, np.int64)
            k.fill_pairs_by_angle_all(q, rad - tol, rad + tol, i, j)
        else:
            i, j = k.ids_by_angle(q, float(rad))
    if not len(i):
        hint = ", or a larger delta_tol" if all_pairs else ""
        raise InputError(
            f"delta {delta:g} {DELTA_UNIT_NAMES[unit]} gives no pose pairs among {n} poses "
            f"({'all' if all_pairs else 'consecutive'} pairs); try a smaller delta{hint}"
        )
    return i, j


def downsample_ids(n: int, max_poses: int) -> np.ndarray:
    """At most ``max_poses`` indices of ``n`` poses, evenly spaced from the first to the last
    (all of them when ``n <= max_poses``): ``floor(linspace(0, n - 1, max_poses))``."""
    if int(max_poses) != max_poses or max_poses < 1:
        raise InputError(f"downsample needs an integer number of poses >= 1, got {max_poses}")
    if n <= max_poses:
        return np.arange(n)
    return np.linspace(0, n - 1, int(max_poses), dtype=np.int64)


def check_motion_filter(min_dist_m: float, min_angle_deg: float) -> None:
    """``InputError`` unless both thresholds are finite and ``>= 0``."""
    if not (np.isfinite(min_dist_m) and min_dist_m >= 0):
        raise InputError(f"motion filter distance must be >= 0 m, got {min_dist_m}")
    if not (np.isfinite(min_angle_deg) and min_angle_deg >= 0):
        raise InputError(f"motion filter angle must be >= 0 deg, got {min_angle_deg}")


def motion_filter_ids(p: np.ndarray, q: np.ndarray, min_dist_m: float, min_angle_deg: float):
    """Indices of the poses kept by the motion filter: the first, then each pose whose path
    travelled since the last kept one reaches ``min_dist_m`` [m] or whose rotation from it
    reaches ``min_angle_deg`` [deg]. ``p`` (N, 3), ``q`` (N, 4); returns (M,) int."""
    check_motion_filter(min_dist_m, min_angle_deg)
    if len(p) < 2:
        raise InputError(f"the motion filter needs at least 2 poses, got {len(p)}")
    k = kernels_for(_pair_kernels)
    dist = accumulated_path(np.asarray(p, dtype=float))
    return k.motion_filter_ids(
        dist, np.ascontiguousarray(q, dtype=float), float(min_dist_m),
        float(np.radians(min_angle_deg)),
    )  # fmt: skip
