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


def test_the_prediction_error_plot_compares_a_prediction_with_the_recording_later():
    from trackflow.io import PoseStream
    from trackflow.math import quat_exp
    from trackflow.viewer import RecordingTrack

    t = np.arange(0.0, 4.0, 0.01)
    pos = np.stack([0.4 * np.cos(t), 0.4 * np.sin(t), 1.0 + 0 * t], axis=1)
    pos += np.random.default_rng(3).normal(0.0, 0.0005, pos.shape)
    q = quat_exp(np.stack([0 * t, 0 * t, t], axis=1))
    track = RecordingTrack.from_stream(
        PoseStream("world", "body", np.round(t * 1e9).astype(np.int64), pos, q)
    )
    ts, err, sigma = track.prediction_errors(0.1)
    assert ts[-1] <= track.t[-1] - 0.1 + 1e-9 and len(ts) == len(err) == len(sigma)
    pred = track.predicted(0.1)
    k = 200  # sample k predicted 0.1 s ahead: the recording 10 samples later (0.01 s apart)
    want = np.linalg.norm(np.asarray(pred.position)[k] - pos[k + 10]) * 1e3
    assert abs(err[k] - want) < 1e-6 * max(want, 1.0), (err[k], want)
    cov = np.asarray(pred.covariance)[k, :3, :3]
    assert abs(sigma[k] - np.sqrt(np.trace(cov)) * 1e3) < 1e-9
    # an honest filter's predicted RMS error is the size of the errors it makes
    ratio = np.sqrt(np.mean(err[50:] ** 2)) / np.sqrt(np.mean(sigma[50:] ** 2))
    assert 0.2 < ratio < 5.0, ratio
