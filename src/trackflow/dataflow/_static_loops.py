"""Static calibrations that contradict each other.

Two statics between the same frames, or a loop of statics (A-B, B-C and C-A), say one
relationship twice. If the two answers differ by more than their uncertainty the setup is
wrong (a stale calibration, a mistyped sign, a forgotten unit), and whichever path the
planner took would silently decide which calibration wins. :class:`StaticLoops` follows the
statics as they are read: frames joined by statics share a root, each with ``T_root_frame``
and the variances summed along the way; a static between two frames that are already joined
is compared with the chain it closes.

The allowed difference is five standard deviations of the summed position variance (and of
the orientation variance), and at least 1 mm and 0.1 degree (calibrations printed with few
digits, statics given without covariance).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..math import Pose, quat_angle

__all__ = ["StaticLoops"]

#: the smallest allowed difference [m] and [rad]
MIN_POS, MIN_ROT = 1e-3, math.radians(0.1)


@dataclass(frozen=True)
class _Link:
    root: str
    pose: Pose  # T_root_frame
    var_pos: float  # summed position variance along the statics to the root [m^2]
    var_rot: float  # [rad^2]
    names: frozenset[str]  # the statics on the way


class StaticLoops:
    """Statics added one by one; :meth:`add` says when one contradicts those before it."""

    def __init__(self):
        self._links: dict[str, _Link] = {}
        self._members: dict[str, list[str]] = {}  # root -> the frames joined to it

    def _link(self, frame: str) -> _Link:
        if frame not in self._links:
            self._links[frame] = _Link(frame, Pose.identity(), 0.0, 0.0, frozenset())
            self._members[frame] = [frame]
        return self._links[frame]

    def add(self, name: str, source: str, target: str, pose: Pose, cov) -> str | None:
        """Add static ``name`` (``T_source_target`` with 6x6 ``cov``); the contradiction it
        makes, in words, or ``None``."""
        c = np.asarray(cov, dtype=float)
        vp, vr = float(np.trace(c[:3, :3]) / 3), float(np.trace(c[3:, 3:]) / 3)
        a, b = self._link(source), self._link(target)
        if a.root == b.root:
            chain = a.pose.inverse() @ b.pose  # T_source_target by the statics before
            dp = float(np.linalg.norm(chain.position - pose.position))
            dr = float(quat_angle(chain.quaternion, pose.quaternion))
            sp = math.sqrt(a.var_pos + b.var_pos + vp)
            sr = math.sqrt(a.var_rot + b.var_rot + vr)
            tol_p, tol_r = max(5 * sp, MIN_POS), max(5 * sr, MIN_ROT)
            if dp > tol_p or dr > tol_r:
                others = sorted(a.names ^ b.names) or ["itself"]
                return (
                    f"static {name!r} ({source} -> {target}) contradicts "
                    f"{', '.join(repr(o) for o in others)} by {dp * 1e3:.1f} mm and "
                    f"{math.degrees(dr):.2f} deg (allowed {tol_p * 1e3:.1f} mm and "
                    f"{math.degrees(tol_r):.2f} deg: five sigma of their covariances)"
                )
            return None
        # the smaller tree joins the other's root (each frame moves O(log n) times):
        # T_rootK_f = T_rootK_k T_k_m T_m_rootM T_rootM_f, k and m the static's ends in the
        # kept and the moved tree
        if len(self._members[a.root]) >= len(self._members[b.root]):
            keep, move, bridge = a, b, a.pose @ pose @ b.pose.inverse()
        else:
            keep, move, bridge = b, a, b.pose @ pose.inverse() @ a.pose.inverse()
        # the statics from a moved frame to the new root: to m (its way to the old root
        # without m's), the new static, then k's way
        via = move.names ^ keep.names ^ {name}
        moved = self._members.pop(move.root)
        for f in moved:
            link = self._links[f]
            self._links[f] = _Link(
                keep.root, bridge @ link.pose, link.var_pos + keep.var_pos + vp + move.var_pos,
                link.var_rot + keep.var_rot + vr + move.var_rot, link.names ^ via,
            )  # fmt: skip
        self._members[keep.root] += moved
        return None
