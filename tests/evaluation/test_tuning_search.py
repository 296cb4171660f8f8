"""The tuning's search: a coarse grid, then local refinement from the best basins."""

from __future__ import annotations

import numpy as np

from trackflow.evaluation._search import grid_then_powell


def _two_basins(z):
    """A wide shallow basin at (-3.5, 0.5), a narrow deep ridge along b - a = 3 near a = -0.5.

    The narrow basin lies between grid points, so its best grid value is worse than the wide
    basin's: a search refining only the best grid point ends in the wrong basin.
    """
    a, b = float(z[0]), float(z[1])
    wide = 0.6 - 0.12 * np.exp(-((a + 3.5) ** 2 + (b - 0.5) ** 2) / 2.0)
    narrow = 0.45 * np.exp(-(((b - a - 3.0) / 0.35) ** 2) - ((a + 0.5) / 0.8) ** 2)
    return wide - narrow


def test_refines_the_best_basins_not_only_the_best_grid_point():
    grid = [(a, b) for a in (-5.0, -3.5, -2.0, -0.5, 1.0) for b in (-1.0, 0.5, 2.0, 3.5)]
    vals = [_two_basins(g) for g in grid]
    best_grid = grid[int(np.argmin(vals))]
    assert best_grid == (-3.5, 0.5)  # the grid's best point is in the wide basin
    x = grid_then_powell(_two_basins, grid, {"xtol": 0.01, "ftol": 1e-6, "maxfev": 200})
    assert abs(x[1] - x[0] - 3.0) < 0.1
    assert _two_basins(x) < _two_basins(best_grid) - 0.3


def test_never_returns_worse_than_the_best_grid_point():
    def flat_then_cliff(z):  # Powell cannot improve on a plateau
        return 1.0 if z[0] < 0.7 else 0.5

    grid = [(a,) for a in (-1.0, 0.0, 1.0)]
    x = grid_then_powell(flat_then_cliff, grid, {"maxfev": 20})
    assert flat_then_cliff(x) == 0.5
