"""Oracle of the pipeline's default attitude, written here from the policy stated in
fusion/pipeline/core.py (not from its array code): Keel's streaming ``update`` over the IMU
samples in arrival order, told by the newest wheel frame or twist that arrived before each
sample (at equal stamps the IMU sample arrives first), if that is at most 2.5 wheel periods
old: the known acceleration (forward: the change of v since the source's previous event over
the wheel period, or over the stamp difference for a twist, 0 for the first event and after a
gap of more than 2.5 periods; centripetal ``v*w`` along +y with ``w`` the sample's own gyro
rate about z, not the wheels'), and stillness (False while v or w is not zero; True while
both are zero and the IMU is quiet; else unknown).
"""

from __future__ import annotations

import math

import numpy as np

from fusion.attitude.keel import Keel
from fusion.geometry.kinematics import ticks_to_twist
from fusion.planar.robot import RobotConfig

__all__ = ["keel_by_hand"]


def keel_by_hand(robot: RobotConfig, imu_t, gyro, accel, wheel_t=(), ticks=(), twist_t=(),
                 twist_v=(), twist_w=(), *, sample_period: float = 0.01,
                 knowledge: bool = True) -> np.ndarray:
    """(N, 4) attitudes of the base-frame ``gyro`` (rad/s) and ``accel`` (m/s^2) at stamps
    ``imu_t`` (s), with what the wheel frames (``wheel_t`` s, ``ticks`` per period) and
    twists (``twist_t`` s, ``twist_v`` m/s, ``twist_w`` rad/s) tell (nothing if not
    ``knowledge``)."""
    keel = Keel(sample_period=sample_period)
    par = keel.params
    period = robot.chassis.encode_sampling_time
    events = sorted([(float(t), 0, i) for i, t in enumerate(imu_t)]
                    + [(float(t), 1, i) for i, t in enumerate(wheel_t)]
                    + [(float(t), 2, i) for i, t in enumerate(twist_t)])
    newest = None  # (stamp, v, w, forward acceleration)
    previous = {1: (-math.inf, 0.0), 2: (-math.inf, 0.0)}  # per source: (stamp, v)
    out = np.empty((len(imu_t), 4))
    for t, kind, i in events:
        if kind in (1, 2):
            if kind == 1:
                v, w = ticks_to_twist(int(ticks[i][0]), int(ticks[i][1]), robot.chassis)
            else:
                v, w = float(twist_v[i]), float(twist_w[i])
            t0, v0 = previous[kind]
            acc = 0.0
            if t - t0 <= 2.5 * period:
                acc = (v - v0) / (period if kind == 1 else t - t0)
            previous[kind] = (t, v)
            newest = (t, v, w, acc)
        else:
            g, a = np.asarray(gyro[i], dtype=float), np.asarray(accel[i], dtype=float)
            still = known = None
            if knowledge and newest is not None and t - newest[0] <= 2.5 * period:
                _, v, w, acc = newest
                known = np.array([acc, v * g[2], 0.0])
                quiet = (math.sqrt(g @ g) < par.bias_clip + par.rest_gyro_threshold
                         and abs(math.sqrt(a @ a) - par.gravity) < par.rest_accel_threshold)
                if v != 0.0 or w != 0.0:
                    still = False
                elif quiet:
                    still = True
            out[i] = keel.update(g, a, timestamp=t, still=still, known_accel=known)
    return out
