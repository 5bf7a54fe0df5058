"""Which of the gyro's axes carries the robot's turns, from a log's odometry, and whether that
axis is the vertical the accelerometer reads.

A driver that swaps two gyro axes (or publishes one sensor's rates with another's
accelerations) leaves every check on gravity passing: the accelerometer sits as the mount
says, only the rates are about other axes. The fusion then takes the heading rate from a
horizontal axis. On the terrain outdoor bag with the gyro's x and y swapped the fused track
was 37 m RMS off GPS (1.5 m untouched) with only a heading disagreement to show for it.

:func:`gyro_yaw_axis` takes the covariance of the three gyro rates with the odometry's yaw
rate (wheel frames or twists; any scale, a skid-steer's too) over the odometry's intervals
(the gyro averaged over each, exactly, from its integral): its direction is the gyro's axis
the odometry turns about, in the IMU frame (rates about the other axes, pitching and
rolling, do not move with the turns; constant offsets drop out).
:func:`axis_angle` compares it with the accelerometer's mean (up, at rest and on average
while driving). Needs the robot to have turned (:data:`MIN_TURN` rad of odometry turns) and
the fit to explain the odometry (:data:`MIN_CORRELATION`); rates in rad/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.integrate import cumulative_trapezoid

__all__ = ["MIN_CORRELATION", "MIN_TURN", "YawAxis", "axis_angle", "components",
           "gyro_yaw_axis"]

#: rad: the odometry's turns (sum of |w| dt over the intervals fitted) needed for a fit.
MIN_TURN = 2.0 * math.pi
#: The fitted rates' correlation with the odometry's yaw rate below which the fit says
#: nothing (the odometry does not follow any axis: a wrong topic, a gyro that is dead).
MIN_CORRELATION = 0.9


@dataclass(frozen=True)
class YawAxis:
    """The gyro axis the odometry turns about.

    Attributes:
        axis: (3,) unit vector in the IMU frame: the odometry's yaw rate is ``scale`` times
            the gyro's rate about it (plus an offset).
        scale: the odometry's yaw rate per gyro rate about ``axis`` (1 for a differential
            drive whose wheel_distance fits; about 1.5 for a skid-steer's geometric track).
        correlation: of the fitted rates with the odometry's.
        turn: rad, the odometry's turns over the intervals fitted.
    """

    axis: tuple[float, float, float]
    scale: float
    correlation: float
    turn: float

    def describe(self) -> str:
        """The axis as IMU-frame components, e.g. ``(+0.00, +1.00, -0.01)``."""
        return components(self.axis)


def components(v: ArrayLike) -> str:
    """A vector's components for a message, e.g. ``(+0.00, +1.00, -0.01)``."""
    return "(" + ", ".join(f"{float(c):+.2f}" for c in np.asarray(v).reshape(-1)) + ")"


def gyro_yaw_axis(imu_t: ArrayLike, gyro: ArrayLike, odom_t: ArrayLike, odom_w: ArrayLike
                  ) -> YawAxis | None:
    """The gyro's axis the odometry's turns show about (module docstring); None when the
    robot turned too little, the streams do not overlap, or no axis explains the odometry.

    Args:
        imu_t: (N,) s, increasing. gyro: (N, 3) rad/s, IMU frame.
        odom_t: (M,) s, increasing. odom_w: (M,) rad/s, the odometry's yaw rate.
    """
    t = np.asarray(imu_t, dtype=float)
    g = np.asarray(gyro, dtype=float)
    s = np.asarray(odom_t, dtype=float)
    w = np.asarray(odom_w, dtype=float)
    ok = np.isfinite(t) & np.all(np.isfinite(g), axis=1)
    t, g = t[ok], g[ok]
    ok = np.isfinite(s) & np.isfinite(w)
    s, w = s[ok], w[ok]
    if t.size < 2 or s.size < 2:
        return None
    inside = (s >= t[0]) & (s <= t[-1])
    s, w = s[inside], w[inside]
    if s.size < 2:
        return None
    dt = np.diff(s)
    use = dt > 0.0
    # the gyro's mean over each odometry interval, from its integral at the interval's ends
    integral = cumulative_trapezoid(g, t, axis=0, initial=0.0)
    at = np.column_stack([np.interp(s, t, integral[:, j]) for j in range(3)])
    mean = np.diff(at, axis=0)[use] / dt[use, None]
    target = 0.5 * (w[1:] + w[:-1])[use]
    turn = float(np.sum(np.abs(target) * dt[use]))
    if turn < MIN_TURN:
        return None
    # the direction of the gyro's covariance with the odometry: the axis whose rate moves
    # with the turns (a least-squares fit on all three would also fit the odometry's noise
    # with the axes that barely move: 7 deg off on a test with 0.02 rad/s of it)
    g_dev = mean - mean.mean(axis=0)
    w_dev = target - target.mean()
    cross = g_dev.T @ w_dev
    size = float(np.linalg.norm(cross))
    if not size > 0:
        return None
    axis = cross / size
    about = g_dev @ axis
    spread = float(np.sqrt(np.dot(about, about) * np.dot(w_dev, w_dev)))
    corr = float(np.dot(about, w_dev)) / spread if spread > 0 else 0.0
    if not corr >= MIN_CORRELATION:
        return None
    scale = float(np.dot(about, w_dev) / np.dot(about, about))
    return YawAxis((float(axis[0]), float(axis[1]), float(axis[2])), scale, corr, turn)


def axis_angle(axis: ArrayLike, up: ArrayLike) -> float:
    """rad in [0, pi]: the angle between the gyro's yaw ``axis`` and ``up`` (the
    accelerometer's mean, IMU frame; any length)."""
    a = np.asarray(axis, dtype=float)
    u = np.asarray(up, dtype=float)
    c = float(np.dot(a, u) / (np.linalg.norm(a) * np.linalg.norm(u)))
    return math.acos(max(-1.0, min(1.0, c)))
