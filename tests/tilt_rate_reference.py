"""Oracle of what the pipeline feeds the EKF as its yaw rate (the horizontal gyro bias, the tilt,
the heading's roll term), written here from the policy stated in
``FusionPipeline._rest_gyro_bias``, ``_bias_leak`` and ``_roll_term`` (fusion/pipeline/core.py),
not from their array code: one sample at a time in arrival order. It restates the formulas, so
it checks the streaming/batch machinery, not the geometry (tests/test_mount.py and
tests/test_terrain_replay.py do).

- Still samples: the IMU's motion code still, and the newest wheel frame or twist that arrived
  before the sample (at equal stamps the IMU sample arrives first) at most ``gap_periods``
  (2.5) wheel periods old with ``|v| <= EkfNoise.twist_zero_v`` and ``|w| <= twist_zero_w``.
- The bias learnt at rest: the mean of the base x, y gyro rates over the still samples so far
  (this one included), 0 before the first. The attitude filter is fed the gyro minus it.
- The EKF's yaw rate: before the first still sample, if a wheel frame or twist arrived before
  the sample, the base gyro's z axis; otherwise the rate about the world vertical
  (``vertical_rate``) minus ``bx*r20 + by*r21``, ``(r20, r21)`` the world vertical's base x, y
  components, plus the
  heading's extra term ``roll_dot * (sin(pitch) - sin_pitch_rest)``: the roll change since the
  previous sample (wrapped) times the mean of the two samples' ``sin(pitch) = -r20`` less the
  mean of ``sin(pitch)`` over the still samples so far, over their interval (0 at the first
  sample and until the first still sample).
- The wheel frames the EKF is given (``FusionPipeline``'s ``HeadingFrame``): a frame stamped
  ``t`` with a tick on either wheel, and IMU samples stamped in ``(t - period, t]``, gets the
  twist ``(v * mean cos(pitch), w + mean(rate - gyro z))`` over those samples, written back as
  left and right ticks; any other frame is kept as it is. A twist the same over the samples
  since the previous twist (at most 0.5 s; 0.5 s before the first), unless it is a
  standstill (``|v| <= twist_zero_v`` and ``|w| <= twist_zero_w``).
"""

from __future__ import annotations

import math

import numpy as np

from fusion.geometry.kinematics import ticks_to_twist
from fusion.geometry.mount import vertical_rate
from fusion.planar.imu_motion import MOTION_STILL
from fusion.planar.robot import RobotConfig

__all__ = ["heading_frame_ticks_by_hand", "heading_frame_twists_by_hand",
           "rest_gyro_bias_by_hand", "tilt_rate_by_hand"]


def _still_samples(robot, imu_t, codes, wheel_t, ticks, twist_t, twist_v, twist_w,
                   gap_periods, with_odometry: bool = False):
    """(N,) bool: the IMU samples at which the robot stood still (the module docstring);
    with ``with_odometry`` also (N,) bool: a wheel frame or twist arrived before the sample."""
    period = robot.chassis.encode_sampling_time
    events = sorted([(float(t), 0, i) for i, t in enumerate(imu_t)]
                    + [(float(t), 1, i) for i, t in enumerate(wheel_t)]
                    + [(float(t), 2, i) for i, t in enumerate(twist_t)])
    newest = None  # (stamp, v, w) of the newest wheel frame or twist
    still = np.zeros(len(imu_t), dtype=bool)
    odometry = np.zeros(len(imu_t), dtype=bool)
    for t, kind, i in events:
        if kind == 1:
            v, w = ticks_to_twist(int(ticks[i][0]), int(ticks[i][1]), robot.chassis)
            newest = (t, v, w)
        elif kind == 2:
            newest = (t, float(twist_v[i]), float(twist_w[i]))
        else:
            odometry[i] = newest is not None
            still[i] = (codes[i] == MOTION_STILL and newest is not None
                        and t - newest[0] <= gap_periods * period
                        and abs(newest[1]) <= robot.ekf.twist_zero_v
                        and abs(newest[2]) <= robot.ekf.twist_zero_w)
    return (still, odometry) if with_odometry else still


def rest_gyro_bias_by_hand(robot: RobotConfig, imu_t, gyro, codes, wheel_t=(), ticks=(),
                           twist_t=(), twist_v=(), twist_w=(), *, gap_periods: float = 2.5
                           ) -> np.ndarray:
    """(N, 3) rad/s: the horizontal gyro bias learnt at rest at each IMU sample (z 0), for
    base-frame ``gyro`` (rad/s) with IMU motion ``codes`` at stamps ``imu_t`` (s), given the
    wheel frames (``wheel_t`` s, ``ticks`` per period) and twists (``twist_t`` s, ``twist_v``
    m/s, ``twist_w`` rad/s), all of them accepted by the pipeline (in order, finite)."""
    still = _still_samples(robot, imu_t, codes, wheel_t, ticks, twist_t, twist_v, twist_w,
                           gap_periods)
    out = np.zeros((len(imu_t), 3))
    sx = sy = 0.0
    count = 0
    for i in range(len(imu_t)):
        if still[i]:
            sx += float(gyro[i][0])
            sy += float(gyro[i][1])
            count += 1
        if count:
            out[i, 0], out[i, 1] = sx / count, sy / count
    return out


