"""IMU readers: EuRoC IMU csv and BROAD .mat (golden rows, round trips, bad input, real files)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.io import savemat

from trackflow.io import ImuStream, read_broad_imu, read_euroc_imu, read_imu

HEADER = (
    "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
    "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n"
)
ROWS = (
    "1403715273262142976,-0.0020943951023931952,0.017453292519943295,0.07749261878854824,"
    "9.0874956666666655,0.13075533333333333,-3.6938381666666662\n"
    "1403715273267142912,-0.0013962634015954637,0.019547687622336492,0.07819075048934597,"
    "9.0793234583333327,0.122583125,-3.6938381666666662\n"
)


def test_euroc_imu_golden_rows(tmp_path):
    f = tmp_path / "imu0.csv"
    f.write_text(HEADER + ROWS)
    s, rep = read_euroc_imu(f)
    assert s.t_ns.tolist() == [1403715273262142976, 1403715273267142912]
    assert s.gyro[0].tolist() == [-0.0020943951023931952, 0.017453292519943295, 0.07749261878854824]
    assert s.accel[1].tolist() == [9.0793234583333327, 0.122583125, -3.6938381666666662]
    assert s.mag is None and s.frame == "imu"
    assert rep.rows_read == rep.rows_kept == 2
    assert read_imu(f)[0].t_ns.tolist() == s.t_ns.tolist()


def test_euroc_imu_bad_rows_name_the_line(tmp_path):
    f = tmp_path / "imu0.csv"
    f.write_text(HEADER + ROWS + "1403715273272143104,1,2,x,4,5,6\n")
    with pytest.raises(ValueError, match=r"imu0.csv:4: unparsable"):
        read_euroc_imu(f)
    s, rep = read_euroc_imu(f, clean=True)
    assert len(s) == 2 and rep.dropped == {"unparsable value": [4]}
    f.write_text(HEADER + ROWS + "1403715273262142976,1,2,3,4,5,6\n")
    with pytest.raises(ValueError, match=r":4: time not increasing"):
        read_euroc_imu(f)
    f.write_text(HEADER + ROWS + "1403715273272143104,1,2,nan,4,5,6\n")
    with pytest.raises(ValueError, match=r":4: non-finite IMU value"):
        read_euroc_imu(f)


@given(
    n=st.integers(2, 30),
    seed=st.integers(0, 2**31 - 1),
    mag=st.booleans(),
)
@settings(max_examples=25, deadline=None)
def test_broad_imu_round_trip(tmp_path_factory, n, seed, mag):
    rng = np.random.default_rng(seed)
    data = {"imu_gyr": rng.normal(size=(n, 3)), "imu_acc": rng.normal(size=(n, 3))}
    if mag:
        data["imu_mag"] = rng.normal(size=(n, 3)) * 40
    f = tmp_path_factory.mktemp("broad") / "trial.mat"
    savemat(f, data)
    s, rep = read_broad_imu(f, rate_hz=100.0)
    np.testing.assert_array_equal(s.gyro, data["imu_gyr"])
    np.testing.assert_array_equal(s.accel, data["imu_acc"])
    assert (s.mag is not None) == mag
    assert s.t_ns.tolist() == [i * 10_000_000 for i in range(n)]
    assert rep.rows_read == n


def test_broad_imu_rejects_bad_files(tmp_path):
    f = tmp_path / "x.mat"
    savemat(f, {"imu_gyr": np.zeros((3, 3))})
    with pytest.raises(ValueError, match="no variable 'imu_acc'"):
        read_broad_imu(f)
    savemat(f, {"imu_gyr": np.zeros((3, 3)), "imu_acc": np.zeros((4, 3))})
    with pytest.raises(ValueError, match=r"imu_acc has shape \(4, 3\)"):
        read_broad_imu(f)
    g = np.zeros((3, 3))
    g[1, 0] = np.nan
    savemat(f, {"imu_gyr": g, "imu_acc": np.zeros((3, 3))})
    with pytest.raises(ValueError, match="row 1: non-finite"):
        read_broad_imu(f)
    s, rep = read_broad_imu(f, clean=True)
    assert len(s) == 2 and rep.dropped == {"non-finite IMU value": [1]}
    (tmp_path / "junk.mat").write_bytes(b"not a mat file")
    with pytest.raises(ValueError, match="not a readable MATLAB file"):
        read_imu(tmp_path / "junk.mat")
    with pytest.raises(ValueError, match="unknown IMU format"):
        read_imu(f, format="xsens")


def test_imu_stream_checks_and_selection():
    t = np.array([0, 5, 10])
    s = ImuStream(t, np.zeros((3, 3)), np.ones((3, 3)))
    assert len(s.select(slice(1, None))) == 2
    assert s.shifted(7).t_ns.tolist() == [7, 12, 17]
    assert abs(s.rate_hz - 2e8) < 1e-3
    with pytest.raises(ValueError, match="increase strictly"):
        ImuStream(np.array([0, 5, 5]), np.zeros((3, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"accel must have shape \(3, 3\)"):
        ImuStream(t, np.zeros((3, 3)), np.zeros((2, 3)))


def test_shared_imu_recordings_read(shared_data):
    s, rep = read_imu(shared_data / "euroc" / "V1_01_easy_imu0.csv")
    assert len(s) == 29120 and rep.rows_dropped == 0
    assert abs(s.rate_hz - 200.0) < 0.1
    assert 9.0 < np.median(np.linalg.norm(s.accel, axis=1)) < 10.5
    b, rep = read_imu(shared_data / "broad" / "06_undisturbed_fast_rotation_A.mat")
    assert len(b) == 56380 and b.mag is not None
    assert np.degrees(np.abs(b.gyro).max()) > 500  # the fast rotation trial
