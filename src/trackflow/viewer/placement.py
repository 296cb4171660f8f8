"""Where the live view draws things: frames placed in the anchor frame by chaining static
values and the newest sensor poses, and poses carried into the anchor frame with their
covariance (pure pose algebra on arrays)."""

from __future__ import annotations

import numpy as np

from ..math import quat_conjugate, quat_multiply, quat_to_matrix
from .board import BoardPose

__all__ = ["place_frames", "to_world"]


def place_frames(anchor: str, values: list[tuple]) -> dict[str, tuple]:
    """Placement ``T_anchor_frame`` as ``(quaternion (4,), position (3,))`` of every frame
    reachable from ``anchor`` through ``values``: ``(a, b, q_ab (4,), t_ab (3,))``, the
    relationships ``T_a_b`` known now (static values, the newest sensor poses), walked either
    way."""
    known = {anchor: (np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3))}
    rot = {anchor: np.eye(3)}  # R_anchor_frame of the placed frames
    changed = True
    while changed:
        changed = False
        for a, b, q_ab, t_ab in values:
            if a in known and b not in known:
                q_a, t_a = known[a]
                known[b] = (quat_multiply(q_a, q_ab), rot[a] @ t_ab + t_a)
                rot[b] = quat_to_matrix(known[b][0])
                changed = True
            elif b in known and a not in known:
                q_b, t_b = known[b]
                q_a = quat_multiply(q_b, quat_conjugate(q_ab))
                rot[a] = quat_to_matrix(q_a)
                known[a] = (q_a, t_b - rot[a] @ t_ab)
                changed = True
    return known


def to_world(q_w_a: np.ndarray, t_w_a: np.ndarray, poses: list[BoardPose]):
    """``T_w_a @ pose`` for n bodies with their frames' placements exact (quaternions
    (n, 4), positions (n, 3)): world positions (n, 3), quaternions (n, 4) and covariances
    (n, 6, 6) (the translation error rotates with ``R_w_a``; the body-frame rotation error
    does not change)."""
    r = quat_to_matrix(q_w_a)
    pos = np.einsum("nij,nj->ni", r, np.array([p.position for p in poses])) + t_w_a
    quat = quat_multiply(q_w_a, np.array([p.quaternion for p in poses]))
    c = np.array([p.covariance for p in poses])
    c[:, :3, :] = r @ c[:, :3, :]
    c[:, :, :3] = c[:, :, :3] @ np.swapaxes(r, -1, -2)
    return pos, quat, c
