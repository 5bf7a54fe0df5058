"""Sample types passed between drivers, logs and filters.

All quantities are SI in the body frame (x forward, y left, z up): angular rate rad/s,
specific force m/s^2, magnetic field uT, temperature deg C, time s on one host clock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["ImuSample", "WheelTicks"]


@dataclass(frozen=True, slots=True)
class ImuSample:
    """One IMU reading.

    Attributes:
        t: host timestamp, s.
        gyro: angular rate (3,), rad/s, body frame.
        accel: specific force (3,), m/s^2, body frame (+g along up at rest).
        mag: magnetic field (3,), uT, body frame, or None.
        temperature: die temperature, deg C, or None.
    """

    t: float
    gyro: NDArray[np.float64]
    accel: NDArray[np.float64]
    mag: NDArray[np.float64] | None = None
    temperature: float | None = None


@dataclass(frozen=True, slots=True)
class WheelTicks:
    """Encoder ticks counted during one sampling period, as on the wire (left, right).

    Attributes:
        t: host timestamp of the end of the period, s.
        left: left wheel ticks in the period (signed).
        right: right wheel ticks in the period (signed).
    """

    t: float
    left: int
    right: int
