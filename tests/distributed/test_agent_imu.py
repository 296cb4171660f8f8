"""An agent reads the setup's ``imus:`` as a single process does: the IMU recording is played
on the agent's clock and aids the filter of its body's own sensor (EuRoC V1_01: a 20 Hz
tracker and the 200 Hz IMU), so a push query at the IMU's rate is answered between the
tracker's poses, close to the truth."""

from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (pip install .[distributed])")

from _agents import endpoint, free_port, wait_for

from trackflow.dataflow import InertialKalmanFilter, load_setup
from trackflow.distributed import Agent, AgentConfig
from trackflow.evaluation import interpolate_poses
from trackflow.io import read_imu, read_stream, write_tum

pytestmark = pytest.mark.slow


@pytest.fixture
def euroc(shared_data, tmp_path):
    gt, _ = read_stream(shared_data / "euroc" / "V1_01_easy_groundtruth_200hz.txt")
    imu, _ = read_imu(shared_data / "euroc" / "V1_01_easy_imu0.csv")
    t0 = int(gt.t_ns[0]) + 30 * 10**9
    keep = (gt.t_ns >= t0) & (gt.t_ns < t0 + 6 * 10**9)
    write_tum(tmp_path / "vicon.txt", gt[np.flatnonzero(keep)[::10]])  # the tracker at 20 Hz
    ik = (imu.t_ns >= t0 - 10**8) & (imu.t_ns < t0 + 6 * 10**9)
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
    return tmp_path, gt, t0


def test_an_agent_plays_its_imu_and_answers_at_its_rate(euroc):
    folder, gt, t0 = euroc
    setup = load_setup(folder / "setup.yaml")
    lead_ns = 3 * 10**9  # the recording starts this long after the agent (warm-up)
    start_ns = time.time_ns() + lead_ns - t0  # recording time t0 plays then
    cfg = AgentConfig("imu_host", setup, realm=f"imu{free_port()}", start_ns=start_ns,
                      zenoh={"listen": {"endpoints": [endpoint(free_port())]}})  # fmt: skip
    with Agent(cfg) as agent:
        st = agent.queries["now"]

        def planned() -> bool:  # the plan fuses the IMU behind the body's own sensor
            with agent.sched.lock:
                return any(
                    isinstance(c, InertialKalmanFilter) for c in agent.net.components.values()
                )

        wait_for(planned, 30)
        agent.wait(timeout_s=lead_ns * 1e-9 + 60)
        done, status, last = agent.recordings_done(), agent.status(), st.last
    assert done, status
    assert last is not None, (status["queries"], status["missed_ticks"], status.get("error"),
                              status["skipped_samples"], agent.net.stats())  # fmt: skip
    published = status["queries"]["now"]["published"]
    # the IMU's rate from a 20 Hz tracker: 6 s at 200 Hz (a stalled agent skips ticks)
    assert published + status["missed_ticks"] > 0.9 * 6 * 200, status["queries"]["now"]
    t = (gt.t_ns - gt.t_ns[0]) * 1e-9
    tq = np.array([(last.t_ns - start_ns - gt.t_ns[0]) * 1e-9])
    tp, _ = interpolate_poses(t, gt.position, gt.quaternion, tq)
    assert np.linalg.norm(last.pose.position - tp[0]) < 0.02
