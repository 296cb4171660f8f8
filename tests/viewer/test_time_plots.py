"""The NIS plot's chi-square band (``viewer.time_plots``): 95 % of the NIS of a consistent
pose filter lies in it (seeded Monte Carlo of 6-dof innovations with their covariance)."""

from __future__ import annotations

import numpy as np

from trackflow.viewer.time_plots import NIS_BAND, NIS_DOF, nis_data, nis_series


def test_the_band_holds_95_percent_of_a_consistent_filters_nis():
    rng = np.random.default_rng(11)
    n = 20_000
    # innovations with a random SPD covariance S, normalised by it as a filter does
    a = rng.normal(size=(NIS_DOF, NIS_DOF))
    S = a @ a.T + NIS_DOF * np.eye(NIS_DOF)
    nu = rng.multivariate_normal(np.zeros(NIS_DOF), S, size=n)
    nis = np.einsum("ni,ij,nj->n", nu, np.linalg.inv(S), nu)
    inside = np.mean((nis >= NIS_BAND[0]) & (nis <= NIS_BAND[1]))
    assert abs(inside - 0.95) < 0.006, inside
    assert np.mean(nis < NIS_BAND[0]) > 0.02 and np.mean(nis > NIS_BAND[1]) > 0.02


def test_the_plot_data_has_the_band_beside_the_curve():
    t = np.array([0.0, 0.1, 0.2])
    data = nis_data(t, np.array([1.0, np.nan, 30.0]))
    assert len(data) == len(nis_series()) == 4
    np.testing.assert_array_equal(data[1], [1.0, 0.0, 30.0])  # no update drawn at 0
    assert np.all(data[2] == NIS_BAND[0]) and np.all(data[3] == NIS_BAND[1])
    assert NIS_BAND[0] < NIS_DOF < NIS_BAND[1]
