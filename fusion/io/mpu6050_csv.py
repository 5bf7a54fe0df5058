"""Reader for raw MPU6050 register recordings in CSV (as in ``datasets/mpu6050_raw``).

Format: ``key,value`` metadata lines (``Fs,100`` gives the sample rate in Hz; others such as
``Logging Type``, ``Initialization time`` and ``Waiting time`` are kept as strings), then the
header ``ax,ay,az,gx,gy,gz``, then one row of signed 16-bit register values per sample.

Conversions to SI happen here, at the edge, with the sensitivities of the ranges the recording
was made at: the ``accel_lsb_per_g`` and ``gyro_lsb_per_dps`` metadata lines when present (this
library's recorder, ``fusion imu --raw``, writes them), else +-2 g = 16384 LSB/g and +-250 deg/s
= 131 LSB/(deg/s) as in the bundled recordings.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.types.constants import STANDARD_GRAVITY

__all__ = ["RawImuRecording", "format_header", "format_row", "read_mpu6050_csv"]

_HEADER = ["ax", "ay", "az", "gx", "gy", "gz"]


@dataclass(frozen=True)
class RawImuRecording:
    """A raw recording.

    Attributes:
        path: the file read.
        fs_hz: sample rate, Hz (from the ``Fs`` line).
        accel: accelerometer x, y, z counts (N, 3), int.
        gyro: gyroscope x, y, z counts (N, 3), int.
        accel_lsb_per_g: accelerometer sensitivity the recording was made at, LSB/g.
        gyro_lsb_per_dps: gyro sensitivity, LSB/(deg/s).
        metadata: the other metadata lines, key -> value string.
    """

    path: Path
    fs_hz: float
    accel: NDArray[np.int64]
    gyro: NDArray[np.int64]
    accel_lsb_per_g: float = 16384.0
    gyro_lsb_per_dps: float = 131.0
    metadata: dict[str, str] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.accel)

    @property
    def t(self) -> NDArray[np.float64]:
        """Sample times from the rate, s, starting at 0."""
        return np.arange(len(self.accel)) / self.fs_hz

    def accel_g(self) -> NDArray[np.float64]:
        """Specific force (N, 3) in g."""
        return self.accel / self.accel_lsb_per_g

    def gyro_dps(self) -> NDArray[np.float64]:
        """Angular rate (N, 3) in deg/s."""
        return self.gyro / self.gyro_lsb_per_dps

    def accel_si(self, gravity: float = STANDARD_GRAVITY) -> NDArray[np.float64]:
        """Specific force (N, 3) in m/s^2 (g = ``gravity``)."""
        return self.accel_g() * gravity

    def gyro_si(self) -> NDArray[np.float64]:
        """Angular rate (N, 3) in rad/s."""
        return np.radians(self.gyro_dps())


def format_header(fs_hz: float, accel_lsb_per_g: float, gyro_lsb_per_dps: float) -> str:
    """The metadata lines and column header of a recording (newline-terminated)."""
    return (f"Fs,{fs_hz:g}\naccel_lsb_per_g,{accel_lsb_per_g:g}\n"
            f"gyro_lsb_per_dps,{gyro_lsb_per_dps:g}\n{','.join(_HEADER)}\n")


def format_row(accel: Sequence[int], gyro: Sequence[int]) -> str:
    """One sample row: accel x, y, z then gyro x, y, z int16 counts (newline-terminated)."""
    return ",".join(str(int(v)) for v in (*accel, *gyro)) + "\n"


def read_mpu6050_csv(
    path: str | Path,
    *,
    accel_lsb_per_g: float | None = None,
    gyro_lsb_per_dps: float | None = None,
) -> RawImuRecording:
    """Read a raw MPU6050 CSV recording; ``ValueError`` names the file and line of bad input.

    Sensitivities: the arguments if given, else the file's metadata, else 16384 LSB/g and
    131 LSB/(deg/s).
    """
    path = Path(path)
    metadata: dict[str, str] = {}
    rows: list[list[int]] = []
    header_line = 0
    with path.open(encoding="utf-8") as fh:
        for lineno, line in enumerate(fh, start=1):
            text = line.strip()
            if not text:
                continue
            cells = [c.strip() for c in text.split(",")]
            if not header_line:
                if [c.lower() for c in cells] == _HEADER:
                    header_line = lineno
                elif len(cells) == 2:
                    metadata[cells[0]] = cells[1]
                else:
                    raise ValueError(
                        f"{path}:{lineno}: expected a 'key,value' metadata line or the header "
                        f"{','.join(_HEADER)}; got {text[:60]!r}"
                    )
                continue
            if len(cells) != 6:
                raise ValueError(f"{path}:{lineno}: expected 6 values, got {len(cells)}")
            try:
                values = [int(c) for c in cells]
            except ValueError:
                raise ValueError(
                    f"{path}:{lineno}: values must be integers (raw register counts); "
                    f"got {text[:60]!r}"
                ) from None
            if any(not -32768 <= v <= 32767 for v in values):
                raise ValueError(f"{path}:{lineno}: value outside int16 range in {text[:60]!r}")
            rows.append(values)
    if not header_line:
        raise ValueError(f"{path}: no header line {','.join(_HEADER)} found")
    if not rows:
        raise ValueError(f"{path}: no samples after the header (line {header_line})")
    fs_text = metadata.pop("Fs", None)
    if fs_text is None:
        raise ValueError(f"{path}: no 'Fs,<Hz>' metadata line before the header")
    try:
        fs = float(fs_text)
    except ValueError:
        raise ValueError(f"{path}: Fs must be a number of Hz; got {fs_text!r}") from None
    if not fs > 0:
        raise ValueError(f"{path}: Fs must be > 0 Hz; got {fs_text!r}")
    lsb = []
    for key, given, default in (("accel_lsb_per_g", accel_lsb_per_g, 16384.0),
                                ("gyro_lsb_per_dps", gyro_lsb_per_dps, 131.0)):
        text = metadata.get(key)
        if given is not None:
            lsb.append(float(given))
        elif text is None:
            lsb.append(default)
        else:
            try:
                value = float(text)
            except ValueError:
                value = math.nan
            if not value > 0:
                raise ValueError(f"{path}: {key} must be a positive number; got {text!r}")
            lsb.append(value)
    data = np.asarray(rows, dtype=np.int64)
    return RawImuRecording(path, fs, data[:, :3], data[:, 3:], lsb[0], lsb[1], metadata)
