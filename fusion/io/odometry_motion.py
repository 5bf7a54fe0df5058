"""The motion a nav_msgs/Odometry topic reports, as the fusion takes it: its twist, or, where
a driver leaves the twist empty or writes it in the wrong frame, the motion its poses show.

nav_msgs/Odometry (REP-105) holds the pose of ``child_frame_id`` in ``frame_id`` and the twist
in ``child_frame_id``: ``linear.x`` forward, ``angular.z`` the yaw rate. Two departures seen
in drivers are recognised from the data, and said (:attr:`OdometryMotion.note`):

- **The twist is empty** (every ``linear.x``, ``linear.y`` and ``angular.z`` exactly 0) while
  the pose moves (gets :data:`MIN_POSE_PATH` m or :data:`MIN_POSE_TURN` rad away from the
  first): a driver that publishes its dead-reckoned pose only. Taken as it is, every message
  reads "standing still": a terrain benchmark bag rewritten that way replayed to a path of
  0 m, with zero-velocity updates while the robot drove and a gyro bias of +3.2 deg/s. The
  twist is then the motion between consecutive poses
  (:func:`fusion.geometry.dead_reckoning.motion_between`, the exact inverse of an arc),
  over each interval's duration, stamped at its middle; intervals longer than
  :data:`MAX_GAP_PERIODS` times the median are left out (their mean speed is no rate of
  any instant), and so are repeated stamps, non-finite poses and pose jumps (an interval that
  moves across the heading, :data:`JUMP_LATERAL_SHARE`, by more than the poses' own
  sideways noise). Poses that scatter make single-interval speeds wrong by tens of percent:
  stamps (record times, ``--stamps bag``: on the bundled Jackal bag they lag the header
  stamps by 8 ms RMS on a 20 ms period, with repeats; the fused path came out 54.7 m of
  83.8), positions (a driver whose pose is noisy: the Jackal bag's with 1 cm of noise
  added, 839 intervals taken for jumps and a path of 90.3 m) or headings. The scatter is
  measured (:func:`stamp_jitter`; the sideways steps a differential drive cannot make, less
  what a driver's integration rule leaves in turns; the heading's second differences over
  one and two intervals, in which turning cancels), and the twist is then the least-squares
  slope of travel and heading against time over a window sized for errors of 2 % of the
  speed, 0.02 m/s and 0.01 rad/s (:func:`slope_half_width`), stamped at each pose (at the
  window's mean time where a run's end cuts it short): 83.7 and 83.8 m. Limits: the sizing
  takes the scatter as independent from pose to pose (the Jackal's record times wander, and
  their second differences read 3.5 ms: the speeds there err by about 5 % RMS, the path by
  0.1 %) and leaves out the smoothing of the robot's own changes; position noise along the
  track alone does not show in the sideways steps.
  A turn of more than pi between two poses cannot be told from one the other way; turns
  above :data:`ALIAS_TURN` are said.
- **The twist's linear velocity is in ``frame_id``** (the odometry frame) instead of the
  robot's: then a differential drive seems to move sideways, by about as much as forward,
  and turning it by the pose's heading makes the sideways part vanish. Recognised when over
  the moving messages the sideways speed's RMS is above :data:`LATERAL_SHARE` of the speed's
  and, turned by the heading, below :data:`ROTATED_LATERAL_SHARE` of it; the forward speed
  is then the turned one, once the heading has ranged over :data:`MIN_HEADING_RANGE` (a
  holonomic base strafing at a constant heading would pass both tests).

Anything else is taken as the driver wrote it (``source`` ``"twist"``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from fusion.geometry.dead_reckoning import motion_between
from fusion.io.pose_track import own_track

if TYPE_CHECKING:
    from fusion.io.bags import OdometryLog

__all__ = [
    "ALIAS_TURN",
    "BURST_SHARE",
    "JUMP_LATERAL_FLOOR",
    "JUMP_LATERAL_SHARE",
    "LATERAL_SHARE",
    "MAX_GAP_PERIODS",
    "MAX_SLOPE_HALF_WIDTH",
    "MIN_HEADING_RANGE",
    "MIN_MOVING",
    "MIN_POSE_PATH",
    "MIN_POSE_TURN",
    "MIN_SLOPE_PERIODS",
    "MOVING_SPEED",
    "OUTLIER_SIGMAS",
    "ROTATED_LATERAL_SHARE",
    "SLOPE_RATE_ERROR",
    "SLOPE_RELATIVE_ERROR",
    "SLOPE_SPEED_ERROR",
    "OdometryMotion",
    "message_period",
    "odometry_motion",
    "slope_half_width",
    "stamp_jitter",
]

#: m: how far the poses must get from the first for an empty twist to be a pose-only
#: driver's, not a robot that stood still (noisy or GPS-corrected poses wander by
#: centimetres; summed over their steps that wander adds up, their reach does not).
MIN_POSE_PATH = 0.5
#: rad: the same for the heading (turning on the spot).
MIN_POSE_TURN = 0.5
#: Pose intervals longer than this many times the median interval are left out.
MAX_GAP_PERIODS = 3.0
#: A pose interval whose displacement across the heading exceeds this share of its travel
#: (plus :data:`JUMP_LATERAL_FLOOR`) is a jump of the pose (a reset, a correction), not motion
#: of a wheeled base: left out.
JUMP_LATERAL_SHARE = 0.2
#: m: the same, an absolute allowance (pose rounding).
JUMP_LATERAL_FLOOR = 0.01
#: rad: the heading must range over at least this on the moving messages before a sideways
#: velocity can be told to be written in frame_id (with a constant heading a holonomic base's
#: strafe looks the same).
MIN_HEADING_RANGE = 0.5
#: m/s: a message moves when its planar speed (linear.x, linear.y) exceeds this.
MOVING_SPEED = 0.05
#: Sideways speed RMS over the speed's, above which the twist may be in frame_id.
LATERAL_SHARE = 0.3
#: The same after turning the velocity by the pose's heading, below which it is.
ROTATED_LATERAL_SHARE = 0.1
#: Moving messages needed before the frame test says anything.
MIN_MOVING = 10
#: Poses are differenced over single intervals (the exact inverse of the driver's
#: integration) unless their scatter needs a slope over more than this many periods either
#: side to meet the errors below (:func:`slope_half_width`).
MIN_SLOPE_PERIODS = 1.5
#: The relative error of a speed the slope window is sized for (against the stamps' scatter).
SLOPE_RELATIVE_ERROR = 0.02
#: m/s: the speed error the slope window is sized for against the positions' noise.
SLOPE_SPEED_ERROR = 0.02
#: rad/s: the yaw-rate error the slope window is sized for against the headings' noise.
SLOPE_RATE_ERROR = 0.01
#: A median interval below this share of the mean one means stamps in bursts
#: (:func:`message_period`).
BURST_SHARE = 0.5
#: Standard deviations (robust, from the median absolute deviation) beyond which a value is
#: an outlier of its noise: a pose interval whose sideways step exceeds this many of the
#: poses' sideways noise can be a jump; a stamp's second difference this far out is a
#: dropped message, not scatter.
OUTLIER_SIGMAS = 5.0
#: s: the slope window's largest half-width (longer smooths away the robot's own changes).
MAX_SLOPE_HALF_WIDTH = 0.5
#: rad: a turn between consecutive poses above this is said (past pi it aliases).
ALIAS_TURN = 0.75 * np.pi


@dataclass(frozen=True)
class OdometryMotion:
    """Twists for the fusion: ``t`` (s), forward speed ``v`` (m/s) and yaw rate ``w``
    (rad/s), (K,) each; ``source``: ``"twist"`` (as written), ``"pose"`` (from consecutive
    poses) or ``"twist in frame_id"`` (linear velocity turned by the heading); ``note``: a
    sentence for the user when it is not ``"twist"``, else ``""``."""

    t: NDArray[np.float64]
    v: NDArray[np.float64]
    w: NDArray[np.float64]
    source: str = "twist"
    note: str = ""


def odometry_motion(odom: OdometryLog) -> OdometryMotion:
    """The twists of ``odom`` the fusion should take (module docstring)."""
    name = odom.topic or "the odometry"
    empty = not (np.any(odom.v) or np.any(odom.vy) or np.any(odom.w))
    if empty and len(odom) >= 2:
        from_pose = _pose_motion(odom, name)
        if from_pose is not None:
            return from_pose
    turned = _turned_to_robot(odom, name)
    if turned is not None:
        return turned
    return OdometryMotion(odom.t, odom.v, odom.w)


def _pose_motion(odom: OdometryLog, name: str) -> OdometryMotion | None:
    """The twist between consecutive poses, or None when the poses hardly move."""
    finite = (np.isfinite(odom.t) & np.isfinite(odom.x) & np.isfinite(odom.y)
              & np.isfinite(odom.yaw))
    _, first = np.unique(odom.t[finite], return_index=True)  # sorted stamps: drop repeats
    t, x, y, yaw = (a[finite][first] for a in (odom.t, odom.x, odom.y, odom.yaw))
    if len(t) < 2:
        return None
    d, dtheta, lateral = motion_between(x, y, yaw)
    reach = float(np.max(np.hypot(x - x[0], y - y[0])))
    swing = float(np.max(np.abs(np.cumsum(dtheta))))
    if reach < MIN_POSE_PATH and swing < MIN_POSE_TURN:
        return None
    dt = np.diff(t)
    # the message rate, repeated stamps included (they are messages recorded at once)
    period = message_period(odom.t[finite])
    jitter = stamp_jitter(t, period)
    keep = dt <= MAX_GAP_PERIODS * period
    # a driver's pose reset (back to its origin) is no motion: along the track it is no
    # sideways jump, and was taken as one interval of -249 m/s (a straight drive re-zeroed
    # 54 m out) or 144 m/s and 21 rad/s (an arc)
    reset = np.zeros(dt.size, dtype=bool)
    starts = own_track(t, x, y, yaw, np.zeros_like(t), np.zeros_like(t)).resets
    reset[np.searchsorted(t, starts) - 1] = True
    gaps = int(np.count_nonzero(~keep))
    resets = int(np.count_nonzero(reset & keep))
    keep &= ~reset
    # a differential drive never moves sideways: what its poses do is their noise, less the
    # step a driver's integration rule leaves in turns (Euler's: -d dtheta/2), robust to the
    # jumps it also finds; each sideways step holds two poses' noise
    plausible = keep & (np.abs(lateral) <= JUMP_LATERAL_SHARE * np.abs(d) + JUMP_LATERAL_FLOOR)
    sideways = _robust_std(_less_rule(lateral, d * dtheta, plausible)[keep])
    position_noise = sideways / np.sqrt(2.0)
    jumped = np.abs(lateral) > (JUMP_LATERAL_SHARE * np.abs(d) + JUMP_LATERAL_FLOOR
                                + OUTLIER_SIGMAS * sideways)
    jumps = int(np.count_nonzero(jumped & keep))
    keep &= ~jumped
    heading_noise = _heading_noise(dtheta, keep)
    repeats = int(np.count_nonzero(finite)) - len(t)
    left_out = []
    if repeats:
        left_out.append(f"{repeats} repeated stamps")
    if not np.all(finite):
        left_out.append(f"{int(np.count_nonzero(~finite))} poses or stamps not finite")
    if resets:
        left_out.append(f"{resets} pose resets (a jump further than the robot can move)")
    if jumps:
        left_out.append(f"{jumps} pose jumps (sideways, which the base cannot move)")
    if gaps:
        left_out.append(f"{gaps} intervals longer than {MAX_GAP_PERIODS:g} times the "
                        f"{1e3 * period:.0f} ms period")
    halves = {"stamps": slope_half_width(jitter, period, SLOPE_RELATIVE_ERROR),
              "positions": slope_half_width(position_noise, period, SLOPE_SPEED_ERROR),
              "headings": slope_half_width(heading_noise, period, SLOPE_RATE_ERROR)}
    scattered = {k: h > MIN_SLOPE_PERIODS * period for k, h in halves.items()}
    if not any(scattered.values()):
        how = f"consecutive poses ({int(np.count_nonzero(keep))} intervals"
        mid = t[:-1] + 0.5 * dt
        t_out, v, w = mid[keep], d[keep] / dt[keep], dtheta[keep] / dt[keep]
    else:
        half = max(halves[k] for k, on in scattered.items() if on)
        t_out, v, w = _sloped_motion(t, d, dtheta, keep, half, period)
        said = {"stamps": f"the stamps by {1e3 * jitter:.1f} ms RMS about a steady "
                          f"{1e3 * period:.0f} ms period (record times, dropped messages)",
                "positions": f"the positions by {1e3 * position_noise:.1f} mm (sideways "
                             "steps a differential drive cannot make)",
                "headings": f"the headings by {np.degrees(heading_noise):.2f} deg"}
        why = "; ".join(said[k] for k, on in scattered.items() if on)
        how = (f"the poses' least-squares slopes over +-{1e3 * half:.0f} ms, as they scatter "
               f"({why}) ({t_out.size} poses")
    # the path and turns the base made, from the twist taken (noise and jumps are none)
    path = _integrated(t_out, np.abs(v), period)
    turn = _integrated(t_out, np.abs(w), period)
    fastest = float(np.max(np.abs(dtheta[keep]), initial=0.0))
    aliasing = (f"; it turns by up to {np.degrees(fastest):.0f} deg between consecutive poses: "
                "a faster turn would read as one the other way" if fastest > ALIAS_TURN else "")
    note = (f"{name}: every twist is zero while its pose moves (a path of {path:.1f} m, "
            f"turns adding up to {np.degrees(turn):.0f} deg; a driver that publishes the pose "
            f"only): the speed and yaw rate are taken from {how}"
            + (f"; left out: {', '.join(left_out)}" if left_out else "") + ")" + aliasing)
    return OdometryMotion(t_out, v, w, "pose", note)


def message_period(t: NDArray[np.float64]) -> float:
    """s: the period of messages stamped ``t`` (s, sorted or not, repeats counted as
    messages): the median interval, unless the stamps come in bursts (record times of
    messages delivered together), where the median is far shorter than the mean interval
    ``span / (N - 1)``, which is then taken. 0 for fewer than 2 stamps."""
    if t.size < 2:
        return 0.0
    t = np.sort(t)
    dt = np.diff(t)
    positive = dt[dt > 0.0]
    mean = float((t[-1] - t[0]) / (t.size - 1))
    median = float(np.median(positive)) if positive.size else 0.0
    return median if median >= BURST_SHARE * mean else mean


def stamp_jitter(t: NDArray[np.float64], period: float | None = None) -> float:
    """s: the RMS scatter of the stamps ``t`` (s) about a steady rate of one message every
    ``period`` s (default :func:`message_period`), from their second differences
    (``t[k+1] - 2 t[k] + t[k-1]`` has 6 times the variance of independent scatter; a steady
    rate leaves them 0). Those further than :data:`OUTLIER_SIGMAS` robust standard
    deviations (:func:`_robust_std`) from the bulk are left out: a dropped message makes two
    of one period each, which on a clean grid would read as scatter; so are gaps longer than
    :data:`MAX_GAP_PERIODS` periods. Scatter that is correlated from stamp to stamp (a
    transport delay that wanders) reads low. 0 for fewer than 3 distinct stamps."""
    t = np.unique(t)
    if t.size < 3:
        return 0.0
    if period is None:
        period = message_period(t)
    dt = np.diff(t)
    normal = dt <= MAX_GAP_PERIODS * period
    second = np.diff(dt)[normal[:-1] & normal[1:]]
    bulk = second[np.abs(second) <= OUTLIER_SIGMAS * _robust_std(second)]
    return float(np.sqrt(np.mean(bulk ** 2) / 6.0)) if bulk.size else 0.0


def _less_rule(lateral: NDArray[np.float64], turned: NDArray[np.float64],
               use: NDArray[np.bool_]) -> NDArray[np.float64]:
    """``lateral`` less its least-squares fit (over ``use``) on ``turned`` (d dtheta, m rad):
    the sideways step an integration rule leaves in turns, which is no noise."""
    u = turned[use]
    scale = float(np.sum(u * u))
    return lateral - (float(np.sum(u * lateral[use])) / scale * turned if scale > 0 else 0.0)


def _heading_noise(dtheta: NDArray[np.float64], keep: NDArray[np.bool_]) -> float:
    """rad: the scatter of the headings, from the second differences of the heading over one
    and over two intervals (kept ones only): with noise s and a steady angular acceleration a
    their mean squares are 6 s^2 + a^2 T^4 and 6 s^2 + 16 a^2 T^4, so turning, which the
    second alone would read as noise, cancels: s^2 = (16 D1 - D2) / 90. Outliers, which
    the median absolute deviation (turn onsets, resets, a message left out for its repeated
    stamp) leave it as it is."""
    heading = np.concatenate([[0.0], np.cumsum(dtheta)])
    ok = np.concatenate([[False], keep]) & np.concatenate([keep, [False]])  # pose k: both
    k = np.flatnonzero(ok[1:-1]) + 1
    one = heading[k + 1] - 2.0 * heading[k] + heading[k - 1]
    inner = k[(k >= 2) & (k + 2 < heading.size)]
    inner = inner[ok[inner - 1] & ok[inner + 1]]
    two = heading[inner + 2] - 2.0 * heading[inner] + heading[inner - 2]
    d1, d2 = _robust_mean_square(one), _robust_mean_square(two)
    return float(np.sqrt(max(16.0 * d1 - d2, 0.0) / 90.0))


def _robust_mean_square(values: NDArray[np.float64]) -> float:
    """The mean square of ``values`` about 0 as the median absolute deviation tells it (a
    normal spread's variance): outliers up to nearly half of them leave it as it is."""
    return (1.4826 * float(np.median(np.abs(values)))) ** 2 if values.size else 0.0


def _integrated(t: NDArray[np.float64], rate: NDArray[np.float64], period: float) -> float:
    """The integral of ``rate`` sampled at ``t`` (s) by the trapezoid rule, over intervals of
    at most :data:`MAX_GAP_PERIODS` ``period`` s (a gap is none of the motion)."""
    if t.size < 2:
        return 0.0
    dt = np.diff(t)
    step = 0.5 * (rate[1:] + rate[:-1]) * dt
    return float(np.sum(step[dt <= MAX_GAP_PERIODS * period]))


def slope_half_width(scatter: float, period: float, allowed: float) -> float:
    """s: the half-width h of the window over which a least-squares slope of values sampled
    every ``period`` s, each off by ``scatter`` (RMS), errs by ``allowed``: over n = 2h/period
    samples spread evenly across +-h the slope errs by ``scatter * sqrt(3) / (h sqrt(n))``.
    The units pair up: a stamp's scatter (s) with a relative error, a position's (m) with a
    speed error (m/s), a heading's (rad) with a yaw-rate error (rad/s). Clipped to
    [``period``, :data:`MAX_SLOPE_HALF_WIDTH`]."""
    h = (scatter / allowed * np.sqrt(1.5 * period)) ** (2.0 / 3.0)
    return float(np.clip(h, period, MAX_SLOPE_HALF_WIDTH))


def _robust_std(values: NDArray[np.float64]) -> float:
    """The standard deviation of the bulk of ``values`` about their median, from the 90th
    percentile of the absolute deviations (1.645 standard deviations for normal values): up
    to a tenth of outliers (jumps, dropped messages, turn onsets) leave it as it is, and,
    unlike the median absolute deviation, it stays above 0 when most values are exactly
    equal but some scatter (stamps rounded to the millisecond, a few of them late). 0 when
    empty."""
    if values.size == 0:
        return 0.0
    return float(np.quantile(np.abs(values - np.median(values)), 0.9) / 1.6449)


def _sloped_motion(t: NDArray[np.float64], d: NDArray[np.float64],
                   dtheta: NDArray[np.float64], keep: NDArray[np.bool_], half: float,
                   period: float
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """For each pose, the least-squares slopes (m/s, rad/s) of travel and heading over the
    poses within ``half`` s joined to it by kept intervals, stamped at their mean time (where
    a slope is the derivative of a steadily accelerating motion, also in a window cut short
    by the end of a run). Windows with fewer than half the poses of a whole one (``2 half /
    period + 1``, at least 3) are left out: near a run's ends the slope would be noisier than
    it was sized for."""
    run = np.concatenate([[0], np.cumsum(~keep)])      # poses of one run share a number
    travel = np.concatenate([[0.0], np.cumsum(np.where(keep, d, 0.0))])
    heading = np.concatenate([[0.0], np.cumsum(np.where(keep, dtheta, 0.0))])
    lo, hi = np.searchsorted(t, t - half), np.searchsorted(t, t + half, side="right")
    n = np.zeros(t.size)
    st = np.zeros(t.size)
    stt = np.zeros(t.size)
    ss = np.zeros(t.size)
    sts = np.zeros(t.size)
    sh = np.zeros(t.size)
    sth = np.zeros(t.size)
    index = np.arange(t.size)
    reach = int(np.max(np.maximum(index - lo, hi - 1 - index)))
    for k in range(-reach, reach + 1):  # sums about each pose's own stamp: no cancellation
        j = index + k
        inside = (j >= lo) & (j < hi)
        j = np.where(inside, j, index)
        inside &= run[j] == run
        u = np.where(inside, t[j] - t, 0.0)
        n += inside
        st += u
        stt += u * u
        ss += np.where(inside, travel[j] - travel, 0.0)
        sts += u * (travel[j] - travel)
        sh += np.where(inside, heading[j] - heading, 0.0)
        sth += u * (heading[j] - heading)
    spread = n * stt - st * st
    ok = (n >= max(3.0, 0.5 * (2.0 * half / period + 1.0))) & (spread > 0.0)
    spread = np.where(ok, spread, 1.0)
    v = (n * sts - st * ss) / spread
    w = (n * sth - st * sh) / spread
    # a window cut short by its run's (or the log's) end: the slope is the derivative at
    # the window's mean time, not at its pose
    starts = np.flatnonzero(np.concatenate([[True], run[1:] != run[:-1]]))
    ends = np.concatenate([starts[1:], [t.size]]) - 1
    cut = (t - half < t[starts][run - run[0]]) | (t + half > t[ends][run - run[0]])
    stamp = (t + np.where(cut, st / np.maximum(n, 1.0), 0.0))[ok]
    # scattered stamps can put the mean times of neighbouring windows out of order
    order = np.argsort(stamp, kind="stable")
    stamp, v, w = stamp[order], v[ok][order], w[ok][order]
    first = np.concatenate([[True], np.diff(stamp) > 0.0])
    return stamp[first], v[first], w[first]


def _turned_to_robot(odom: OdometryLog, name: str) -> OdometryMotion | None:
    """The forward speed of a linear velocity written in frame_id, or None when it is not."""
    moving = np.hypot(odom.v, odom.vy) > MOVING_SPEED
    if np.count_nonzero(moving) < MIN_MOVING:
        return None
    heading = np.unwrap(odom.yaw[moving])
    if not np.ptp(heading) >= MIN_HEADING_RANGE:
        return None
    speed = float(np.sqrt(np.mean(odom.v[moving] ** 2 + odom.vy[moving] ** 2)))
    lateral = float(np.sqrt(np.mean(odom.vy[moving] ** 2)))
    c, s = np.cos(odom.yaw), np.sin(odom.yaw)
    forward = c * odom.v + s * odom.vy
    turned_lateral = float(np.sqrt(np.mean((-s * odom.v + c * odom.vy)[moving] ** 2)))
    if not (lateral > LATERAL_SHARE * speed and turned_lateral < ROTATED_LATERAL_SHARE * speed):
        return None
    note = (f"{name}: its twist's linear velocity is in {odom.frame_id or 'frame_id'}, not in "
            f"{odom.child_frame_id or 'child_frame_id'} as nav_msgs/Odometry says: sideways "
            f"{100 * lateral / speed:.0f} % of the speed as written, "
            f"{100 * turned_lateral / speed:.0f} % turned by the pose's heading; the forward "
            "speed is the turned one")
    return OdometryMotion(odom.t, forward, odom.w, "twist in frame_id", note)
