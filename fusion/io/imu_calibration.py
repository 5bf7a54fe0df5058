"""IMU calibration files: :class:`fusion.calibration.imu.ImuCalibration` as JSON.

The file states its format, version and units (gyro bias rad/s, accelerometer offset m/s^2,
scale 1); :meth:`~fusion.calibration.imu.ImuCalibration.to_dict` and ``from_dict`` define the
content, this module only reads and writes it.
"""

from __future__ import annotations

import json
from pathlib import Path

from fusion.calibration.imu import ImuCalibration
from fusion.io.atomic import atomic_write

__all__ = ["load_imu_calibration", "save_imu_calibration"]


def save_imu_calibration(calibration: ImuCalibration, path: str | Path) -> None:
    """Write ``calibration`` as JSON, atomically (an existing file is replaced only by a
    complete one; a missing folder is refused naming ``path``)."""
    with atomic_write(path, encoding="utf-8") as fh:
        fh.write(json.dumps(calibration.to_dict(), indent=2) + "\n")


def load_imu_calibration(path: str | Path) -> ImuCalibration:
    """Read a file written by :func:`save_imu_calibration`.

    Raises:
        ValueError: not JSON (naming ``file:line``), not a calibration file, a missing key or
            a bad value, naming the file.
    """
    path = Path(path)
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}:{exc.lineno}: not valid JSON: {exc.msg}") from None
    if not isinstance(d, dict):
        raise ValueError(f"{path}: not an IMU calibration file")
    return ImuCalibration.from_dict(d, str(path))
