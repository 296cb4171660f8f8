"""The evaluation's learned motion model (``trackflow.filters.twist_ar``) and its selection.

Checked here:

* ``predict_kalman`` dispatches per part: a :class:`PartwisePredictor` takes its positions
  from its position filter and its quaternions from its orientation filter, exactly, in both
  arrangements of a derivative-model and a learned filter; horizon 0 gives the filtered poses;
  anything else raises ``ValueError``;
* on increments that follow a known stable VAR(2) with strong coupling of body-x translation
  into yaw (a hand-held orbit), ``tune_model`` picks the learned model for both parts and it
  beats linear extrapolation and the derivative-only tuning on the held-back half; on smooth
  constant-acceleration motion with white measurement noise (where the derivative model is
  right) allowing learned models never makes the scored half worse;
* the persistent-excitation guard: ``"full ..."`` candidates only when the tuning data moves
  along every body axis (``min(excitation_ratios) >= 0.25``);
* ``ar_orders=()`` is exactly the derivative-only tuning, invalid orders raise;
* the report's ``motion_model`` names the learned and the partwise choice and is JSON;
* on a real smoothed hand-held recording (shared data, skipped when absent) the tuned filter
  beats linear extrapolation clearly.

Synthetic recordings are integrated here with ``scipy.spatial.transform.Rotation``,
independently of the library.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from trackflow.evaluation import (
    KalmanPredictor,
    PartwisePredictor,
    Trajectory,
    TwistARPredictor,
    default_predictor,
    evaluate_predictors,
    evaluate_recording,
    predict_kalman,
    tune_model,
)
from trackflow.filters import MotionModel
from trackflow.filters.twist_ar import TwistARModel, excitation_ratios, run_twist_ar

DT = 0.01  # 100 Hz
SCORED = (0.05, 0.1)  # horizons [s] compared on the scored half


# -- synthetic recordings -------------------------------------------------------------------------


def _integrate(xi: np.ndarray, q0) -> tuple[np.ndarray, np.ndarray]:
    """Poses from increments: ``t_k = t_{k-1} + R_{k-1} u_k``, ``R_k = R_{k-1} Exp(w_k)``.

    Returns positions (N + 1, 3) and sign-continuous quaternions (N + 1, 4), starting at the
    origin with orientation ``q0``.
    """
    n = xi.shape[0] + 1
    rots = [Rotation.from_quat(q0)]
    steps = Rotation.from_rotvec(xi[:, 3:])
    p = np.zeros((n, 3))
    for k in range(1, n):
        p[k] = p[k - 1] + rots[-1].apply(xi[k - 1, :3])
        rots.append(rots[-1] * steps[k - 1])
    return p, Rotation.concatenate(rots).as_quat()


def _measure(p, q, rng, pos_noise: float, ori_noise: float):
    """Times and noisy measurements: ``t + dt`` and ``R Exp(dtheta)``, white, isotropic."""
    n = p.shape[0]
    pm = p + pos_noise * rng.standard_normal(p.shape)
    rot = Rotation.from_quat(q) * Rotation.from_rotvec(ori_noise * rng.standard_normal((n, 3)))
    qm = rot.as_quat()
    flips = np.cumprod(np.r_[1.0, np.sign(np.sum(qm[1:] * qm[:-1], axis=1))])
    return DT * np.arange(n), pm, qm * flips[:, None]


def _companion_radius(a0: np.ndarray, a1: np.ndarray) -> float:
    comp = np.zeros((12, 12))
    comp[:6, :6], comp[:6, 6:], comp[6:, :6] = a0, a1, np.eye(6)
    return float(np.max(np.abs(np.linalg.eigvals(comp))))


def orbit_increments(rng, seconds: float, coupling: float = 0.3, scale=(5e-3,) * 6):
    """Increments ``xi = (u, w)`` from a stable VAR(2) with translation-rotation coupling.

    Every component is a lightly damped oscillator (pole radius 0.985, 1.2-1.8 Hz) driven by
    white noise; the yaw increment ``w_z`` is also driven by the body-x increment ``u_x``
    (``+c u_x[k] - 0.9 c u_x[k-1]``), like a hand circling an object while walking around it.
    The coupling is one-way, so the companion eigenvalues are the oscillators' (stable).
    Each component is finally scaled to standard deviation ``scale`` (a diagonal similarity,
    still a VAR(2)): 5 mm and 5 mrad per 10 ms step, about 0.5 m/s and 29 deg/s.
    """
    n = int(round(seconds / DT))
    theta = 2.0 * np.pi * np.array([1.2, 1.6, 1.4, 1.8, 1.3, 1.5]) * DT
    r = 0.985
    a0 = np.diag(2.0 * r * np.cos(theta))
    a1 = -(r**2) * np.eye(6)
    a0[5, 0], a1[5, 0] = coupling, -0.9 * coupling
    assert _companion_radius(a0, a1) < 0.99
    burn = 500
    noise = rng.standard_normal((n + burn, 6))
    xi = np.zeros((n + burn, 6))
    for k in range(2, n + burn):
        xi[k] = a0 @ xi[k - 1] + a1 @ xi[k - 2] + noise[k]
    xi = xi[burn:]
    return xi * (np.asarray(scale, dtype=float) / xi.std(axis=0))


def orbit_recording(rng, seconds: float, **kwargs):
    xi = orbit_increments(rng, seconds, **kwargs)
    p, q = _integrate(xi, Rotation.random(random_state=rng).as_quat())
    return _measure(p, q, rng, 1e-5, 1e-5)  # tiny measurement noise


def polynomial_recording(rng, seconds: float, pos_noise: float, ori_noise: float):
    """Constant acceleration (position) and constant angular acceleration about a fixed axis."""
    t = DT * np.arange(int(round(seconds / DT)) + 1)
    v0, acc = 0.2 * rng.standard_normal(3), 0.03 * rng.standard_normal(3)
    p = v0 * t[:, None] + 0.5 * acc * t[:, None] ** 2
    axis = rng.standard_normal(3)
    angle = 0.3 * t + 0.5 * 0.02 * t**2  # rad: 17 deg/s, +1.1 deg/s per second
    rot = Rotation.random(random_state=rng) * Rotation.from_rotvec(
        angle[:, None] * axis / np.linalg.norm(axis)
    )
    return _measure(p, rot.as_quat(), rng, pos_noise, ori_noise)


def _parts(predictor):
    """``(position filter, orientation filter)`` of any evaluation predictor."""
    if isinstance(predictor, PartwisePredictor):
        return predictor.position, predictor.orientation
    return predictor, predictor


def _tune_half(t, p, q, ar_orders, **kwargs):
    """``evaluate_recording(tune_fraction=0.5)`` with a chosen ``ar_orders``: tune, then score."""
    rec = Trajectory.check(t, p, q)
    split = float(t[0] + 0.5 * (t[-1] - t[0]))
    train = t <= split
    res = tune_model(rec.select(train), ar_orders=ar_orders, **kwargs)
    return res, evaluate_predictors(rec, res.predictor, SCORED, split)


def _rms(report, h_ms: int) -> np.ndarray:
    """Kalman ``(position [mm], orientation [deg])`` RMS at one horizon."""
    s = report.stats["kalman"][h_ms]
    return np.array([s.pos_rms_mm, s.ori_rms_deg])


# -- shared (module-level) runs: the tunings are the expensive part -------------------------------


@pytest.fixture(scope="module")
def orbit():
    return orbit_recording(np.random.default_rng(11), 60.0)


@pytest.fixture(scope="module")
def orbit_report(orbit):
    return evaluate_recording(
        Trajectory.check(*orbit), horizons=(0.01, 0.05, 0.1), tune_fraction=0.5
    )


@pytest.fixture(scope="module")
def orbit_derivative_only(orbit):
    return _tune_half(*orbit, ar_orders=())


@pytest.fixture(scope="module")
def polynomial_runs():
    rec = polynomial_recording(np.random.default_rng(5), 20.0, 3e-4, 2e-3)
    return rec, {orders: _tune_half(*rec, ar_orders=orders) for orders in ((3,), ())}


# -- 1. dispatch ----------------------------------------------------------------------------------


@pytest.fixture
def two_filters(rng):
    t, p, q = orbit_recording(rng, 8.0)
    kalman = default_predictor(t, p, q)
    learned = TwistARPredictor(TwistARModel.fit(t, p, q, 3), 1e-5, 1e-5)
    return (t, p, q), kalman, learned


@pytest.mark.parametrize("arrangement", ["kalman_position", "learned_position"])
def test_partwise_takes_each_part_from_its_own_filter(two_filters, arrangement):
    (t, p, q), kalman, learned = two_filters
    a, b = (kalman, learned) if arrangement == "kalman_position" else (learned, kalman)
    h = (0.0, 0.03, 0.1)
    pa, qa, _ = predict_kalman(Trajectory.check(t, p, q), a, h)
    pb, qb, _ = predict_kalman(Trajectory.check(t, p, q), b, h)
    pp, pq, n_gated = predict_kalman(
        Trajectory.check(t, p, q), PartwisePredictor(position=a, orientation=b), h
    )
    assert pp.shape == (3, t.size, 3) and pq.shape == (3, t.size, 4)
    np.testing.assert_array_equal(pp, pa)
    np.testing.assert_array_equal(pq, qb)
    assert n_gated == 0  # default_predictor has no gate; the learned filter never gates
    # the two filters really differ, so taking a part from the wrong one would be seen
    assert np.max(np.abs(pa[2] - pb[2])) > 1e-4
    assert np.max(np.abs(qa[2] - qb[2])) > 1e-4


def test_horizon_zero_gives_the_filtered_poses(two_filters):
    (t, p, q), kalman, learned = two_filters
    pk, qk, _ = predict_kalman(Trajectory.check(t, p, q), kalman, (0.0,))
    ref = kalman.run(t, kalman.measurements(p, q), ())
    np.testing.assert_allclose(pk[0], ref.filtered.position, rtol=0, atol=1e-12)
    np.testing.assert_allclose(qk[0], ref.filtered.quaternion, rtol=0, atol=1e-12)
    pl, ql, _ = predict_kalman(Trajectory.check(t, p, q), learned, (0.0,))
    ref = run_twist_ar(t, p, q, learned.model, learned.pos_sigma, learned.ori_sigma)
    np.testing.assert_allclose(pl[0], ref.position, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ql[0], ref.quaternion, rtol=0, atol=1e-12)
    # filtered, not the raw measurements (the filters smooth), yet close to them
    assert 0 < np.max(np.abs(pl[0] - p)) < 1e-3


def test_anything_else_is_not_a_predictor(two_filters):
    (t, p, q), kalman, learned = two_filters
    for bad in (kalman.model, learned.model, None, "kalman"):
        with pytest.raises(ValueError, match="not a predictor"):
            predict_kalman(Trajectory.check(t, p, q), bad, (0.05,))
    with pytest.raises(ValueError, match="orientation"):
        PartwisePredictor(position=kalman, orientation=learned.model)
    with pytest.raises(ValueError, match="position"):
        PartwisePredictor(position=PartwisePredictor(kalman, learned), orientation=kalman)
    with pytest.raises(ValueError, match="TwistARModel"):
        TwistARPredictor(MotionModel(2, 1, noise=(0.0, 0.0, 1.0, 0.0, 1.0)), 1e-3, 1e-3)
    with pytest.raises(ValueError, match="pos_sigma"):
        TwistARPredictor(learned.model, 0.0, 1e-3)


# -- 2. the selection -----------------------------------------------------------------------------


def test_the_generated_increments_are_coupled_and_excite_every_axis(orbit):
    """The synthetic recording has the properties the selection tests rely on."""
    t, p, q = orbit
    r = Rotation.from_quat(q)
    u = (r[:-1].inv()).apply(p[1:] - p[:-1])
    w = (r[:-1].inv() * r[1:]).as_rotvec()
    assert abs(np.corrcoef(u[:, 0], w[:, 2])[0, 1]) > 0.5  # body-x speed drives yaw
    assert min(excitation_ratios(t, p, q)) > 0.5


def test_learned_model_is_chosen_on_a_coupled_autoregression(orbit_report, orbit_derivative_only):
    rep = orbit_report
    pos, ori = _parts(rep.predictor)
    assert isinstance(pos, TwistARPredictor), type(pos).__name__
    assert isinstance(ori, TwistARPredictor), type(ori).__name__
    assert type(rep.predictor) in (TwistARPredictor, PartwisePredictor)
    k, lin = rep.stats["kalman"][100], rep.stats["linear"][100]
    assert k.pos_rms_mm < 0.7 * lin.pos_rms_mm, (k.pos_rms_mm, lin.pos_rms_mm)
    assert k.ori_rms_deg < 0.7 * lin.ori_rms_deg, (k.ori_rms_deg, lin.ori_rms_deg)
    # and clearly better than the best derivative model on the same scored half
    _, deriv = orbit_derivative_only
    assert isinstance(deriv.predictor, KalmanPredictor)
    for h in (50, 100):
        assert np.all(_rms(rep, h) < 0.9 * _rms(deriv, h)), (h, _rms(rep, h), _rms(deriv, h))
    # the coupling (and the per-axis frequencies) show in the validation: a full model
    # predicts the orientation better than every isotropic one (by 1-8 % over seeds 1-5, 11)
    ar = rep.tuning["candidates"]["twist_ar"]
    best = {s: min(v["orientation"]["cv_cost"] for k_, v in ar.items()
                   if k_.startswith(s + " ") and "orientation" in v)
            for s in ("full", "isotropic")}  # fmt: skip
    assert best["full"] < best["isotropic"], best


def test_allowing_learned_models_never_loses_on_smooth_polynomial_motion(polynomial_runs):
    _, runs = polynomial_runs
    (res_ar, rep_ar), (_, rep_d) = runs[(3,)], runs[()]
    assert "twist_ar" in res_ar.candidates  # the learned models were tried ...
    for h in (50, 100):
        ar, der = _rms(rep_ar, h), _rms(rep_d, h)
        assert np.all(ar <= 1.02 * der), (h, ar, der)
        # ... and the derivative model is the right one here: far ahead of extrapolation
        lin = rep_d.stats["linear"][h]
        assert _rms(rep_d, h)[0] < 0.3 * lin.pos_rms_mm
        assert _rms(rep_d, h)[1] < 0.3 * lin.ori_rms_deg


# -- 3. persistent excitation ---------------------------------------------------------------------


def _spread_ratio(increments: np.ndarray) -> float:
    """``sqrt(smallest / largest eigenvalue)`` of the sample covariance of (M, 3) increments."""
    ev = np.linalg.eigvalsh(np.cov(increments.T))
    return float(np.sqrt(max(ev[0], 0.0) / ev[-1]))


@pytest.mark.parametrize(
    ("translation_spread", "rotation_spread", "full_tried"),
    [
        (0.0, 0.0, False),  # one body axis each: body-x speed, yaw rate
        (0.0, 1.0, False),  # translation along one axis, rotation about all
        (1.0, 0.0, False),
        (0.1, 1.0, False),  # the other translation axes at 10 % of the main one
        (0.7, 1.0, True),
        (1.0, 1.0, True),  # evenly moving: random 3D motion
    ],
)
def test_full_coupling_only_with_persistent_excitation(
    rng, translation_spread, rotation_spread, full_tried
):
    ts, rs = translation_spread, rotation_spread
    # a zero spread: no motion at all along that body axis (body x and body z always move)
    t, p, q = orbit_recording(rng, 15.0, scale=5e-3 * np.array([1.0, ts, ts, rs, rs, 1.0]))
    ratios = excitation_ratios(t, p, q)
    # the definition, on increments computed here (all sample intervals are regular)
    r = Rotation.from_quat(q)
    u = r[:-1].inv().apply(p[1:] - p[:-1])
    w = (r[:-1].inv() * r[1:]).as_rotvec()
    np.testing.assert_allclose(ratios, [_spread_ratio(u), _spread_ratio(w)], rtol=1e-6)
    for spread, ratio in zip((ts, rs), ratios):
        if spread == 0.0:
            assert ratio < 0.01  # only the 10 um / 10 urad measurement noise
        else:  # independent axes: about the relative spread (15 s of lightly damped motion)
            assert 0.5 * spread < ratio < min(1.5 * spread, 1.0)
    res = tune_model(Trajectory.check(t, p, q), pos_derivatives=(2,), ori_derivatives=(1,),
                     max_evaluations=4, ar_orders=(3,))  # fmt: skip
    ar = res.candidates["twist_ar"]
    assert ar["excitation"] == {"translation": ratios[0], "rotation": ratios[1]}
    assert (min(ratios) >= 0.25) == full_tried
    # entries are named "<structure> <order>" (plus details of the setting after a space)
    tried = {tuple(k.split()[:2]) for k in ar if k != "excitation"}
    assert tried == ({("full", "3"), ("isotropic", "3")} if full_tried else {("isotropic", "3")})
    for entry in ar.values():
        assert "skipped" not in entry


# -- 4. switching the learned models off ----------------------------------------------------------


def test_no_orders_is_exactly_the_derivative_only_tuning(orbit_report, orbit_derivative_only,
                                                        polynomial_runs):  # fmt: skip
    res_d, _ = orbit_derivative_only
    assert type(res_d.predictor) is KalmanPredictor
    assert "twist_ar" not in res_d.candidates
    # the derivative-model search is the same with and without the learned models
    cands = orbit_report.tuning["candidates"]
    for part in ("position", "orientation"):
        assert cands[part] == res_d.candidates[part]
    # where the derivative model wins both parts, the result is identical
    _, runs = polynomial_runs
    (res_ar, rep_ar), (res_d, rep_d) = runs[(3,)], runs[()]
    assert type(res_ar.predictor) is KalmanPredictor
    assert res_ar.predictor.as_dict() == res_d.predictor.as_dict()
    assert (res_ar.cost_position, res_ar.cost_orientation) == (
        res_d.cost_position,
        res_d.cost_orientation,
    )
    for h in (50, 100):
        np.testing.assert_array_equal(_rms(rep_ar, h), _rms(rep_d, h))


@pytest.mark.parametrize("orders", [(0,), (-1,), (3, 0), (2.5,), "3", (True,)])
def test_invalid_orders_raise(rng, orders):
    t, p, q = orbit_recording(rng, 3.0)
    with pytest.raises(ValueError, match="ar_orders"):
        tune_model(Trajectory.check(t, p, q), ar_orders=orders)


@pytest.mark.parametrize("check", [(-0.01,), (0.0,), (float("nan"),)])
def test_invalid_check_horizons_raise(rng, check):
    t, p, q = orbit_recording(rng, 3.0)
    with pytest.raises(ValueError, match="check_horizons"):
        tune_model(Trajectory.check(t, p, q), check_horizons=check)


def test_every_learned_candidate_records_the_never_worse_check(orbit_report):
    cands = orbit_report.tuning["candidates"]["twist_ar"]
    scored = [v for k, v in cands.items() if k != "excitation" and "skipped" not in v]
    assert scored
    for v in scored:
        for part in ("position", "orientation"):
            assert isinstance(v[part]["worse_than_none_in_blocks"], list)
            assert set(v[part]["worse_than_none_in_blocks"]) <= {1, 2}


def test_a_learned_start_point_is_refused_by_name(two_filters):
    (t, p, q), kalman, learned = two_filters
    for bad in (learned, PartwisePredictor(kalman, learned)):
        with pytest.raises(ValueError, match="start must be a KalmanPredictor"):
            tune_model(Trajectory.check(t, p, q), start=bad)


def test_no_horizons_give_empty_arrays_of_the_documented_shape(two_filters):
    (t, p, q), kalman, learned = two_filters
    for pred in (kalman, learned, PartwisePredictor(kalman, learned)):
        pp, pq, _ = predict_kalman(Trajectory.check(t, p, q), pred, ())
        assert pp.shape == (0, t.size, 3) and pq.shape == (0, t.size, 4)


# -- 5. the report --------------------------------------------------------------------------------


def test_report_names_the_learned_and_the_partwise_model(two_filters, orbit_report):
    (t, p, q), kalman, learned = two_filters
    cases = {
        "twist_ar": learned,
        "partwise": PartwisePredictor(position=learned, orientation=kalman),
    }
    for kind, predictor in cases.items():
        d = evaluate_predictors(Trajectory.check(t, p, q), predictor, (0.02, 0.05)).as_dict()
        back = json.loads(json.dumps(d))
        assert back["motion_model"]["kind"] == kind
        assert back["motion_model"] == d["motion_model"]
    mm = cases["partwise"].as_dict()
    assert mm["position"]["kind"] == "twist_ar" and mm["position"]["order"] == 3
    assert mm["orientation"] == kalman.as_dict()
    # the tuned report of the coupled recording, with its whole tuning summary
    d = json.loads(json.dumps(orbit_report.as_dict()))
    expected = "twist_ar" if isinstance(orbit_report.predictor, TwistARPredictor) else "partwise"
    assert d["motion_model"]["kind"] == expected
    ar = d["tuning"]["candidates"]["twist_ar"]
    assert set(ar["excitation"]) == {"translation", "rotation"}
    assert {tuple(k.split()[:2]) for k in ar if k != "excitation"} >= {
        ("full", "3"),
        ("isotropic", "3"),
    }


# -- 6. a real recording --------------------------------------------------------------------------


def test_real_hand_held_recording(shared_data):
    """ar_table 01 (smoothed hand-held motion, 100 Hz), first 60 s: tune on 30 s, score 30 s.

    The recording starts with 4 s at rest, and the learned models are validated forward in
    time on thirds of the tuning data, so the first third must hold enough motion: with the
    first 40 s (13 s thirds) the tuning keeps the derivative model and orientation at 50 ms is
    0.96 x linear extrapolation (position 0.51); with 50 s an isotropic learned model is
    chosen (orientation 0.78 / 0.90 x at 50 / 100 ms), with 60 s full ones. Measured on 60 s at
    50 / 100 ms: position 0.29 / 0.38 x linear, orientation 0.43 / 0.57 x (whole file:
    0.32 / 0.42 and 0.45 / 0.59).
    """
    from trackflow.io import read_stream

    stream, _ = read_stream(shared_data / "ar_table" / "table_01.txt", clean=True)
    t = np.asarray(stream.times_s)
    keep = t <= t[0] + 60.0
    rep = evaluate_recording(
        Trajectory.check(t[keep], np.asarray(stream.position)[keep],
                         np.asarray(stream.quaternion)[keep]),
        horizons=(0.01, 0.02, 0.05, 0.1, 0.2), tune_fraction=0.5,
    )  # fmt: skip
    k, lin, none = (rep.stats[name] for name in ("kalman", "linear", "none"))
    for h in (50, 100):
        assert k[h].pos_rms_mm <= 0.7 * lin[h].pos_rms_mm, (h, k[h].pos_rms_mm, lin[h].pos_rms_mm)
        assert k[h].ori_rms_deg <= 0.95 * lin[h].ori_rms_deg, (h, k[h].ori_rms_deg)
    for h in rep.horizons_ms:
        assert k[h].pos_rms_mm <= none[h].pos_rms_mm and k[h].ori_rms_deg <= none[h].ori_rms_deg
        assert k[h].n > 1000


def test_a_part_whose_learned_candidates_are_all_rejected_keeps_its_derivative_model(
    orbit, monkeypatch
):
    """Fault injection: every learned orientation prediction is turned by 20 degrees, so each
    learned candidate is worse than holding the last sample for orientation (and rejected
    there) while position keeps a learned model; the measurement-noise refinement of the
    position's best candidate must not trip over the part that has none."""
    original = TwistARPredictor.predict
    turn = Rotation.from_rotvec([0.0, 0.0, np.deg2rad(20.0)])

    def turned(self, *args, **kwargs):
        out = original(self, *args, **kwargs)
        q = [(Rotation.from_quat(pq) * turn).as_quat() for pq in out.quaternion]
        return out._replace(quaternion=np.stack(q))

    monkeypatch.setattr(TwistARPredictor, "predict", turned)
    t, p, q = orbit
    half = t <= t[0] + 0.5 * (t[-1] - t[0])
    res = tune_model(Trajectory.check(t[half], p[half], q[half]), ar_orders=(3,))
    pos, ori = _parts(res.predictor)
    assert isinstance(ori, KalmanPredictor) and isinstance(pos, TwistARPredictor)
    scored = [v for k, v in res.candidates["twist_ar"].items()
              if k != "excitation" and "skipped" not in v]  # fmt: skip
    assert scored and all(v["orientation"]["worse_than_none_in_blocks"] for v in scored)
    assert any(not v["position"]["worse_than_none_in_blocks"] for v in scored)
