"""Inertial measurement streams: ``ImuStream`` and readers for EuRoC IMU csv and BROAD ``.mat``.

``sensor_msgs/Imu`` in ROS bags: :mod:`trackflow.io._rosimu`; ``read_imu`` over every format:
:mod:`trackflow.io._api`.

EuRoC IMU csv
-------------
``#timestamp [ns], w_RS_S_x, w_RS_S_y, w_RS_S_z [rad/s], a_RS_S_x, a_RS_S_y, a_RS_S_z [m/s^2]``:
angular velocity and specific force of the sensor frame S, in S. Time is integer nanoseconds.

BROAD trials
------------
``imu_gyr`` (rad/s), ``imu_acc`` (m/s^2) and ``imu_mag`` (microtesla), (N, 3) each, sampled at
285.714 Hz without timestamps on the same grid as the OptiTrack pose that
:func:`trackflow.io.read_broad` reads: ``t_ns = round(i * 1e9 / 285.714)``. The IMU rows have no
dropouts; a non-finite IMU row is an error naming the row (or, with ``clean``, dropped and
counted).

Both give the sensor's own frame (``"imu"`` by default); accelerometers measure specific force
``f = R_w_s^T (a_w - g_w)``, so an IMU at rest reads about ``+9.81`` m/s^2 upwards.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FormatError, InputError
from ._devices import BROAD_RATE_HZ
from ._report import ReadReport
from ._stream import unit_quaternions
from ._table import parse_rows

__all__ = ["ImuStream", "check_rows", "read_broad_imu", "read_euroc_imu"]


@dataclass(frozen=True)
class ImuStream:
    """Samples of one inertial measurement unit.

    Attributes
    ----------
    t_ns : ndarray of int64, shape (N,)
        Strictly increasing sample times [ns].
    gyro : ndarray, shape (N, 3)
        Angular velocity of the sensor frame, in the sensor frame [rad/s].
    accel : ndarray, shape (N, 3)
        Specific force in the sensor frame [m/s^2] (gravity reads upwards at rest).
    mag : ndarray, shape (N, 3), or None
        Magnetic field in the sensor frame [microtesla], when the IMU has a magnetometer.
    frame : str
        Name of the sensor frame.
    orientation : ndarray, shape (N, 4), or None
        ``R_ref_sensor`` as unit quaternions ``(x, y, z, w)``, when the IMU estimates its
        orientation against a reference frame of its own (ROS ``sensor_msgs/Imu``).
    orientation_covariance : ndarray, shape (N, 3, 3), or None
        Covariance of ``dtheta`` with ``R_true = R Exp(dtheta)`` (on the right, sensor frame)
        [rad^2], ``docs/conventions.md``. All zeros for a sample: unknown.
    gyro_covariance, accel_covariance : ndarray, shape (N, 3, 3), or None
        Covariance of ``gyro`` [(rad/s)^2] and of ``accel`` [(m/s^2)^2], sensor frame. All
        zeros for a sample: unknown.
    """

    t_ns: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    mag: np.ndarray | None = None
    frame: str = "imu"
    orientation: np.ndarray | None = None
    orientation_covariance: np.ndarray | None = None
    gyro_covariance: np.ndarray | None = None
    accel_covariance: np.ndarray | None = None

    def __post_init__(self):
        t = np.ascontiguousarray(self.t_ns, dtype=np.int64).reshape(-1)
        n = t.shape[0]
        arrays = {"gyro": (self.gyro, (n, 3)), "accel": (self.accel, (n, 3))}
        optional = {
            "mag": (n, 3),
            "orientation": (n, 4),
            "orientation_covariance": (n, 3, 3),
            "gyro_covariance": (n, 3, 3),
            "accel_covariance": (n, 3, 3),
        }
        for name, shape in optional.items():
            if getattr(self, name) is not None:
                arrays[name] = (getattr(self, name), shape)
        for name, (value, shape) in arrays.items():
            a = np.ascontiguousarray(value, dtype=float)
            if a.shape != shape:
                raise InputError(f"ImuStream.{name} must have shape {shape}, got {a.shape}")
            if not np.all(np.isfinite(a)):
                k = int(np.flatnonzero(~np.isfinite(a.reshape(n, -1)).all(axis=1))[0])
                raise InputError(f"ImuStream.{name} sample {k} is not finite: {a[k].tolist()}")
            if name == "orientation" and n:
                a = unit_quaternions(a)
            object.__setattr__(self, name, a)
        if n > 1 and np.any(np.diff(t) <= 0):
            k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
            raise InputError(
                f"ImuStream times must increase strictly: sample {k} (t_ns={int(t[k])}) "
                f"after t_ns={int(t[k - 1])}"
            )
        object.__setattr__(self, "t_ns", t)

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    @property
    def t(self) -> np.ndarray:
        """Sample times [s] (float64, absolute), shape (N,)."""
        return self.t_ns.astype(np.float64) * 1e-9

    @property
    def rate_hz(self) -> float:
        """Median sample rate [Hz]."""
        if len(self) < 2:
            raise InputError("an IMU stream needs two samples to have a rate")
        return 1e9 / float(np.median(np.diff(self.t_ns)))

    def select(self, mask_or_index) -> ImuStream:
        """The samples at a boolean mask, slice or index array (order kept)."""

        def pick(a):
            return None if a is None else a[mask_or_index]

        return ImuStream(
            self.t_ns[mask_or_index],
            self.gyro[mask_or_index],
            self.accel[mask_or_index],
            pick(self.mag),
            self.frame,
            pick(self.orientation),
            pick(self.orientation_covariance),
            pick(self.gyro_covariance),
            pick(self.accel_covariance),
        )

    def shifted(self, offset_ns: int) -> ImuStream:
        """The same samples with ``offset_ns`` added to every time stamp."""
        return dataclasses.replace(self, t_ns=self.t_ns + int(offset_ns))


def read_euroc_imu(
    path, *, clean: bool = False, frame: str = "imu"
) -> tuple[ImuStream, ReadReport]:
    """Read a EuRoC IMU csv (see module docstring); ``file:line`` errors for malformed rows."""
    path = Path(path)
    report = ReadReport(str(path), "euroc_imu")
    table, _ = parse_rows(
        path,
        report,
        delimiter=",",
        ncols=7,
        time_col=0,
        time_exponent=0,
        value_cols=range(1, 7),
        clean=clean,
    )
    keep = check_rows(report, table.where, table.t_ns, table.values, clean, f"{path}:", "line")
    v = table.values[keep]
    report.rows_kept = int(np.count_nonzero(keep))
    stream = ImuStream(table.t_ns[keep], v[:, 0:3], v[:, 3:6], None, frame)
    return stream, report


def read_broad_imu(
    path, *, clean: bool = False, rate_hz: float = BROAD_RATE_HZ, frame: str = "imu"
) -> tuple[ImuStream, ReadReport]:
    """Read the IMU of a BROAD trial: ``imu_gyr``, ``imu_acc``, ``imu_mag`` (module docstring)."""
    from scipy.io import loadmat
    from scipy.io.matlab import MatReadError

    path = Path(path)
    try:
        mat = loadmat(path)
    except (
        ValueError,
        OSError,
        TypeError,
        IndexError,
        MatReadError,
    ) as exc:  # scipy 1.13: IndexError
        raise FormatError(f"{path}: not a readable MATLAB file ({exc})") from exc
    cols = {}
    for key in ("imu_gyr", "imu_acc"):
        if key not in mat:
            raise FormatError(f"{path}: no variable {key!r} (not a BROAD trial?)")
        cols[key] = np.asarray(mat[key], dtype=float)
    n = cols["imu_gyr"].shape[0]
    if "imu_mag" in mat:
        cols["imu_mag"] = np.asarray(mat["imu_mag"], dtype=float)
    for key, a in cols.items():
        if a.shape != (n, 3):
            raise FormatError(f"{path}: {key} has shape {a.shape}, expected ({n}, 3)")
    report = ReadReport(str(path), "broad", unit="row", rows_read=n)
    t_ns = np.rint(np.arange(n) * (1e9 / rate_hz)).astype(np.int64)
    values = np.concatenate(list(cols.values()), axis=1)
    keep = check_rows(report, np.arange(n), t_ns, values, clean, f"{path}: row ", "row")
    report.rows_kept = int(np.count_nonzero(keep))
    report.notes.append(f"t = row / {rate_hz} Hz; gyro rad/s, accel m/s^2, mag microtesla")
    mag = cols["imu_mag"][keep] if "imu_mag" in cols else None
    stream = ImuStream(t_ns[keep], cols["imu_gyr"][keep], cols["imu_acc"][keep], mag, frame)
    return stream, report


def check_rows(report, where, t_ns, values, clean, prefix, unit) -> np.ndarray:
    """Rows to keep: finite values and increasing time; otherwise an error naming the row."""
    bad = ~np.isfinite(values).all(axis=1)
    order = np.ones(len(t_ns), dtype=bool)
    if len(t_ns) > 1:
        last = np.maximum.accumulate(t_ns)
        order[1:] = t_ns[1:] > last[:-1]
    for mask, reason in ((bad, "non-finite IMU value"), (~order & ~bad, "time not increasing")):
        if np.any(mask):
            k = int(np.flatnonzero(mask)[0])
            if not clean:
                raise FormatError(f"{prefix}{int(where[k])}: {reason}")
            report.drop(reason, where[mask])
    return ~bad & order
