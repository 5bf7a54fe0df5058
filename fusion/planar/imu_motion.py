"""Is the IMU at rest, moving, or neither? A causal window statistic per sample.

The planar EKF takes a zero-velocity update only when the wheels AND the IMU are still, and
calls zero ticks while the IMU shows motion an encoder fault (:mod:`fusion.planar._ekf_core`).
This module gives it the IMU's half: for every sample a code

- :data:`MOTION_MOVING`: some gyro axis varies by at least ``gyro_move`` rad/s or some
  accelerometer axis by at least ``accel_move`` m/s^2 (standard deviations over an
  exponentially weighted window of time constant ``tau`` s): vibration while driving (of
  order 1 m/s^2 and 0.01 rad/s per m/s), a bump, a turn starting;
- :data:`MOTION_STILL`: every gyro axis has varied by at most ``gyro_still`` and every
  accelerometer axis by at most ``accel_still`` (same window) for the last ``still_time`` s
  without a break;
- :data:`MOTION_UNSURE`: neither (a smooth drive can look like rest; so can the first
  ``still_time`` s of a log).

Why standard deviations and both sensors: a robot at rest shows only sensor noise
(MPU6050: about 0.04 m/s^2 and 7e-4 rad/s per sample); driving shakes the accelerometer
by far more than that, and the gyro sees the rotation rates of the shaking too, so the
window statistic separates driving from rest even when one sensor alone is ambiguous. A
steady turn has a quiet gyro but a non-zero rate: the EKF tests the rate itself against its
bias (the motion-onset test), not this module. The thresholds are chosen by
cross-validation (``benchmarks/tune_ekf.py``).

Streaming and batch agree exactly: :meth:`ImuMotionDetector.update_batch` runs one compiled
loop over the samples with the detector's state carried in an array across calls.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion._jit import njit

__all__ = [
    "MOTION_MOVING",
    "MOTION_STILL",
    "MOTION_UNKNOWN",
    "MOTION_UNSURE",
    "ImuMotionDetector",
    "MotionThresholds",
    "imu_motion_codes",
    "imu_window_stds",
]

#: No IMU information (a gyro rate alone): the EKF falls back to the wheels (see its docstring).
MOTION_UNKNOWN = 0
MOTION_STILL = 1
MOTION_UNSURE = 2
MOTION_MOVING = 3

# state vector layout: last stamp, time quiet so far, then 6 means and 6 variances
_S_T = 0
_S_QUIET = 1
_S_STATS = 2
_STATE_SIZE = 14


@dataclass(frozen=True)
class MotionThresholds:
    """When the IMU counts as still or moving (SI units).

    Attributes:
        tau: time constant of the window, s (short: motion is declared within a fraction of a
            second, and a stop is not mistaken for motion for long after).
        still_time: how long the IMU must stay quiet before it counts as still, s.
        gyro_still: largest gyro standard deviation at rest, any axis, rad/s.
        accel_still: largest accelerometer standard deviation at rest, any axis, m/s^2.
        gyro_move: gyro standard deviation that means motion, any axis, rad/s.
        accel_move: accelerometer standard deviation that means motion, any axis, m/s^2.
    """

    tau: float = 0.1
    still_time: float = 0.3
    gyro_still: float = 0.01
    accel_still: float = 0.15
    gyro_move: float = 0.03
    accel_move: float = 0.5

    def __post_init__(self) -> None:
        for name in ("tau", "still_time", "gyro_still", "accel_still", "gyro_move",
                     "accel_move"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"MotionThresholds.{name} must be finite and > 0, got "
                                 f"{value!r}")
        if self.gyro_move < self.gyro_still or self.accel_move < self.accel_still:
            raise ValueError("MotionThresholds: the motion thresholds must not be below the "
                             f"stillness ones, got {self}")

    def as_array(self) -> NDArray[np.float64]:
        return np.array([self.tau, self.still_time, self.gyro_still, self.accel_still,
                         self.gyro_move, self.accel_move])


@njit
def _ewma(state, base, values, alpha):
    """Exponentially weighted mean and variance of 6 channels (in place at ``base``)."""
    for c in range(6):
        m = state[base + c]
        d = values[c] - m
        state[base + c] = m + alpha * d
        state[base + 6 + c] = (1.0 - alpha) * (state[base + 6 + c] + alpha * d * d)


@njit
def _largest_std(state, base, first, count):
    v = 0.0
    for c in range(first, first + count):
        if state[base + 6 + c] > v:
            v = state[base + 6 + c]
    return math.sqrt(v)


@njit
def _motion_loop(state, th, t, gyro, accel, out, stds):
    values = np.empty(6)
    for k in range(t.shape[0]):
        for c in range(3):
            values[c] = gyro[k, c]
            values[3 + c] = accel[k, c]
        if math.isnan(state[_S_T]):
            for c in range(6):
                state[_S_STATS + c] = values[c]
                state[_S_STATS + 6 + c] = 0.0
            state[_S_QUIET] = 0.0
            dt = 0.0
        else:
            dt = t[k] - state[_S_T]
            if dt < 0.0:
                dt = 0.0
            _ewma(state, _S_STATS, values, 1.0 - math.exp(-dt / th[0]))
        state[_S_T] = t[k]
        gyro_std = _largest_std(state, _S_STATS, 0, 3)
        accel_std = _largest_std(state, _S_STATS, 3, 3)
        stds[k, 0] = gyro_std
        stds[k, 1] = accel_std
        if gyro_std <= th[2] and accel_std <= th[3]:
            state[_S_QUIET] += dt
        else:
            state[_S_QUIET] = 0.0
        if gyro_std >= th[4] or accel_std >= th[5]:
            out[k] = 3.0
        elif state[_S_QUIET] >= th[1]:
            out[k] = 1.0
        else:
            out[k] = 2.0


class ImuMotionDetector:
    """Streaming IMU still/moving classifier (see the module docstring).

    Args:
        thresholds: :class:`MotionThresholds` (default: the cross-validated defaults).
    """

    def __init__(self, thresholds: MotionThresholds | None = None) -> None:
        self.thresholds = thresholds if thresholds is not None else MotionThresholds()
        self._th = self.thresholds.as_array()
        self._state = np.zeros(_STATE_SIZE)
        self._state[_S_T] = math.nan
        #: (N, 2) the window statistics of the last batch: the largest gyro (rad/s) and
        #: accelerometer (m/s^2) standard deviation over the axes, per sample
        self.last_stds = np.empty((0, 2))

    def update_batch(self, t: ArrayLike, gyro: ArrayLike, accel: ArrayLike
                     ) -> NDArray[np.float64]:
        """Codes (N,) (:data:`MOTION_STILL`, :data:`MOTION_UNSURE`, :data:`MOTION_MOVING`, as
        floats) of samples stamped ``t`` (s, increasing) with base-frame ``gyro`` (N, 3) rad/s
        and ``accel`` (N, 3) m/s^2, continuing from the previous call."""
        t = np.ascontiguousarray(t, dtype=np.float64).reshape(-1)
        g = np.ascontiguousarray(gyro, dtype=np.float64).reshape(-1, 3)
        a = np.ascontiguousarray(accel, dtype=np.float64).reshape(-1, 3)
        if not t.size == g.shape[0] == a.shape[0]:
            raise ValueError(f"{t.size} IMU stamps but gyro {g.shape} and accel {a.shape}")
        out = np.empty(t.size)
        self.last_stds = np.empty((t.size, 2))
        _motion_loop(self._state, self._th, t, g, a, out, self.last_stds)
        return out

    def update(self, t: float, gyro: ArrayLike, accel: ArrayLike) -> int:
        """The code of one sample (see :meth:`update_batch`)."""
        return int(self.update_batch(np.array([t]), gyro, accel)[0])


def imu_window_stds(t: ArrayLike, gyro: ArrayLike, accel: ArrayLike,
                    thresholds: MotionThresholds | None = None) -> NDArray[np.float64]:
    """(N, 2): for each sample of a whole recording, the largest gyro (rad/s) and
    accelerometer (m/s^2) standard deviation over the axes in the detector's window, the
    statistics :class:`ImuMotionDetector` compares with its thresholds."""
    detector = ImuMotionDetector(thresholds)
    detector.update_batch(t, gyro, accel)
    return detector.last_stds


def imu_motion_codes(t: ArrayLike, gyro: ArrayLike, accel: ArrayLike,
                     thresholds: MotionThresholds | None = None) -> NDArray[np.float64]:
    """Codes of a whole recording (a fresh :class:`ImuMotionDetector`)."""
    return ImuMotionDetector(thresholds).update_batch(t, gyro, accel)
