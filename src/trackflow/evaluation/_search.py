"""The tuning's numerical search: a coarse grid in log10 parameters, then bounded Powell
from its best basins; and the one-line progress bar the searches draw."""

from __future__ import annotations

import time
from typing import TextIO

import numpy as np

__all__ = ["BOUNDS", "Progress", "grid", "grid_then_powell", "huber", "refine"]

BOUNDS = (-9.0, 6.0)  # log10 of the white-noise densities


def huber(e: np.ndarray, c: float) -> np.ndarray:
    """Huber loss of errors ``e`` (any shape) with threshold ``c``: quadratic below, linear
    above."""
    return np.where(e <= c, 0.5 * e * e, c * (e - 0.5 * c))


class Progress:
    """A one-line progress bar on a text stream (stderr in the CLI)."""

    def __init__(self, stream: TextIO | None, total: int, width: int = 30):
        self.stream, self.total, self.width, self.n = stream, total, width, 0
        self.label, self.best, self._last = "", float("inf"), 0.0

    def start(self, label: str) -> None:
        self.label, self.best = label, float("inf")

    def step(self, cost: float) -> None:
        self.n += 1
        self.best = min(self.best, cost)
        now = time.perf_counter()
        if self.stream is None or now - self._last < 0.2:
            return
        self._last = now
        done = min(self.n, self.total) * self.width // self.total
        self.stream.write(
            f"\rtuning {self.label:<22} [{'#' * done}{'.' * (self.width - done)}] "
            f"{self.n:4d} evals, best cost {self.best:.4f}"
        )
        self.stream.flush()

    def close(self) -> None:
        if self.stream is not None:
            self.stream.write("\n")
            self.stream.flush()


def grid(cost, starts) -> tuple[np.ndarray, np.ndarray]:
    """``cost`` at every grid point: ``(points (G, D), values (G,))``."""
    pts = np.array([np.asarray(s, dtype=float) for s in starts])
    return pts, np.array([cost(s) for s in pts])


def refine(cost, pts, values, options, n_starts: int = 2) -> np.ndarray:
    """Powell from the best basins of a grid (see :func:`grid_then_powell`)."""
    from scipy.optimize import minimize  # ~0.4 s: only when searching

    step = np.array([np.min(np.diff(np.unique(c))) if np.unique(c).size > 1 else 1.0
                     for c in pts.T])  # fmt: skip
    near = np.all(np.abs(pts[:, None, :] - pts[None, :, :]) <= 1.5 * step, axis=2)
    local = [i for i in range(len(values)) if values[i] <= values[near[i]].min()]
    chosen = sorted(local, key=lambda i: values[i])[:n_starts]
    best_x, best_f = pts[chosen[0]], float(values[chosen[0]])
    for i in chosen:
        # local: Powell's bounded line searches span the whole box, so the box is the basin
        lo = np.maximum(pts[i] - 1.5 * step, BOUNDS[0])
        hi = np.minimum(pts[i] + 1.5 * step, BOUNDS[1])
        res = minimize(cost, pts[i], method="Powell", bounds=list(zip(lo, hi)),
                       options=options)  # fmt: skip
        if float(res.fun) < best_f:
            best_x, best_f = np.asarray(res.x, dtype=float), float(res.fun)
    return best_x


def grid_then_powell(cost, starts, options, n_starts: int = 2) -> np.ndarray:
    """Minimise ``cost`` over log10 parameters: a coarse grid, then Powell from its best basins.

    The cost has long flat plateaus and several narrow ridges in these coordinates, so one
    local search lands in whichever optimum is nearest its start. The grid points that are
    local minima of the grid (no lower value among their neighbours, 1 grid step away in every
    coordinate) each stand for one basin; Powell refines the ``n_starts`` best of them, each
    inside the box of +-1.5 grid steps around it (scipy's bounded line searches range over
    the whole box, so wider bounds would let a refinement jump into another basin), and the
    lowest result wins (never worse than the best grid point).
    """
    pts, values = grid(cost, starts)
    return refine(cost, pts, values, options, n_starts)
