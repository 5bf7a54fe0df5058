"""Wheel counts that cannot be one period's ticks of two working encoders, named.

An independent probe wrote wheels.csv the ways people get it wrong; the replay fused each
and blamed something else (skid-steer, wheel_distance, "speeds in cm/s") or nothing:

- ``wheel_dead``: one wheel's count is 0 in nearly every frame in which the other counts (an
  unplugged encoder: 21.7 % final error, the warnings pointed at skid-steer and the IMU);
- ``wheel_sign``: the two wheels count in opposite directions while the gyro says the robot
  drives straight (a mirrored motor whose count was not negated: 42.5 %);
- ``wheel_totals``: the counts are running totals, not each period's (most frames beyond
  ``max_speed``, their differences plausible counts; a 16-bit counter's also wrap at 65536:
  470 % and 104 %, "speeds in cm/s?").

:func:`wheel_count_warnings` returns them as trust warnings
(:class:`fusion.evaluation.trust.TrustWarning`), so ``--strict`` refuses such a log.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fusion.evaluation.trust import TrustWarning
from fusion.geometry.mount import imu_to_base, mount_matrix
from fusion.jobs.streams import Streams
from fusion.planar.robot import RobotConfig

__all__ = ["DEAD_SHARE", "MIN_FRAMES", "OPPOSITE_SHARE", "STRAIGHT_RATE", "TOTALS_SHARE",
           "wheel_count_warnings"]

#: Frames of evidence below which nothing is said.
MIN_FRAMES = 50
#: Share of the frames in which the other wheel counts (2 ticks or more) with this one at 0.
DEAD_SHARE = 0.95
#: rad/s: the gyro's base-frame yaw rate below which the robot drives straight.
STRAIGHT_RATE = 0.05
#: Share of the straight, moving frames in which the two wheels count in opposite directions.
OPPOSITE_SHARE = 0.9
#: Share of the frames beyond ``max_speed`` whose differences are plausible counts.
TOTALS_SHARE = 0.5
_SIDES = ("left", "right")


def wheel_count_warnings(streams: Streams, robot: RobotConfig) -> list[TrustWarning]:
    """The checks of the module docstring on ``streams``' wheel frames (and, for
    ``wheel_sign``, its gyro about the base's z axis); empty without wheel frames."""
    if not streams.has_wheels:
        return []
    ticks = np.asarray(streams.ticks, dtype=np.float64)
    out = _totals(ticks, robot)
    if out:
        return out  # running totals make the other two meaningless
    out += _dead(ticks)
    if streams.has_imu and not out:
        out += _opposite(streams, ticks, robot)
    return out


def _totals(ticks: NDArray[np.float64], robot: RobotConfig) -> list[TrustWarning]:
    c = robot.chassis
    limit = robot.ekf.max_speed * c.encode_sampling_time / c.speed_ratio  # ticks a period
    beyond = np.any(np.abs(ticks) > limit, axis=1)
    if np.count_nonzero(beyond) < MIN_FRAMES or ticks.shape[0] < 3:
        return []
    diffs = np.diff(ticks, axis=0)
    wrapped = np.abs(np.abs(diffs) - 65536.0) <= limit
    plausible = np.all((np.abs(diffs) <= limit) | wrapped, axis=1)
    share = float(np.mean(plausible[beyond[1:]])) if np.any(beyond[1:]) else 0.0
    if share < TOTALS_SHARE:
        return []
    wraps = int(np.count_nonzero(np.any(wrapped & (np.abs(diffs) > limit), axis=1)))
    counter = (f"; {wraps} steps of about 65536 between rows: a 16-bit counter that wraps"
               if wraps else "")
    return [TrustWarning(
        "wheel_totals",
        f"the wheel counts look like running totals, not each period's ticks: "
        f"{np.count_nonzero(beyond)} of {ticks.shape[0]} frames count more than max_speed "
        f"({robot.ekf.max_speed:g} m/s) allows in one period, while {share:.0%} of their "
        f"differences from the row before are plausible counts{counter}; each row must hold "
        "the ticks of its own period (datasets/LOGDIR.md): write the differences "
        "(modulo the counter's range)",
        {"frames_beyond": float(np.count_nonzero(beyond)), "plausible_share": share,
         "wraps": float(wraps)})]


def _dead(ticks: NDArray[np.float64]) -> list[TrustWarning]:
    out = []
    for side, other in ((0, 1), (1, 0)):
        counting = np.abs(ticks[:, other]) >= 2
        n = int(np.count_nonzero(counting))
        if n < MIN_FRAMES:
            continue
        share = float(np.mean(ticks[counting, side] == 0))
        if share >= DEAD_SHARE:
            out.append(TrustWarning(
                "wheel_dead",
                f"the {_SIDES[side]} wheel's count is 0 in {share:.1%} of the {n} frames in "
                f"which the {_SIDES[other]} one counts: its encoder is not read (unplugged, "
                "a broken wire, a wrong pin); the wheels' speed and turns are wrong",
                {"zero_share": share, "frames": float(n), "side": float(side)}))
    return out


def _opposite(streams: Streams, ticks: NDArray[np.float64],
              robot: RobotConfig) -> list[TrustWarning]:
    rate = imu_to_base(mount_matrix(robot.imu_mount_rpy), streams.gyro)[:, 2]
    half = 0.5 * robot.chassis.encode_sampling_time
    at = np.interp(np.asarray(streams.wheel_t) - half, streams.imu_t, rate)
    moving = (np.abs(ticks[:, 0]) >= 2) & (np.abs(ticks[:, 1]) >= 2)
    straight = moving & (np.abs(at) < STRAIGHT_RATE)
    n = int(np.count_nonzero(straight))
    if n < MIN_FRAMES:
        return []
    share = float(np.mean(np.sign(ticks[straight, 0]) != np.sign(ticks[straight, 1])))
    if share < OPPOSITE_SHARE:
        return []
    return [TrustWarning(
        "wheel_sign",
        f"the left and right wheels count in opposite directions in {share:.0%} of the {n} "
        "frames in which the gyro says the robot drives straight: one wheel's count has its "
        "sign flipped (a mirrored motor or encoder); negate the column of the wheel that "
        "counts backwards when the robot drives forward",
        {"opposite_share": share, "frames": float(n)})]
