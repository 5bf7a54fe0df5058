"""BROAD benchmark trials (MATLAB ``.mat`` or HDF5 files): IMU data with optical ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.geometry import quaternion as quat
from fusion.io.errors import LogFormatError
from fusion.io.imu_csv import ImuLog

__all__ = ["BroadTrial", "read_broad"]


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
