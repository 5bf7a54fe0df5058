"""Oracle of the yaw rate the pipeline gives its EKF with tilt compensation, written here from
the policy stated in ``FusionPipeline._bias_leak`` (fusion/pipeline/core.py), not from its array
code: one sample at a time in arrival order, the rate about the world vertical
(``vertical_rate``) minus the change, since rest, of the horizontal gyro bias's leak through
the projection, ``bx*(r20 - r20_rest) + by*(r21 - r21_rest)``. ``bx, by`` and
``r20_rest, r21_rest`` are the means of the base x, y gyro rates and of the world vertical's
base x, y components over the samples so far (this one included) at which the robot stood
still: the IMU's motion code still, and the newest wheel frame or twist that arrived before the
sample (at equal stamps the IMU sample arrives first) at most ``gap_periods`` (2.5) wheel
periods old with
``|v| <= EkfNoise.twist_zero_v`` and ``|w| <= twist_zero_w``. Nothing is taken off before the
first such sample.
"""

from __future__ import annotations

import numpy as np

from fusion.geometry.kinematics import ticks_to_twist
from fusion.geometry.mount import vertical_rate
from fusion.planar.imu_motion import MOTION_STILL
from fusion.planar.robot import RobotConfig

__all__ = ["tilt_rate_by_hand"]


def tilt_rate_by_hand(robot: RobotConfig, imu_t, gyro, q, codes, wheel_t=(), ticks=(),
                      twist_t=(), twist_v=(), twist_w=(), *, gap_periods: float = 2.5
                      ) -> np.ndarray:
    """(N,) rad/s: the EKF's yaw-rate input for base-frame ``gyro`` (rad/s) with attitudes
    ``q`` ([w, x, y, z]) and IMU motion ``codes`` at stamps ``imu_t`` (s), given the wheel
    frames (``wheel_t`` s, ``ticks`` per period) and twists (``twist_t`` s, ``twist_v`` m/s,
    ``twist_w`` rad/s), all of them accepted by the pipeline (in order, finite), with the
    pipeline's ``gap_periods``."""
    period = robot.chassis.encode_sampling_time
    events = sorted([(float(t), 0, i) for i, t in enumerate(imu_t)]
                    + [(float(t), 1, i) for i, t in enumerate(wheel_t)]
                    + [(float(t), 2, i) for i, t in enumerate(twist_t)])
    newest = None  # (stamp, v, w) of the newest wheel frame or twist
    sums = [0.0, 0.0, 0.0, 0.0]  # bx, by, r20, r21 over the still samples
    count = 0
    out = np.empty(len(imu_t))
    for t, kind, i in events:
        if kind == 1:
            v, w = ticks_to_twist(int(ticks[i][0]), int(ticks[i][1]), robot.chassis)
            newest = (t, v, w)
            continue
        if kind == 2:
            newest = (t, float(twist_v[i]), float(twist_w[i]))
            continue
        qw, qx, qy, qz = (float(c) for c in q[i])
        n2 = qw * qw + qx * qx + qy * qy + qz * qz
        r20 = 2.0 * (qx * qz - qw * qy) / n2
        r21 = 2.0 * (qy * qz + qw * qx) / n2
        if (codes[i] == MOTION_STILL and newest is not None
                and t - newest[0] <= gap_periods * period
                and abs(newest[1]) <= robot.ekf.twist_zero_v
                and abs(newest[2]) <= robot.ekf.twist_zero_w):
            for k, value in enumerate((float(gyro[i][0]), float(gyro[i][1]), r20, r21)):
                sums[k] += value
            count += 1
        rate = float(vertical_rate(np.asarray(gyro[i], dtype=float), np.asarray(q[i])))
        if count:
            bx, by, m20, m21 = (s / count for s in sums)
            rate -= bx * (r20 - m20) + by * (r21 - m21)
        out[i] = rate
    return out
