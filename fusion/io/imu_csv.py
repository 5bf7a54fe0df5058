"""IMU CSV files: the IMU log type, its reader and the attitude CSV writer.

One IMU CSV format for every command (``fusion imu -o`` writes it; ``fusion attitude``,
``fusion replay`` and :func:`read_imu_csv` read it). A header line names the columns; these
are read, in any order::

    t,gx,gy,gz,ax,ay,az[,mx,my,mz]

``t`` in s (strictly increasing), gyro in rad/s, accelerometer (specific force) in m/s^2,
magnetometer in uT (all three or none), all in the body frame (x forward, y left, z up).
Any other column is allowed and ignored, e.g. what ``fusion imu`` adds
(:data:`IMU_RECORD_COLUMNS`): ``temp`` (deg C), the attitude ``qw,qx,qy,qz`` (body -> ENU)
and ``roll,pitch,yaw`` (rad, ZYX). Angles are in radians in every file the library writes;
a column in degrees says so in its name (``_deg``).

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
from fusion.io.read_progress import LineProgress, ReadProgress

__all__ = ["ATTITUDE_CSV_COLUMNS", "IMU_CSV_COLUMNS", "IMU_RECORD_COLUMNS", "ImuLog",
           "imu_csv_line", "imu_csv_lines", "read_imu_csv", "write_attitude_csv"]

#: The columns every IMU CSV has (s, rad/s, m/s^2).
IMU_CSV_COLUMNS = ("t", "gx", "gy", "gz", "ax", "ay", "az")

#: Optional magnetometer columns (uT).
MAG_COLUMNS = ("mx", "my", "mz")

#: What ``fusion attitude`` writes: t (s), quaternion body -> ENU, ZYX angles (rad).
ATTITUDE_CSV_COLUMNS = ("t", "qw", "qx", "qy", "qz", "roll", "pitch", "yaw")

#: What ``fusion imu`` writes: the IMU columns, the die temperature (deg C; empty when the
#: chip gave none) and the attitude columns (quaternion, roll/pitch/yaw in rad).
IMU_RECORD_COLUMNS = (*IMU_CSV_COLUMNS, "temp", *ATTITUDE_CSV_COLUMNS[1:])


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


def read_imu_csv(path: str | Path, progress: ReadProgress | None = None) -> ImuLog:
    """Read an IMU CSV (schema in the module docstring): the columns named there, by name;
    ``progress(done, total)`` (bytes) is told how far the parse is (a large file takes
    seconds).

    Raises :class:`LogFormatError` naming the file and line for a header without the IMU
    columns, a row with the wrong number of fields, a value of a read column that is not a
    number, and timestamps that do not increase.
    """
    path = Path(path)
    with path.open(newline="") as fh:
        header_line = fh.readline()
    header = [h.strip() for h in header_line.strip().split(",")]
    columns = _read_columns(path, header, header_line)
    width = len(header)
    usecols = [header.index(c) for c in columns]
    try:
        if progress is None:
            data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, dtype=np.float64,
                              usecols=usecols)
        else:
            with path.open() as fh:
                data = np.loadtxt(LineProgress(fh, path.stat().st_size, progress),
                                  delimiter=",", skiprows=1, ndmin=2, dtype=np.float64,
                                  usecols=usecols)
    except ValueError:
        _raise_bad_csv_line(path, header, columns)
        raise
    if data.shape[0]:
        _check_widths(path, width)
    else:
        data = np.zeros((0, len(columns)))
    t = data[:, 0].copy()
    bad = np.flatnonzero(~(np.diff(t) > 0))
    if bad.size:
        line = _data_lines(path)[bad[0] + 1]
        raise LogFormatError(
            f"{path}:{line}: timestamp {float(t[bad[0] + 1])!r} does not increase "
            f"(previous {float(t[bad[0]])!r})"
        )
    _check_not_exchanged(path, data[:, 1:4], data[:, 4:7])
    has_mag = len(columns) == 10
    return ImuLog(
        t=t,
        gyro=np.ascontiguousarray(data[:, 1:4]),
        accel=np.ascontiguousarray(data[:, 4:7]),
        mag=np.ascontiguousarray(data[:, 7:10]) if has_mag else None,
        source=str(path),
    )


#: m/s^2, and the share of it within which a mean vector is gravity's (_check_not_exchanged)
_GRAVITY, _GRAVITY_SHARE = 9.80665, 0.25


def _check_not_exchanged(path: Path, gyro: np.ndarray, accel: np.ndarray) -> None:
    """Refuse rates that average gravity's magnitude while the accelerations do not: the
    gyro's and the accelerometer's columns under each other's names (an independent probe's
    log with data in t,ax,ay,az,gx,gy,gz order under the documented header was fused into six
    warnings about gravity, slip and encoders, none naming the columns). No robot turns at
    9.8 rad/s on average."""
    if gyro.shape[0] == 0:
        return
    g, a = np.mean(gyro, axis=0), np.mean(accel, axis=0)
    gn, an = float(np.linalg.norm(g)), float(np.linalg.norm(a))
    if abs(gn - _GRAVITY) <= _GRAVITY_SHARE * _GRAVITY and an < _GRAVITY_SHARE * _GRAVITY:
        raise LogFormatError(
            f"{path}: the gyro columns gx,gy,gz average ({g[0]:.3g}, {g[1]:.3g}, {g[2]:.3g}), "
            f"a magnitude of {gn:.3g}: gravity's, in m/s^2, while ax,ay,az average "
            f"{an:.3g}: the gyro's and the accelerometer's columns are exchanged (the header "
            "names what each column holds: t,gx,gy,gz,ax,ay,az in rad/s and m/s^2)")


def _read_columns(path: Path, header: list[str], header_line: str) -> tuple[str, ...]:
    """The columns to read (IMU, plus magnetometer if the header has it), checked."""
    want = "t,gx,gy,gz,ax,ay,az[,mx,my,mz] (in any order; other columns are ignored)"
    dup = sorted({h for h in header if header.count(h) > 1 and h})
    if dup:
        raise LogFormatError(f"{path}:1: column {dup[0]!r} appears twice in the header")
    missing = [c for c in IMU_CSV_COLUMNS if c not in header]
    if missing:
        raise LogFormatError(
            f"{path}:1: header has no column {', '.join(repr(c) for c in missing)}; an IMU "
            f"CSV needs {want}, got {header_line.strip()[:120]!r}")
    mags = [c for c in MAG_COLUMNS if c in header]
    if mags and len(mags) != 3:
        raise LogFormatError(f"{path}:1: magnetometer columns must be all of mx,my,mz or "
                             f"none, got {','.join(mags)}")
    return IMU_CSV_COLUMNS + (MAG_COLUMNS if mags else ())


def _data_lines(path: Path) -> list[int]:
    """Line numbers (1-based) of the data rows: the non-blank lines after the header."""
    with path.open(newline="") as fh:
        return [n for n, line in enumerate(fh, start=1) if n > 1 and line.strip()]


def imu_csv_lines(path: str | Path, indices: list[int]) -> list[int]:
    """The lines of the IMU CSV ``path`` holding samples ``indices`` (0-based data rows)."""
    lines = _data_lines(Path(path))
    return [lines[i] for i in indices]


def imu_csv_line(log: ImuLog, index: int) -> int:
    """The line of ``log.source`` (an IMU CSV read by :func:`read_imu_csv`) holding sample
    ``index``."""
    return _data_lines(Path(log.source))[index]


def _check_widths(path: Path, width: int) -> None:
    """Every data row has as many fields as the header (loadtxt checks only the read ones;
    a missing field would shift the columns after it). Numbers hold no commas or quotes,
    so counting commas is exact and fast."""
    with path.open("rb") as fh:
        fh.readline()
        for lineno, line in enumerate(fh, start=2):
            if line.count(b",") != width - 1 and line.strip():
                raise LogFormatError(
                    f"{path}:{lineno}: expected {width} fields (as in the header), got "
                    f"{line.count(b',') + 1}")


def _raise_bad_csv_line(path: Path, header: list[str], columns: tuple[str, ...]) -> None:
    """Find the first malformed data line of a CSV and raise naming it."""
    _check_widths(path, len(header))
    with path.open(newline="") as fh:
        reader = csv.reader(fh)
        next(reader, None)
        for row in reader:
            if not row:
                continue
            for name in columns:
                value = row[header.index(name)]
                try:
                    float(value)
                except ValueError:
                    raise LogFormatError(
                        f"{path}:{reader.line_num}: column {name!r} is not a number: {value!r}"
                    ) from None


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
