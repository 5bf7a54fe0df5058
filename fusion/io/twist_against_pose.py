"""Does a nav_msgs/Odometry topic's twist move the way its own pose does?

A driver integrates its pose from the same wheel speeds it publishes as the twist, so over
each interval between messages the twist's travel (the mean of the two forward speeds times
the interval) and turn (the same of the yaw rates) should equal the pose's
(:func:`fusion.geometry.dead_reckoning.motion_between`). A driver that flips the sign of one
(a motor wired the other way round and corrected in the pose only, a yaw-rate sign
convention) publishes a twist that runs against its pose: the fusion takes the twist, so
the fused track comes out turned by 180 deg (a GPS alignment hides that) or turning the
other way, with only a heading disagreement to show for it.

:func:`twist_against_pose` measures the agreement: per quantity, the cosine between the
twist's and the pose's per-interval motion (1: the same direction interval by interval, -1:
opposite) and their least-squares ratio, over the intervals of at most
:data:`fusion.io.odometry_motion.MAX_GAP_PERIODS` periods whose poses did not jump sideways.
Nothing is compared unless the pose travelled :data:`MIN_PATH` m (or turned :data:`MIN_TURN`
rad): a driver that publishes the twist and leaves the pose at zero says nothing.
:data:`OPPOSITE_COSINE` is the verdict's threshold. Which of the two is wrong the odometry
cannot tell; :mod:`fusion.jobs.odometry_signs` asks the IMU.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from fusion.geometry.dead_reckoning import motion_between
from fusion.io.odometry_motion import (
    JUMP_LATERAL_FLOOR,
    JUMP_LATERAL_SHARE,
    MAX_GAP_PERIODS,
    message_period,
)

if TYPE_CHECKING:
    from fusion.io.bags import OdometryLog

__all__ = ["MIN_PATH", "MIN_TURN", "OPPOSITE_COSINE", "TwistPoseFit", "fit_of",
           "twist_against_pose"]

#: m: the pose's travel (summed over the intervals compared) below which the speeds are not
#: compared (a robot that stood, a driver leaving the pose at zero).
MIN_PATH = 1.0
#: rad: the same for the yaw rates.
MIN_TURN = 1.0
#: A cosine at or below minus this says the twist runs against the pose (a sign flipped in
#: one of them); noise, slip corrections and stamp jitter leave it near +1.
OPPOSITE_COSINE = 0.9


@dataclass(frozen=True)
class TwistPoseFit:
    """The twist's motion against its pose's, interval by interval.

    Attributes:
        path: m, the pose's travel over the intervals compared (sum of |d|).
        turn: rad, the same for its turns.
        speed_cosine, rate_cosine: cosine between the twist's and the pose's per-interval
            travel (turn): +1 the same direction throughout, -1 opposite; NaN when the pose
            travelled less than :data:`MIN_PATH` (turned less than :data:`MIN_TURN`).
        speed_ratio, rate_ratio: the twist's travel (turn) over the pose's, least squares
            through zero (NaN as the cosines).
        intervals: intervals compared.
    """

    path: float
    turn: float
    speed_cosine: float
    speed_ratio: float
    rate_cosine: float
    rate_ratio: float
    intervals: int

    @property
    def speed_opposite(self) -> bool:
        """The twist's forward speed runs against the pose's travel."""
        return bool(self.speed_cosine <= -OPPOSITE_COSINE)

    @property
    def rate_opposite(self) -> bool:
        """The twist's yaw rate turns against the pose's heading."""
        return bool(self.rate_cosine <= -OPPOSITE_COSINE)


def twist_against_pose(t: NDArray[np.float64], x: NDArray[np.float64],
                       y: NDArray[np.float64], yaw: NDArray[np.float64],
                       v: NDArray[np.float64], w: NDArray[np.float64]) -> TwistPoseFit:
    """Compare the twist (forward speed ``v`` m/s, yaw rate ``w`` rad/s) with the pose
    (``x``, ``y`` m, ``yaw`` rad) of the same N messages stamped ``t`` (s, sorted); see the
    module docstring."""
    arrays = [np.asarray(a, dtype=float).reshape(-1) for a in (t, x, y, yaw, v, w)]
    if len({a.size for a in arrays}) != 1:
        raise ValueError("t, x, y, yaw, v and w must have the same length, got "
                         + ", ".join(str(a.size) for a in arrays))
    finite = np.all(np.isfinite(np.stack(arrays)), axis=0)
    t, x, y, yaw, v, w = (a[finite] for a in arrays)
    nan = math.nan
    if t.size < 3:
        return TwistPoseFit(0.0, 0.0, nan, nan, nan, nan, 0)
    d, dtheta, lateral = motion_between(x, y, yaw)
    dt = np.diff(t)
    keep = ((dt > 0.0) & (dt <= MAX_GAP_PERIODS * message_period(t))
            & (np.abs(lateral) <= JUMP_LATERAL_SHARE * np.abs(d) + JUMP_LATERAL_FLOOR))
    travel = 0.5 * (v[1:] + v[:-1]) * dt
    turned = 0.5 * (w[1:] + w[:-1]) * dt
    d, dtheta, travel, turned = d[keep], dtheta[keep], travel[keep], turned[keep]
    path, turn = float(np.sum(np.abs(d))), float(np.sum(np.abs(dtheta)))
    speed = _agreement(travel, d) if path >= MIN_PATH else (nan, nan)
    rate = _agreement(turned, dtheta) if turn >= MIN_TURN else (nan, nan)
    return TwistPoseFit(path, turn, *speed, *rate, int(np.count_nonzero(keep)))


def _agreement(twist: NDArray[np.float64], pose: NDArray[np.float64]) -> tuple[float, float]:
    """(cosine, ratio) of the twist's per-interval motion against the pose's."""
    pp = float(np.dot(pose, pose))
    tt = float(np.dot(twist, twist))
    tp = float(np.dot(twist, pose))
    if not (pp > 0.0 and tt > 0.0):
        return (math.nan, math.nan) if pp == 0.0 else (0.0, 0.0)
    return tp / math.sqrt(pp * tt), tp / pp


def fit_of(odom: OdometryLog, v: NDArray[np.float64] | None = None) -> TwistPoseFit:
    """:func:`twist_against_pose` of an odometry log, with ``v`` (m/s, one per message) in
    place of its ``linear.x`` when given (a forward speed turned from frame_id)."""
    return twist_against_pose(odom.t, odom.x, odom.y, odom.yaw,
                              odom.v if v is None else v, odom.w)
