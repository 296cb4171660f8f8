"""How far first-order covariance propagation is from Monte Carlo, at 1 and 10 degrees.

Cases: composition ``T_a_b @ T_b_c`` with a 1 m lever arm (both poses uncertain, independent)
and inversion of a pose 1 m from the origin; inputs have diagonal covariances with 1 mm position
and 1 or 10 degree rotation standard deviation, so the result can be compared with a
second-order prediction (below). The figures in ``docs/linearization.md`` are printed by
running this file as a script: ``.venv/bin/python tests/math/test_linearization.py``.

Second-order prediction for the thinnest direction. The rotation error moves the lever tip
``L`` by ``[dtheta]x L`` to first order; along the lever itself the first-order motion is zero
and the second-order term ``-|dtheta_perp|^2 L / 2`` has variance ``sigma_rot^4 L^2`` (two
perpendicular axes). Along that direction first order sees only the position variance
``k sigma_pos^2`` (``k`` = number of independent position errors that add up there), so the
smallest eigenvalue of ``M^-1/2 C M^-1/2`` is about ``1 / (1 + sigma_rot^4 L^2 / (k sigma_pos^2))``.
"""

from __future__ import annotations

import numpy as np
import pytest
from _helpers import (
    covariance_agreement,
    local,
    random_pose,
    retract,
    sample_covariance,
    sample_errors,
)

from trackflow import UncertainPose

N_SAMPLES = 200_000
SIGMA_POSITION = 1e-3  # metres
LEVER = 1.0  # metres
SIGMAS_DEG = (1.0, 10.0)
CASES = ("compose", "inverse")
SEED = 20261121


def diagonal_cov(sigma_rotation: float) -> np.ndarray:
    return np.diag([SIGMA_POSITION**2] * 3 + [sigma_rotation**2] * 3)


def measure(case: str, sigma_deg: float, rng: np.random.Generator) -> dict:
    """First-order vs Monte Carlo for one case; returns the figures of one table row."""
    sig = np.radians(sigma_deg)
    c_in = diagonal_cov(sig)
    if case == "compose":
        a, b = random_pose(rng, 0.5), random_pose(rng, LEVER)
        analytic = UncertainPose(a, c_in).compose(UncertainPose(b, c_in)).covariance
        sa = retract(a, sample_errors(rng, c_in, N_SAMPLES))
        sb = retract(b, sample_errors(rng, c_in, N_SAMPLES))
        err = local(a @ b, sa @ sb)
        k = 2  # position errors of a and of b both add along the lever
    elif case == "inverse":
        a = random_pose(rng, LEVER)
        analytic = UncertainPose(a, c_in).inverse().covariance
        s = retract(a, sample_errors(rng, c_in, N_SAMPLES))
        err = local(a.inverse(), s.inverse())
        k = 1
    else:
        raise ValueError(f"unknown case {case!r}")
    mc = sample_covariance(err)
    frob, ratios = covariance_agreement(analytic, mc)
    return {
        "case": case,
        "sigma_deg": sigma_deg,
        "frobenius": frob,
        "ratio_min": float(ratios[0]),
        "ratio_max": float(ratios[-1]),
        "predicted_min": 1.0 / (1.0 + sig**4 * LEVER**2 / (k * SIGMA_POSITION**2)),
        "mean_offset_mm": float(np.linalg.norm(err[:, :3].mean(axis=0)) * 1e3),
    }


@pytest.mark.parametrize("case", CASES)
def test_linearization_error_grows_with_rotation_sigma(case):
    rows = {s: measure(case, s, np.random.default_rng(SEED)) for s in SIGMAS_DEG}
    small, large = rows[1.0], rows[10.0]
    # 1 degree: within the bars of test_montecarlo.py
    assert small["frobenius"] <= 0.02
    assert 0.8 <= small["ratio_min"] and small["ratio_max"] <= 1.2
    # first order is a few percent low in the thinnest direction, as predicted at second order
    assert small["ratio_min"] < 0.97
    assert abs(small["ratio_min"] - small["predicted_min"]) < 0.02
    # 10 degrees: clearly worse in every figure, the thinnest direction almost entirely missed
    assert large["frobenius"] > small["frobenius"]
    assert large["ratio_min"] < small["ratio_min"]
    assert abs(large["ratio_max"] - 1.0) > abs(small["ratio_max"] - 1.0)
    assert large["ratio_min"] < 0.1
    assert abs(large["ratio_min"] / large["predicted_min"] - 1.0) < 0.3


def table() -> str:
    """The Markdown table of ``docs/linearization.md``."""
    lines = [
        "| case | rotation sigma | Frobenius rel. error | smallest ratio | largest ratio "
        "| predicted smallest | mean offset |",
        "|---|---|---|---|---|---|---|",
    ]
    for case in CASES:
        for s in SIGMAS_DEG:
            r = measure(case, s, np.random.default_rng(SEED))
            lines.append(
                f"| {case} | {s:g} deg | {100 * r['frobenius']:.2f} % | {r['ratio_min']:.4f} "
                f"| {r['ratio_max']:.4f} | {r['predicted_min']:.4f} "
                f"| {r['mean_offset_mm']:.3f} mm |"
            )
    return "\n".join(lines)


if __name__ == "__main__":
    print(table())
