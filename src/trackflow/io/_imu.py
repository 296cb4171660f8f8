"""Inertial measurement streams: ``ImuStream`` and readers for EuRoC IMU csv and BROAD ``.mat``.

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

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FormatError, InputError
from ._devices import BROAD_RATE_HZ
from ._report import ReadReport
from ._table import parse_rows

__all__ = ["IMU_FORMATS", "ImuStream", "read_broad_imu", "read_euroc_imu", "read_imu"]

#: IMU file formats :func:`read_imu` understands.
IMU_FORMATS = ("euroc_imu", "broad")


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
    """

    t_ns: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    mag: np.ndarray | None = None
    frame: str = "imu"

    def __post_init__(self):
        t = np.ascontiguousarray(self.t_ns, dtype=np.int64).reshape(-1)
        n = t.shape[0]
        arrays = {"gyro": self.gyro, "accel": self.accel}
        if self.mag is not None:
            arrays["mag"] = self.mag
        for name, value in arrays.items():
            a = np.ascontiguousarray(value, dtype=float)
            if a.shape != (n, 3):
                raise InputError(f"ImuStream.{name} must have shape ({n}, 3), got {a.shape}")
            if not np.all(np.isfinite(a)):
                k = int(np.flatnonzero(~np.isfinite(a).all(axis=1))[0])
                raise InputError(f"ImuStream.{name} sample {k} is not finite: {a[k].tolist()}")
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
        t = self.t_ns[mask_or_index]
        return ImuStream(
            t,
            self.gyro[mask_or_index],
            self.accel[mask_or_index],
            None if self.mag is None else self.mag[mask_or_index],
            self.frame,
        )

    def shifted(self, offset_ns: int) -> ImuStream:
        """The same samples with ``offset_ns`` added to every time stamp."""
        return ImuStream(self.t_ns + int(offset_ns), self.gyro, self.accel, self.mag, self.frame)


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
    keep = _check_rows(report, table.where, table.t_ns, table.values, clean, f"{path}:", "line")
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
    keep = _check_rows(report, np.arange(n), t_ns, values, clean, f"{path}: row ", "row")
    report.rows_kept = int(np.count_nonzero(keep))
    report.notes.append(f"t = row / {rate_hz} Hz; gyro rad/s, accel m/s^2, mag microtesla")
    mag = cols["imu_mag"][keep] if "imu_mag" in cols else None
    stream = ImuStream(t_ns[keep], cols["imu_gyr"][keep], cols["imu_acc"][keep], mag, frame)
    return stream, report


def _check_rows(report, where, t_ns, values, clean, prefix, unit) -> np.ndarray:
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


def read_imu(
    path, format: str | None = None, *, clean: bool = False, **options
) -> tuple[ImuStream, ReadReport]:
    """Read an IMU recording; the format is guessed from the extension (``.mat`` -> ``broad``).

    Parameters
    ----------
    path : path-like
    format : {"euroc_imu", "broad"}, optional
    clean : bool
        Drop malformed rows (counted in the report) instead of raising ``ValueError``.
    **options
        ``rate_hz=`` for ``broad``; ``frame=`` names the sensor frame.

    Returns
    -------
    ImuStream, ReadReport
    """
    if format is None:
        format = "broad" if Path(path).suffix.lower() == ".mat" else "euroc_imu"
    if format == "broad":
        return read_broad_imu(path, clean=clean, **options)
    if format == "euroc_imu":
        return read_euroc_imu(path, clean=clean, **options)
    raise InputError(f"unknown IMU format {format!r}; expected one of {IMU_FORMATS}")
