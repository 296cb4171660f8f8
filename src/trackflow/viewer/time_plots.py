"""What the views' time plots share: the NIS plot with the chi-square band a consistent filter's
NIS stays in.

The NIS (normalised innovation squared) of a pose update is chi-square with 6 degrees of
freedom when the declared noise and motion model fit what the sensor delivers; 95 % of the
updates then lie between :data:`NIS_BAND` ``[0]`` and ``[1]`` (the 2.5 % and 97.5 % points).
A curve mostly above the band says the sensor is noisier or moves harder than declared; mostly
below, that the declared noise or motion is larger than needed.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

__all__ = ["NIS_BAND", "NIS_DOF", "nis_data", "nis_series"]

#: degrees of freedom of a pose update's NIS (position and orientation)
NIS_DOF = 6
#: the central 95 % of chi-square with :data:`NIS_DOF` degrees of freedom
NIS_BAND = (float(chi2.ppf(0.025, NIS_DOF)), float(chi2.ppf(0.975, NIS_DOF)))


def nis_series(stroke: str = "#333") -> tuple[dict, ...]:
    """The uPlot series of :func:`nis_data`: time, the NIS, the band's two edges (dashed)."""
    lo, hi = NIS_BAND
    band = {"stroke": "#2a2", "dash": [6, 4], "width": 1}
    return (
        {"label": "t [s]"},
        {"label": "NIS", "stroke": stroke},
        {"label": f"chi2(6) 2.5 % ({lo:.2f})", **band},
        {"label": f"chi2(6) 97.5 % ({hi:.2f})", **band},
    )


def nis_data(t_s: np.ndarray, nis: np.ndarray) -> tuple[np.ndarray, ...]:
    """The NIS plot's data: ``t_s`` (N,) [s], the NIS (N,) (NaN drawn as 0: no update) and
    the band's edges as constant series."""
    t_s = np.asarray(t_s, float)
    ones = np.ones_like(t_s)
    return (t_s, np.nan_to_num(np.asarray(nis, float)), NIS_BAND[0] * ones, NIS_BAND[1] * ones)
