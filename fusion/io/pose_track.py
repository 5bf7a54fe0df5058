"""The track a bag's odometry poses draw, from its first pose, across the driver's resets.

A driver that restarts (or a ``/set_pose`` call) starts its pose again at the origin while the
robot stands elsewhere. Drawn as published, the bag's odometry then jumps back to where it
started, and every figure scored on it (its RMSE against GPS, the plot) mixes two tracks: the
probe bag re-zeroed at 150 s scored the bag's odometry 21.23 m off GPS against 19.57 m
untouched, nothing said. :func:`own_track` splices a reset out: a step between two poses
longer than the robot can travel in that interval (:data:`RESET_STEP` m plus three times
what its twist, or its poses' speed just before and after, allows; across a gap, the fastest
it drove) or, over an interval of
:data:`SETTLE` s or less, a turn beyond what its yaw rate allows (:data:`RESET_TURN` rad plus
three times) is a reset if the poses a second later have not come back to the track of the
second before it (misordered or stray poses do; so a reset of the heading alone, the position
kept, is not found), and the poses after it are moved so that the first of them continues
the one before by the poses' own motion over the interval before (whatever the twist's signs,
or an empty twist; across a gap, extrapolated over it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fusion.geometry.angles import wrap_angle
from fusion.geometry.dead_reckoning import motion_between

__all__ = ["RESET_STEP", "RESET_TURN", "OwnTrack", "own_track"]

#: m: a step between consecutive poses beyond this (plus three times the travel the
#: speeds allow) is a reset of the driver's pose.
RESET_STEP = 1.0
#: rad: a turn between consecutive poses beyond this (plus three times the yaw rate's) is one.
RESET_TURN = 0.5
#: s: a jump is a reset only if the poses this long after it have not come back (:func:`_stays`).
SETTLE = 1.0


@dataclass
class OwnTrack:
    """The odometry's poses from its first one: ``track`` (K, 3) x m, y m, yaw rad (the first
    pose at the origin, facing x), ``resets`` the stamps (s) of the poses after a reset."""

    track: NDArray[np.float64]
    resets: list[float] = field(default_factory=list)

    @property
    def note(self) -> str:
        """What to tell the user ("" without a reset)."""
        if not self.resets:
            return ""
        at = ", ".join(f"{t:.3f}" for t in self.resets[:5])
        more = f" and {len(self.resets) - 5} more" if len(self.resets) > 5 else ""
        return (f"the odometry's pose jumped further than the robot can move at {at} s{more} "
                "(a driver restart or a pose reset): its track continues across each jump "
                "by the twist")


def own_track(t, x, y, yaw, v, w) -> OwnTrack:
    """The spliced track of poses (``x``, ``y`` m, ``yaw`` rad at ``t`` s, increasing, all
    finite: :func:`fusion.io.bags.read_bag` refuses others) with their twists (``v`` m/s,
    ``w`` rad/s; module docstring)."""
    t, x, y, yaw, v, w = (np.asarray(a, dtype=float) for a in (t, x, y, yaw, v, w))
    n = t.size
    if n == 0:
        return OwnTrack(np.zeros((0, 3)))
    resets: list[float] = []
    # the pose frame after the latest reset, as (angle, offset) taking it into the first frame
    a, ox, oy = 0.0, 0.0, 0.0
    px, py, pyaw = x.copy(), y.copy(), yaw.copy()
    dts = np.diff(t)
    step = np.hypot(np.diff(x), np.diff(y))
    with np.errstate(divide="ignore", invalid="ignore"):
        pose_speed = np.where(dts > 0, step / dts, 0.0)  # per interval, m/s
    short = (dts > 0) & (dts <= SETTLE)
    # across a gap the robot may have driven at any speed it ever did
    top = max(float(np.max(np.abs(v))), float(np.percentile(pose_speed[short], 99))
              if short.any() else 0.0)
    for i in range(1, n):
        dt = max(float(dts[i - 1]), 0.0)
        # what the robot can travel: its twist, or its poses' speed just before and after
        near = [pose_speed[k] for k in (i - 2, i) if 0 <= k < n - 1]
        speed = max([abs(v[i - 1]), abs(v[i]), *near, top if dt > SETTLE else 0.0])
        turn = abs(float(wrap_angle(yaw[i] - yaw[i - 1])))
        # (across a gap the robot may have turned any way: only the step tells there)
        jumped = (step[i - 1] > RESET_STEP + 3.0 * speed * dt
                  or (dt <= SETTLE
                      and turn > RESET_TURN + 3.0 * max(abs(w[i - 1]), abs(w[i])) * dt))
        if jumped and _stays(t, x, y, yaw, i, speed):
            d, dtheta = _motion_over(t, x, y, yaw, v, w, i)
            half = 0.5 * dtheta
            chord = d * (math.sin(half) / half if half else 1.0)
            ex = px[i - 1] + chord * math.cos(pyaw[i - 1] + half)
            ey = py[i - 1] + chord * math.sin(pyaw[i - 1] + half)
            a = pyaw[i - 1] + dtheta - yaw[i]
            c, s = math.cos(a), math.sin(a)
            ox, oy = ex - (c * x[i] - s * y[i]), ey - (s * x[i] + c * y[i])
            resets.append(float(t[i]))
        if resets:
            c, s = math.cos(a), math.sin(a)
            px[i], py[i] = ox + c * x[i] - s * y[i], oy + s * x[i] + c * y[i]
            pyaw[i] = yaw[i] + a
    c0, s0 = math.cos(pyaw[0]), math.sin(pyaw[0])
    dx, dy = px - px[0], py - py[0]
    track = np.column_stack([c0 * dx + s0 * dy, -s0 * dx + c0 * dy, wrap_angle(pyaw - pyaw[0])])
    return OwnTrack(track, resets)


def _motion_over(t, x, y, yaw, v, w, i: int) -> tuple[float, float]:
    """``(travel m, turn rad)`` over the reset interval ``i - 1 -> i``: the poses' own motion
    over the interval before, scaled to this one's length (the same in any pose frame, and
    whatever the twist's signs or emptiness), or the twist's where there is none."""
    dt = max(float(t[i] - t[i - 1]), 0.0)
    if i >= 2 and t[i - 1] > t[i - 2]:
        d, dtheta, _ = motion_between(x[i - 2:i], y[i - 2:i], yaw[i - 2:i])
        share = dt / float(t[i - 1] - t[i - 2])
        return float(d[0]) * share, float(dtheta[0]) * share
    return float(v[i - 1]) * dt, float(w[i - 1]) * dt


def _stays(t, x, y, yaw, i: int, speed: float) -> bool:
    """Whether the jump into pose ``i`` holds: :data:`SETTLE` s later the poses have not come
    back to where any pose of the :data:`SETTLE` s before it was, or was heading, within
    :data:`RESET_STEP` plus the travel since (misordered or stray poses come back; a reset's
    new frame does not). Positions only: a reset of the heading alone is not found."""
    j = min(int(np.searchsorted(t, t[i] + SETTLE)), t.size - 1)
    first = min(int(np.searchsorted(t, t[i] - SETTLE)), i - 1)
    for r in range(first, i):
        span = t[j] - t[r]
        tol = RESET_STEP + speed * span
        ex = x[r] + speed * span * math.cos(yaw[r])
        ey = y[r] + speed * span * math.sin(yaw[r])
        if min(math.hypot(x[j] - x[r], y[j] - y[r]), math.hypot(x[j] - ex, y[j] - ey)) <= tol:
            return False
    return True
