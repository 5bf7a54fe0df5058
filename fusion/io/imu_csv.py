"""IMU CSV files: the IMU log type, its reader and the attitude CSV writer.

IMU CSV schema (header line required)::

    t,gx,gy,gz,ax,ay,az[,mx,my,mz]

``t`` in s (strictly increasing), gyro in rad/s, accelerometer (specific force) in m/s^2,
magnetometer in uT, all in the body frame (x forward, y left, z up).

Errors name the file and, where it applies, the line (1-based, as an editor shows it).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.geometry import quaternion as quat
from fusion.io.atomic import atomic_write
from fusion.io.errors import LogFormatError

__all__ = ["IMU_CSV_COLUMNS", "ImuLog", "read_imu_csv", "write_attitude_csv"]


IMU_CSV_COLUMNS = ("t", "gx", "gy", "gz", "ax", "ay", "az")


MAG_COLUMNS = ("mx", "my", "mz")


ATTITUDE_CSV_COLUMNS = ("t", "qw", "qx", "qy", "qz", "roll", "pitch", "yaw")


@dataclass
class ImuLog:
    """IMU samples: ``t`` (N,) s, ``gyro`` (N, 3) rad/s, ``accel`` (N, 3) m/s^2, ``mag`` uT."""

    t: NDArray[np.float64]
    gyro: NDArray[np.float64]
    accel: NDArray[np.float64]
    mag: NDArray[np.float64] | None = None
    source: str = ""

    def __len__(self) -> int:
        return len(self.t)


def read_imu_csv(path: str | Path) -> ImuLog:
    """Read an IMU CSV (schema in the module docstring).

    Raises :class:`LogFormatError` naming the file and line for a wrong header, a row with the
    wrong number of fields or a non-numeric value, and timestamps that do not increase.
    """
    path = Path(path)
    with path.open(newline="") as fh:
        header_line = fh.readline()
    header = [h.strip() for h in header_line.strip().split(",")]
    width = len(header)
    if tuple(header[:7]) != IMU_CSV_COLUMNS or width not in (7, 10) or (
        width == 10 and tuple(header[7:]) != MAG_COLUMNS
    ):
        raise LogFormatError(
            f"{path}:1: header must be {','.join(IMU_CSV_COLUMNS)}[,mx,my,mz], "
            f"got {header_line.strip()!r}"
        )
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, dtype=np.float64)
    except ValueError:
        _raise_bad_csv_line(path, width)
        raise
    if data.shape[0] and data.shape[1] != width:
        _raise_bad_csv_line(path, width)
    if data.shape[0] == 0:
        data = np.zeros((0, width))
    t = data[:, 0].copy()
    bad = np.flatnonzero(~(np.diff(t) > 0))
    if bad.size:
        line = int(bad[0]) + 3  # header is line 1, data row i is line i + 2
        raise LogFormatError(
            f"{path}:{line}: timestamp {t[bad[0] + 1]!r} does not increase "
            f"(previous {t[bad[0]]!r})"
        )
    return ImuLog(
        t=t,
        gyro=np.ascontiguousarray(data[:, 1:4]),
        accel=np.ascontiguousarray(data[:, 4:7]),
        mag=np.ascontiguousarray(data[:, 7:10]) if width == 10 else None,
        source=str(path),
    )


def _raise_bad_csv_line(path: Path, width: int) -> None:
    """Find the first malformed data line of a CSV and raise naming it."""
    with path.open(newline="") as fh:
        reader = csv.reader(fh)
        next(reader, None)
        for lineno, row in enumerate(reader, start=2):
            if not row:
                continue
            if len(row) != width:
                raise LogFormatError(
                    f"{path}:{lineno}: expected {width} fields, got {len(row)}"
                )
            for name, value in zip(_columns(width), row):
                try:
                    float(value)
                except ValueError:
                    raise LogFormatError(
                        f"{path}:{lineno}: column {name!r} is not a number: {value!r}"
                    ) from None


def _columns(width: int) -> tuple[str, ...]:
    return IMU_CSV_COLUMNS + (MAG_COLUMNS if width == 10 else ())


def write_attitude_csv(
    path: str | Path, t: NDArray, quaternions: NDArray
) -> None:
    """Write ``t,qw,qx,qy,qz,roll,pitch,yaw`` (s, quaternion body -> ENU, radians).

    Written atomically (:func:`fusion.io.atomic.atomic_write`): an existing file is replaced
    only by a complete one.
    """
    q = np.asarray(quaternions, dtype=float)
    euler = quat.to_euler(q)
    table = np.column_stack([np.asarray(t, dtype=float), q, euler])
    with atomic_write(path, encoding="ascii", newline="\n") as fh:
        np.savetxt(fh, table, delimiter=",", header=",".join(ATTITUDE_CSV_COLUMNS),
                   comments="", fmt="%.10g")
