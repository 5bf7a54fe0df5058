"""Log readers: BROAD benchmark trials and plain IMU CSV files.

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

from fusion import quaternion as quat

__all__ = [
    "IMU_CSV_COLUMNS",
    "BroadTrial",
    "ImuLog",
    "LogFormatError",
    "read_broad",
    "read_imu_csv",
    "write_attitude_csv",
]

IMU_CSV_COLUMNS = ("t", "gx", "gy", "gz", "ax", "ay", "az")
MAG_COLUMNS = ("mx", "my", "mz")
ATTITUDE_CSV_COLUMNS = ("t", "qw", "qx", "qy", "qz", "roll", "pitch", "yaw")


class LogFormatError(ValueError):
    """A log file that does not match its format; the message names file and line."""


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


@dataclass
class BroadTrial(ImuLog):
    """One BROAD trial: IMU data plus optical ground truth.

    Attributes (beyond :class:`ImuLog`):
        quat_ref: (N, 4) ground-truth attitude, ``[w, x, y, z]``, sensor -> earth (ENU-like,
            z up); NaN rows where the markers were lost.
        pos_ref: (N, 3) ground-truth position, m.
        movement: (N,) bool, the motion phases the errors are computed over.
        rate: sampling rate, Hz.
        name: trial name (file stem).
    """

    quat_ref: NDArray[np.float64] | None = None
    pos_ref: NDArray[np.float64] | None = None
    movement: NDArray[np.bool_] | None = None
    rate: float = 0.0
    name: str = ""

    def reference_initial_quaternion(self) -> NDArray[np.float64]:
        """The initial state of the dataset's published Mahony runs, in ENU.

        Exactly the dataset's recipe (datasets/broad/README.md), including its quirk: with
        ``a``, ``m`` the first accelerometer and magnetometer samples, ``z = a``,
        ``x = (z x -m) x z``, ``y = z x x``, ``R = [x, y, z]`` (normalised columns),
        ``q0 = quat(R)``, returned as ``qz(+90 deg) * q0``. It is not the physically correct
        attitude; use it only to reproduce the published numbers.
        """
        if self.mag is None:
            raise ValueError(f"{self.source}: the trial has no magnetometer data")
        z = self.accel[0]
        x = np.cross(np.cross(z, -self.mag[0]), z)
        y = np.cross(z, x)
        R = np.column_stack([v / np.linalg.norm(v) for v in (x, y, z)])
        q0 = quat.from_matrix(R)
        qz = np.array([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])
        return quat.multiply(qz, q0)


_BROAD_KEYS = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "opt_pos", "movement", "sampling_rate")


def read_broad(path: str | Path) -> BroadTrial:
    """Read a BROAD trial from its ``.mat`` (scipy) or ``.hdf5``/``.h5`` (h5py) file."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".mat":
        from scipy.io import loadmat
        from scipy.io.matlab import MatReadError

        try:
            raw = loadmat(path, variable_names=_BROAD_KEYS)
        except (MatReadError, ValueError, TypeError, OSError) as exc:
            if isinstance(exc, FileNotFoundError):
                raise
            raise LogFormatError(f"{path}: not a readable MATLAB file ({exc})") from exc
    elif suffix in (".hdf5", ".h5"):
        try:
            import h5py
        except ImportError as exc:
            raise ImportError(
                f"{path}: reading HDF5 needs h5py: pip install 'diffbot-fusion[hdf5]'"
            ) from exc
        with h5py.File(path, "r") as f:
            raw = {k: np.asarray(f[k]) for k in _BROAD_KEYS if k in f}
    else:
        raise LogFormatError(f"{path}: unknown BROAD file type {suffix!r} (want .mat or .hdf5)")
    missing = [k for k in _BROAD_KEYS if k not in raw]
    if missing:
        raise LogFormatError(f"{path}: not a BROAD trial, missing {', '.join(missing)}")

    def rows(key: str, width: int) -> NDArray[np.float64]:
        a = np.asarray(raw[key], dtype=np.float64)
        if a.ndim == 2 and a.shape[0] == width and a.shape[1] != width:
            a = a.T  # column-major writers store (width, N)
        if a.ndim != 2 or a.shape[1] != width:
            raise LogFormatError(f"{path}: {key} has shape {a.shape}, expected (N, {width})")
        return np.ascontiguousarray(a)

    gyro, accel, mag = rows("imu_gyr", 3), rows("imu_acc", 3), rows("imu_mag", 3)
    quat_ref, pos_ref = rows("opt_quat", 4), rows("opt_pos", 3)
    movement = np.asarray(raw["movement"]).reshape(-1).astype(bool)
    rate = float(np.asarray(raw["sampling_rate"]).reshape(-1)[0])
    n = gyro.shape[0]
    for key, arr in (("imu_acc", accel), ("imu_mag", mag), ("opt_quat", quat_ref),
                     ("opt_pos", pos_ref), ("movement", movement)):
        if arr.shape[0] != n:
            raise LogFormatError(f"{path}: {key} has {arr.shape[0]} rows, imu_gyr has {n}")
    if not rate > 0:
        raise LogFormatError(f"{path}: sampling_rate must be > 0 Hz, got {rate}")
    return BroadTrial(
        t=np.arange(n) / rate, gyro=gyro, accel=accel, mag=mag, source=str(path),
        quat_ref=quat_ref, pos_ref=pos_ref, movement=movement, rate=rate, name=path.stem,
    )


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

    Written to a temporary file first and renamed, so an existing file is never left half
    written.
    """
    path = Path(path)
    q = np.asarray(quaternions, dtype=float)
    euler = quat.to_euler(q)
    table = np.column_stack([np.asarray(t, dtype=float), q, euler])
    tmp = path.with_name(path.name + ".partial")
    try:
        np.savetxt(tmp, table, delimiter=",", header=",".join(ATTITUDE_CSV_COLUMNS),
                   comments="", fmt="%.10g")
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
