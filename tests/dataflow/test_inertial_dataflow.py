"""An IMU on a body frame in a setup: the planner fuses it behind the body's pose sensor."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.dataflow import InertialKalmanFilter, load_setup
from trackflow.evaluation import interpolate_poses
from trackflow.io import read_imu, read_stream, write_tum
from trackflow.math import quat_angle


@pytest.fixture
def euroc_setup(shared_data, tmp_path):
    gt, _ = read_stream(shared_data / "euroc" / "V1_01_easy_groundtruth_200hz.txt")
    imu, _ = read_imu(shared_data / "euroc" / "V1_01_easy_imu0.csv")
    t0 = int(gt.t_ns[0]) + 30 * 10**9  # 10 s of flight
    keep = (gt.t_ns >= t0) & (gt.t_ns < t0 + 10 * 10**9)
    sel = np.flatnonzero(keep)[::10]  # the tracker at 20 Hz
    write_tum(tmp_path / "vicon.txt", gt[sel])
    ik = (imu.t_ns >= t0 - 10**8) & (imu.t_ns < t0 + 10 * 10**9)
    rows = [f"{t},{g[0]!r},{g[1]!r},{g[2]!r},{a[0]!r},{a[1]!r},{a[2]!r}"
            for t, g, a in zip(imu.t_ns[ik].tolist(), imu.gyro[ik].tolist(),
                               imu.accel[ik].tolist())]  # fmt: skip
    (tmp_path / "imu0.csv").write_text("#timestamp [ns],wx,wy,wz,ax,ay,az\n" + "\n".join(rows))
    (tmp_path / "setup.yaml").write_text(
        """
sensors:
  - {name: vicon, source: world, target: body, rate_hz: 20, sigma_pos_mm: 1,
     sigma_ori_deg: 0.1, recording: vicon.txt}
imus:
  - {name: adis, body: body, recording: imu0.csv, mode: strapdown,
     noise: {gyro: 0.01, accel: 0.05, gyro_bias: 2.0e-5, accel_bias: 3.0e-3}}
queries:
  - {name: now, source: world, target: body, mode: push, rate_hz: 200}
"""
    )
    return tmp_path, gt, int(np.count_nonzero(ik))


def test_imu_gives_imu_rate_answers_close_to_the_truth(euroc_setup):
    folder, gt, n_imu = euroc_setup
    setup = load_setup(folder / "setup.yaml")
    plan = setup.plan("now")
    assert plan.count("imu source") == 1
    assert "IMU adis" in plan.explain()
    net, app = plan.build(setup.players())
    assert any(isinstance(c, InertialKalmanFilter) for c in net.components.values())
    net.run()
    out = app.arrays()
    # IMU-rate answers from a 20 Hz tracker: the filter answers between poses
    assert len(out["t_ns"]) > 0.9 * n_imu
    assert np.median(np.diff(out["t_ns"])) == 5_000_000
    t = (gt.t_ns - gt.t_ns[0]) * 1e-9
    tq = (out["t_ns"] - gt.t_ns[0]) * 1e-9
    tp, qq = interpolate_poses(t, gt.position, gt.quaternion, tq)
    late = tq > tq[0] + 2.0  # after the biases settled
    e_p = np.linalg.norm(out["position"][late] - tp[late], axis=1)
    e_q = np.degrees(quat_angle(out["quaternion"][late], qq[late]))
    assert np.sqrt(np.mean(e_p**2)) < 0.01 and np.sqrt(np.mean(e_q**2)) < 0.5


def test_setup_errors_name_the_imu(tmp_path):
    f = tmp_path / "bad.yaml"
    f.write_text(
        "sensors:\n  - {name: s, source: w, target: b}\nimus:\n  - {name: i, body: nowhere}\n"
    )
    with pytest.raises(ValueError, match="IMU i"):
        load_setup(f)
    f.write_text(
        "sensors:\n  - {name: s, source: w, target: b}\n"
        "imus:\n  - {name: i, body: b, colour: red}\n"
    )
    with pytest.raises(ValueError, match=r"bad.yaml:4: imus\[0\]: unknown keys \['colour'\]"):
        load_setup(f)
    f.write_text(
        "sensors:\n  - {name: s, source: w, target: b}\n"
        "imus:\n  - {name: i, body: b, mode: magic}\n"
    )
    with pytest.raises(ValueError, match="mode must be one of"):
        load_setup(f)
