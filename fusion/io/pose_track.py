"""The track a bag's odometry poses draw, from its first pose, across the driver's resets.

A driver that restarts (or a ``/set_pose`` call) starts its pose again at the origin while the
robot stands elsewhere. Drawn as published, the bag's odometry then jumps back to where it
started, and every figure scored on it (its RMSE against GPS, the plot) mixes two tracks: the
probe bag re-zeroed at 150 s scored the bag's odometry 21.23 m off GPS against 19.57 m
untouched, nothing said. :func:`own_track` splices a reset out: a step between two poses
longer than the robot can travel in that interval (:data:`RESET_STEP` m plus three times
what its twist, or its poses' median speed, allows) or a turn beyond what its yaw rate allows
(:data:`RESET_TURN` rad plus three times) is a reset if the poses a second later have not come
back to the track before it (misordered or scattered poses do), and the poses after it are
moved so that the first of them continues the one before by the twist over that interval.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from fusion.geometry.angles import wrap_angle

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
    """The spliced track of poses (``x``, ``y`` m, ``yaw`` rad at ``t`` s) with their twists
    (``v`` m/s, ``w`` rad/s; module docstring)."""
    t, x, y, yaw, v, w = (np.asarray(a, dtype=float) for a in (t, x, y, yaw, v, w))
    n = t.size
    resets: list[float] = []
    # the pose frame after each reset, as (angle, offset) taking it into the first frame
    a, ox, oy = 0.0, 0.0, 0.0
    px, py, pyaw = x.copy(), y.copy(), yaw.copy()
    if n >= 2:
        step = np.hypot(np.diff(x), np.diff(y))
        moving = np.diff(t) > 0
        pose_speed = float(np.median(step[moving] / np.diff(t)[moving])) if moving.any() else 0.0
        for i in range(1, n):
            dt = max(t[i] - t[i - 1], 0.0)
            speed = max(abs(v[i - 1]), abs(v[i]), pose_speed)
            turn = abs(float(wrap_angle(yaw[i] - yaw[i - 1])))
            jumped = (step[i - 1] > RESET_STEP + 3.0 * speed * dt
                      or turn > RESET_TURN + 3.0 * max(abs(w[i - 1]), abs(w[i])) * dt)
            if jumped and _stays(t, x, y, yaw, i, speed):
                # the pose the twist predicts (an arc), in the first frame
                half = 0.5 * w[i - 1] * dt
                chord = v[i - 1] * dt * (math.sin(half) / half if half else 1.0)
                th = pyaw[i - 1] + w[i - 1] * dt
                ex = px[i - 1] + chord * math.cos(pyaw[i - 1] + half)
                ey = py[i - 1] + chord * math.sin(pyaw[i - 1] + half)
                a = th - yaw[i]
                c, s = math.cos(a), math.sin(a)
                ox, oy = ex - (c * x[i] - s * y[i]), ey - (s * x[i] + c * y[i])
                resets.append(float(t[i]))
            if resets:
                c, s = math.cos(a), math.sin(a)
                px[i], py[i] = ox + c * x[i] - s * y[i], oy + s * x[i] + c * y[i]
                pyaw[i] = yaw[i] + a
    if n == 0:
        return OwnTrack(np.zeros((0, 3)))
    c0, s0 = math.cos(pyaw[0]), math.sin(pyaw[0])
    dx, dy = px - px[0], py - py[0]
    track = np.column_stack([c0 * dx + s0 * dy, -s0 * dx + c0 * dy, wrap_angle(pyaw - pyaw[0])])
    return OwnTrack(track, resets)


def _stays(t, x, y, yaw, i: int, speed: float) -> bool:
    """Whether the jump into pose ``i`` holds: :data:`SETTLE` s later the poses have not come
    back to where the ones before it (``i - 1``, or ``i - 2`` if ``i - 1`` was a lone stray)
    were, or were heading, within :data:`RESET_STEP` plus the travel since (misordered or
    scattered poses come back; a reset's new frame does not)."""
    j = min(int(np.searchsorted(t, t[i] + SETTLE)), t.size - 1)
    for r in (i - 1, i - 2):
        if r < 0:
            continue
        span = t[j] - t[r]
        tol = RESET_STEP + speed * span
        ex = x[r] + speed * span * math.cos(yaw[r])
        ey = y[r] + speed * span * math.sin(yaw[r])
        if min(math.hypot(x[j] - x[r], y[j] - y[r]), math.hypot(x[j] - ex, y[j] - ey)) <= tol:
            return False
    return True
