"""Wheel counts that cannot be one period's ticks of two working encoders, named.

An independent probe wrote wheels.csv the ways people get it wrong; the replay fused each
and blamed something else (skid-steer, wheel_distance, "speeds in cm/s") or nothing:

- ``wheel_dead``: one wheel's count is 0 in nearly every frame in which the other counts (an
  unplugged encoder: 21.7 % final error, the warnings pointed at skid-steer and the IMU);
- ``wheel_sign``: the gyro's yaw rate follows the sum of the two wheels' counts, not their
  difference (a mirrored motor whose count was not negated: 42.5 %);
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

__all__ = ["DEAD_SHARE", "MIN_FRAMES", "MIN_WINDOWS", "SIGN_CORRELATION", "SIGN_MARGIN",
           "SIGN_WINDOW", "TOTALS_ONWARD", "TOTALS_SHARE", "wheel_count_warnings"]

#: Frames of evidence below which nothing is said.
MIN_FRAMES = 50
#: Share of the frames in which the other wheel counts (2 ticks or more) with this one at 0.
DEAD_SHARE = 0.95
#: s: the wheels' counts and the gyro's rate are compared per window this long ...
SIGN_WINDOW = 1.0
#: ... over at least this many windows in which both wheels count.
MIN_WINDOWS = 30
#: Least correlation of the gyro's yaw rate with the sum of the wheels' counts for one of
#: them to have its sign flipped ...
SIGN_CORRELATION = 0.7
#: ... by this much more than with their difference (the turn, when both are right).
SIGN_MARGIN = 0.3
#: Share of the frames beyond ``max_speed`` whose differences are plausible counts.
TOTALS_SHARE = 0.5
#: Share of a running total's steps that go the same way as the step before (it reverses only
#: where the robot does).
TOTALS_ONWARD = 0.8
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
    # a running total keeps moving one way while the robot drives (its steps are the
    # periods' counts); a period's count goes up and down with the speed: counts that do are
    # per period at a wrong scale (speed_ratio in mm, say: speed_scale and implausible
    # speak), not totals (a review's case; a synthetic run: 0.16 against 0.998)
    steps = np.sum(diffs, axis=1)
    steps = steps[(steps != 0) & ~np.any(wrapped & (np.abs(diffs) > limit), axis=1)]
    onward = float(np.mean(np.sign(steps[1:]) == np.sign(steps[:-1]))) if steps.size > 2 else 0
    if share < TOTALS_SHARE or onward < TOTALS_ONWARD:
        return []
    wraps = int(np.count_nonzero(np.any(wrapped & (np.abs(diffs) > limit), axis=1)))
    counter = (f"; {wraps} steps of about 65536 between rows: a 16-bit counter that wraps"
               if wraps else "")
    return [TrustWarning(
        "wheel_totals",
        f"the wheel counts look like running totals, not each period's ticks: "
        f"{np.count_nonzero(beyond)} of {ticks.shape[0]} frames count more than max_speed "
        f"({robot.ekf.max_speed:g} m/s) allows in one period, while {share:.0%} of their "
        f"differences from the row before are plausible counts{counter}, and they go one way "
        f"({onward:.0%} of the steps as the one before); each row "
        "must hold the ticks of its own period (datasets/LOGDIR.md): write the differences "
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
    at = np.interp(np.asarray(streams.wheel_t) - 0.5 * robot.chassis.encode_sampling_time,
                   streams.imu_t, rate)
    # per second of driving: a frame's few ticks are mostly their quantisation (a healthy
    # 20 s run correlated by 0.36 frame by frame)
    bins = np.floor((np.asarray(streams.wheel_t) - streams.wheel_t[0]) / SIGN_WINDOW)
    edges = np.flatnonzero(np.diff(bins)) + 1
    left, right = (np.add.reduceat(ticks[:, k], np.r_[0, edges]) for k in (0, 1))
    gyro = np.add.reduceat(at, np.r_[0, edges]) / np.diff(np.r_[0, edges, at.size])
    moving = (np.abs(left) >= 2) & (np.abs(right) >= 2)
    n = int(np.count_nonzero(moving))
    if n < MIN_WINDOWS:
        return []
    # the turn is right minus left; with one count negated it is their sum. Correlations
    # leave out the gyro's bias and any scale (a wrong speed_ratio, a skid-steer's track):
    # a first version compared rates and called a slow scan in place, and a speed_ratio in
    # mm, flipped wheels (a review's cases)
    left, right, gyro = left[moving], right[moving], gyro[moving]
    diff, total = _correlation(gyro, right - left), _correlation(gyro, right + left)
    if not (abs(total) >= SIGN_CORRELATION and abs(total) >= abs(diff) + SIGN_MARGIN):
        return []
    side = "left" if total > 0 else "right"
    return [TrustWarning(
        "wheel_sign",
        f"the gyro's yaw rate follows the sum of the wheels' counts (correlation "
        f"{abs(total):.2f}), not their difference ({abs(diff):.2f}), over {n} s of driving: "
        f"one wheel's count has its sign flipped, the {side} one (a mirrored motor or "
        f"encoder); negate its column",
        {"sum_correlation": total, "difference_correlation": diff, "windows": float(n)})]


def _correlation(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """Pearson correlation, 0 where either does not vary."""
    if not (np.std(a) > 0 and np.std(b) > 0):
        return 0.0
    return float(np.corrcoef(a, b)[0, 1])
