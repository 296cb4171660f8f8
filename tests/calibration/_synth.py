"""Synthetic two-tracker recordings with known X, Z, clock offset and noise (test helper)."""

from __future__ import annotations

import numpy as np

from trackflow.io import PoseStream
from trackflow.math import quat_conjugate, quat_exp, quat_multiply, quat_rotate

X_TRUE = (np.array([0.01, 0.08, 0.27]), quat_exp(np.array([1.5, 0.1, -0.05])))
Z_TRUE = (np.array([-0.3, -0.35, -0.9]), quat_exp(np.array([0.6, 1.2, 1.1])))


def motion(t: np.ndarray, seed: int = 0, rot_amp: float = 0.6, axes=(1, 1, 1)):
    """A smooth tool trajectory ``T_base_tool(t)``: sums of sinusoids in position and rotation."""
    rng = np.random.default_rng(seed)
    f = rng.uniform(0.05, 0.4, size=(2, 3, 3))
    ph = rng.uniform(0, 2 * np.pi, size=(2, 3, 3))
    amp_p = rng.uniform(0.05, 0.15, size=(3, 3))
    amp_r = rng.uniform(0.3, 1.0, size=(3, 3)) * rot_amp * np.asarray(axes, float)[None, :]
    s = np.sin(2 * np.pi * f[..., None] * t + ph[..., None])  # (2, 3, 3, N)
    p = np.array([0.4, 0.0, 0.4])[:, None] + np.einsum("kj,kjn->jn", amp_p, s[0])
    rv = np.einsum("kj,kjn->jn", amp_r, s[1])
    return p.T, quat_exp(rv.T)


def perturb(p, q, sigma_p, sigma_r, rng):
    p = p + rng.normal(0, sigma_p, p.shape)
    q = quat_multiply(q, quat_exp(rng.normal(0, sigma_r, p.shape)))
    return p, q


def two_trackers(
    seed: int = 0,
    duration: float = 30.0,
    rate_a: float = 30.0,
    rate_b: float = 72.0,
    offset: float = 0.25,
    sigma_p: float = 5e-4,
    sigma_r: float = np.radians(0.1),
    axes=(1, 1, 1),
    rot_amp: float = 0.6,
    gap: tuple[float, float] | None = None,
    t0: float = 1.7e9,
    Z=Z_TRUE,
):
    """Robot ``T_base_tool`` (a) and sensor ``T_world_body`` (b) with ``t_a = t_b + offset``.

    ``A X = Z B`` holds exactly at matching instants before noise; both streams get white
    position and rotation noise; ``gap = (start, end)`` seconds removes sensor samples; ``Z``
    ``(p (3,), q (4,))`` is the sensor's world in the robot's base (another session's).
    """
    rng = np.random.default_rng(seed + 1000)
    ta = np.arange(0, duration, 1 / rate_a) + rng.uniform(0, 1 / rate_a)
    tb = np.arange(0, duration, 1 / rate_b) + rng.uniform(0, 1 / rate_b)
    pa, qa = motion(ta, seed, rot_amp, axes)
    pb_t, qb_t = motion(tb, seed, rot_amp, axes)  # true A at the sensor's true instants
    Xp, Xq = X_TRUE
    Zp, Zq = Z
    # B = Z^-1 A X
    pAX = pb_t + quat_rotate(qb_t, Xp)
    qAX = quat_multiply(qb_t, Xq)
    qZi = quat_conjugate(Zq)
    pb = quat_rotate(qZi, pAX - Zp)
    qb = quat_multiply(qZi, qAX)
    pa, qa = perturb(pa, qa, sigma_p, sigma_r, rng)
    pb, qb = perturb(pb, qb, sigma_p, sigma_r, rng)
    keep = np.ones(len(tb), bool) if gap is None else ~((tb >= gap[0]) & (tb < gap[1]))
    a = PoseStream.from_seconds("base", "tool", t0 + ta, pa, qa)
    # the sensor's clock reads t_true - offset
    b = PoseStream.from_seconds("world", "body", t0 + tb[keep] - offset, pb[keep], qb[keep])
    return a, b
