"""Stamps in seconds, and a wheel period that fits the frames: checked before a log is fused.

A log directory's times are seconds (datasets/LOGDIR.md). A recorder that writes them in
milliseconds, microseconds or nanoseconds, or a robot.toml whose ``encode_sampling_time`` is in
milliseconds, gave no error of its own: an independent probe's imu.csv in microseconds ran out
of memory in the fusion (a 300 s run read as 3.5 days), one in milliseconds read "imu_rate_hz
must be 4.0 .. 10000.0 Hz, got 0.1", and ``encode_sampling_time = 25`` (ms) fused speeds 1000
times too slow, silently (42.7 % final error against 0.05 %).

:func:`check_imu_stamps`: the IMU's median sample interval must be a rate the fusion takes
(:data:`MIN_IMU_RATE_HZ` to :data:`MAX_IMU_RATE_HZ`). :func:`check_wheel_stamps`: each wheel
frame counts the ticks of one firmware period, so frames cannot come faster than one a
period over most of the log (:data:`FRAME_RATE_TOLERANCE` allows for the clocks' drift), and
a log that lost nine in ten of them (:data:`MAX_PERIODS_PER_FRAME`) is no odometry. The
errors say which unit would fit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fusion.io.errors import LogFormatError

__all__ = ["FRAME_RATE_TOLERANCE", "MAX_IMU_RATE_HZ", "MAX_PERIODS_PER_FRAME",
           "MIN_CHECKED_FRAMES", "MIN_IMU_RATE_HZ", "WINDOW_FRAMES", "check_imu_stamps",
           "check_wheel_stamps"]

#: Range of a plausible nominal IMU rate, Hz (its period must stay below the attitude
#: filter's ``max_gap``, 0.25 s; the MPU6050 samples at 1 kHz at most).
MIN_IMU_RATE_HZ = 4.0
MAX_IMU_RATE_HZ = 10_000.0
#: Wheel frames may come this much faster on average than one per ``encode_sampling_time``
#: (host and firmware clocks drift by 1e-4; a log of a few frames rounds).
FRAME_RATE_TOLERANCE = 0.1
#: Mean frame interval, in periods, beyond which the wheels' log is refused: nine in ten
#: frames lost (or another time unit), too few to dead-reckon from.
MAX_PERIODS_PER_FRAME = 10.0

#: Frames over which a wheel log's interval is averaged before the median is taken.
WINDOW_FRAMES = 10
#: Wheel logs shorter than this many frames are not checked.
MIN_CHECKED_FRAMES = 20

_UNITS = (("ms", 1e-3), ("us", 1e-6), ("ns", 1e-9))


def _unit_hint(interval: float, low: float, high: float) -> str:
    """A hint naming the unit that would bring ``interval`` into [low, high] s, where one does
    and ``interval`` is a second or more (a slow sensor stamped in s is not told "ms")."""
    if interval < 1.0:
        return ""
    for name, factor in _UNITS:
        if low <= interval * factor <= high:
            return (f"; if t is in {name}, the interval is {interval * factor:.4g} s: t "
                    "must be in s")
    return ""


def check_imu_stamps(path: str | Path, t: NDArray[np.float64]) -> None:
    """Raise :class:`LogFormatError` naming ``path`` when the median interval of the IMU's
    stamps ``t`` is no IMU rate (:data:`MIN_IMU_RATE_HZ` to :data:`MAX_IMU_RATE_HZ`); fewer
    than 2 stamps are not checked."""
    if t.size < 2:
        return
    interval = float(np.median(np.diff(t)))
    low, high = 1.0 / MAX_IMU_RATE_HZ, 1.0 / MIN_IMU_RATE_HZ
    if low <= interval <= high:
        return
    raise LogFormatError(
        f"{path}: the samples are {interval:.6g} s apart (median of t), a rate of "
        f"{1.0 / interval:.4g} Hz; an IMU samples at {MIN_IMU_RATE_HZ:g} to "
        f"{MAX_IMU_RATE_HZ:g} Hz{_unit_hint(interval, low, high)}")


def check_wheel_stamps(path: str | Path, t: NDArray[np.float64], period: float) -> None:
    """Raise :class:`LogFormatError` naming ``path`` when the wheel frames stamped ``t`` (s)
    come faster than one per ``period`` (robot.toml's ``encode_sampling_time``, s) allows,
    or slower than one per :data:`MAX_PERIODS_PER_FRAME` periods, over most of the log: the
    median of the mean interval over :data:`WINDOW_FRAMES` consecutive frames (a recorder's
    pause, a backlog read in a burst and the host's jitter move it little); logs of fewer
    than :data:`MIN_CHECKED_FRAMES` frames are not checked."""
    if t.size < MIN_CHECKED_FRAMES:
        return
    k = WINDOW_FRAMES
    mean = float(np.median((t[k:] - t[:-k]) / k))
    ratio = mean / period
    if (1.0 - FRAME_RATE_TOLERANCE) <= ratio <= MAX_PERIODS_PER_FRAME:
        return
    if ratio < 1.0:
        why = ("each frame counts one period's ticks, so they cannot come faster than one a "
               "period: encode_sampling_time is too long, or not in s (the miiboo board's is "
               "0.04 s)")
        if 0.5 <= mean / (period * 1e-3) <= 2.0:
            why += f"; in ms it would fit: encode_sampling_time = {period * 1e-3:g}"
    else:
        why = (f"{1.0 - 1.0 / ratio:.1%} of the frames missing, or the times in another "
               f"unit{_unit_hint(mean, 0.5 * period, 2.0 * period)}")
    raise LogFormatError(
        f"{path}: the frames are {mean:.6g} s apart (typically), {ratio:.4g} times robot.toml's "
        f"encode_sampling_time {period:g} s: {why}")