def tilt_rate_by_hand(robot: RobotConfig, imu_t, gyro, q, codes, wheel_t=(), ticks=(),
                      twist_t=(), twist_v=(), twist_w=(), *, gap_periods: float = 2.5
                      ) -> np.ndarray:
    """(N,) rad/s: the EKF's yaw-rate input for base-frame ``gyro`` (rad/s, as measured) with
    attitudes ``q`` ([w, x, y, z]; of the gyro minus :func:`rest_gyro_bias_by_hand`) and the
    other arguments as there."""
    still, odometry = _still_samples(robot, imu_t, codes, wheel_t, ticks, twist_t, twist_v,
                                     twist_w, gap_periods, with_odometry=True)
    bias = rest_gyro_bias_by_hand(robot, imu_t, gyro, codes, wheel_t, ticks, twist_t,
                                  twist_v, twist_w, gap_periods=gap_periods)
    count = 0
    previous = None  # (stamp, roll, sin(pitch))
    sin_pitch_sum = 0.0
    out = np.empty(len(imu_t))
    for i in range(len(imu_t)):
        qw, qx, qy, qz = (float(c) for c in q[i])
        n2 = qw * qw + qx * qx + qy * qy + qz * qz
        r20 = 2.0 * (qx * qz - qw * qy) / n2
        r21 = 2.0 * (qy * qz + qw * qx) / n2
        if still[i]:
            count += 1
        rate = float(vertical_rate(np.asarray(gyro[i], dtype=float), np.asarray(q[i])))
        if count:
            bx, by = float(bias[i, 0]), float(bias[i, 1])
            rate -= bx * r20 + by * r21
        r22 = 1.0 - 2.0 * (qx * qx + qy * qy) / n2
        roll = math.atan2(r21, r22)
        if still[i]:
            sin_pitch_sum += -r20
        if previous is not None and count:
            t0, roll0, s0 = previous
            turn = math.remainder(roll - roll0, 2.0 * math.pi)
            rate += turn * (0.5 * (-r20 + s0) - sin_pitch_sum / count) / (float(imu_t[i]) - t0)
        previous = (float(imu_t[i]), roll, -r20)
        out[i] = float(gyro[i][2]) if (odometry[i] and not count) else rate
    return out


def _means(q, rate, gyro_z, near):
    """Mean cos(pitch) and mean (rate - gyro z) over the samples ``near``."""
    qw, qx, qy, qz = np.asarray(q)[near].T
    sin_pitch = -2.0 * (qx * qz - qw * qy) / (qw * qw + qx * qx + qy * qy + qz * qz)
    cos_pitch = np.sqrt(np.maximum(1.0 - sin_pitch * sin_pitch, 0.0)).mean()
    return cos_pitch, (np.asarray(rate)[near] - np.asarray(gyro_z)[near]).mean()


def heading_frame_ticks_by_hand(robot: RobotConfig, imu_t, q, rate, gyro_z, wheel_t, ticks):
    """(M, 2) float ticks of the wheel frames as the pipeline hands them to the EKF (the module
    docstring), one frame at a time: ``q`` (N, 4) the attitudes, ``rate`` (N,) the EKF's yaw
    rate and ``gyro_z`` (N,) the base gyro's z rate of the IMU samples at ``imu_t``."""
    chassis = robot.chassis
    period, L = chassis.encode_sampling_time, chassis.wheel_distance
    per_speed = period / chassis.speed_ratio  # ticks per m/s
    out = np.asarray(ticks, dtype=np.float64).copy()
    imu_t = np.asarray(imu_t)
    for i, t in enumerate(np.asarray(wheel_t).tolist()):
        left, right = out[i]
        near = (imu_t > t - period) & (imu_t <= t)
        if (left == 0.0 and right == 0.0) or not near.any():
            continue
        cos_pitch, diff = _means(q, rate, gyro_z, near)
        v = 0.5 * (left + right) / per_speed * cos_pitch
        w = (right - left) / (per_speed * L) + diff
        out[i] = ((v - 0.5 * w * L) * per_speed, (v + 0.5 * w * L) * per_speed)
    return out


def heading_frame_twists_by_hand(robot: RobotConfig, imu_t, q, rate, gyro_z, twist_t, twist_v,
                                 twist_w):
    """(K,) speeds and (K,) yaw rates of the twists as the pipeline hands them to the EKF (the
    module docstring); the other arguments as for :func:`heading_frame_ticks_by_hand`."""
    v, w = np.array(twist_v, dtype=np.float64), np.array(twist_w, dtype=np.float64)
    imu_t = np.asarray(imu_t)
    previous = None
    for i, t in enumerate(np.asarray(twist_t).tolist()):
        span = 0.5 if previous is None else min(t - previous, 0.5)
        previous = t
        near = (imu_t > t - span) & (imu_t <= t)
        still = abs(v[i]) <= robot.ekf.twist_zero_v and abs(w[i]) <= robot.ekf.twist_zero_w
        if still or not near.any():
            continue
        cos_pitch, diff = _means(q, rate, gyro_z, near)
        v[i] *= cos_pitch
        w[i] += diff
    return v, w
