"""A replay's IMU stamps put on the odometry's clock when they lag it
(:func:`fusion.calibration.time_offset.estimate_imu_lag`), or by the lag the user gives
(``fusion replay --imu-lag``).

Below :func:`lag_limit` a lag is left alone: a twist or a wheel frame is the mean rate over
the interval it closes, half an interval before its stamp, which the estimate reads as a
small lag (-5 to -16 ms on the black-box simulator's runs, -35 ms on the terrain bag's 10 Hz
twists), and a few tens of ms cost nothing measurable (the terrain bag's IMU 0.3 s late:
1.49 m of GPS RMSE against 1.46). Above it the IMU's stamps are moved by the whole estimate,
with a note; when pieces of the run disagree on the lag (a run whose turns repeat at one
period), nothing is moved and the note says so.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from fusion.calibration.gyro_axes import gyro_yaw_axis
from fusion.calibration.time_offset import PIECE, estimate_imu_lag
from fusion.jobs.streams import Streams

__all__ = ["LAG_LIMIT", "choose_imu_lag", "lag_limit", "shifted"]

#: s: the least lag moved, whatever the streams' rates.
LAG_LIMIT = 0.1


def lag_limit(streams: Streams) -> float:
    """s: lags up to this are left alone: :data:`LAG_LIMIT`, or two intervals of the slower
    stream (the IMU's or the odometry's median interval) if that is longer."""
    periods = [float(np.median(np.diff(t))) for t in (streams.imu_t, streams.wheel_t,
                                                      streams.twist_t)
               if t is not None and t.size >= 2]
    return max([LAG_LIMIT, *(2.0 * p for p in periods if math.isfinite(p))])


def choose_imu_lag(streams: Streams, chassis, given: float | None = None) -> tuple[float, str]:
    """``(lag, note)``: s to subtract from the IMU's stamps (0: leave them) and what to tell
    the user ("" for nothing). ``given``: the user's lag (``--imu-lag``), taken as it is;
    None: estimated (module docstring). ``chassis``: the wheel frames' geometry."""
    if given is not None:
        if not math.isfinite(given):
            raise ValueError(f"--imu-lag must be a finite number of s, got {given!r}")
        note = (f"IMU stamps moved by {-given:+.3f} s onto the odometry's clock (--imu-lag)"
                if given else "")
        return float(given), note
    odometry = streams.odometry_rates(chassis) if streams.has_imu else None
    if odometry is None:
        return 0.0, ""
    t, _, w = odometry
    up = _up(streams, t, w)
    if up is None:
        return 0.0, ""
    est = estimate_imu_lag(streams.imu_t, streams.gyro, up, t, w)
    limit = lag_limit(streams)
    if est is None or not abs(est.lag) > limit:
        return 0.0, ""
    late = f"{est.lag:.3f} s late" if est.lag > 0 else f"{-est.lag:.3f} s early"
    if est.spread > 0.5 * limit:
        return 0.0, (f"the IMU's stamps look {late} against the odometry's, but pieces of the "
                     f"run disagree by up to {est.spread:.3f} s: not moved (give --imu-lag "
                     "to move them)")
    return est.lag, (f"the IMU's stamps were {late} against the odometry's (their yaw rates "
                     f"line up best there: correlation {est.correlation:.3f}; {est.pieces} "
                     f"pieces of {PIECE:.0f} s agree within {est.spread:.3f} s): "
                     "moved onto the odometry's clock (--imu-lag 0 keeps them)")


def shifted(streams: Streams, lag: float) -> Streams:
    """``streams`` with ``lag`` s taken off the IMU's stamps (itself for 0)."""
    if not lag or not streams.has_imu:
        return streams
    return dataclasses.replace(streams, imu_t=streams.imu_t - lag)


def _up(streams: Streams, t, w):
    """The IMU frame's up: the accelerometer's mean where it reads gravity, else the gyro
    axis the odometry turns about; None if neither is known."""
    if not streams.level_note():
        return np.mean(streams.accel, axis=0)
    axis = gyro_yaw_axis(streams.imu_t, streams.gyro, t, w)
    return None if axis is None else np.array(axis.axis)
