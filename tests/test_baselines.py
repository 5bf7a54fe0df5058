"""Baselines on analytic cases: wheel-only dead reckoning and gyro heading with the bias
re-learnt at stops."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion.evaluation.baselines import (
    StopDetector,
    detect_stops,
    gyro_at_stops,
    gyro_at_stops_twist,
    wheel_only,
)
from fusion.geometry.kinematics import DiffDriveParams

ROBOT = DiffDriveParams(wheel_distance=0.3, speed_ratio=1e-4, encode_sampling_time=0.04)
G = 9.80665


def test_wheel_only_on_a_circle():
    # constant ticks: each period turns by (r - l)*sr/L about a circle of radius
    # L/2 * (l + r)/(r - l); the midpoint rule overstates each chord by 1/sinc(dtheta/2)
    left, right, n = 300, 500, 400
    poses = wheel_only(ROBOT, np.tile([left, right], (n, 1)))
    dth = (right - left) * 1e-4 / 0.3
    radius = 0.15 * (left + right) / (right - left)
    theta = n * dth
    assert poses[-1, 2] == pytest.approx(theta, rel=1e-12)
    chord = math.sin(dth / 2) / (dth / 2)
    assert poses[-1, 0] == pytest.approx(radius * math.sin(theta) / chord, rel=1e-9)
    assert poses[-1, 1] == pytest.approx(radius * (1 - math.cos(theta)) / chord, rel=1e-9)


def _log(phases, rate=200.0, period=0.04):
    """IMU and wheel streams from phases ``(duration s, gyro z rad/s, ticks per period, imu
    moving)``: a moving IMU has a 3 Hz rocking on x and the accelerometer."""
    imu_t, gz, wheel_t, ticks, moving = [], [], [], [], []
    t0 = 0.0
    for duration, g, tk, shaking in phases:
        ti = t0 + np.arange(round(duration * rate)) / rate
        imu_t.append(ti)
        gz.append(np.full(ti.size, g))
        moving.append(np.full(ti.size, shaking))
        tw = t0 + period * np.arange(1, round(duration / period) + 1)
        wheel_t.append(tw)
        ticks.append(np.tile(tk, (tw.size, 1)))
        t0 += duration
    imu_t = np.concatenate(imu_t)
    shake = np.concatenate(moving) * 0.3 * np.sin(2 * np.pi * 3.0 * imu_t)
    gyro = np.column_stack([shake, np.zeros_like(imu_t), np.concatenate(gz)])
    accel = np.column_stack([shake, np.zeros_like(imu_t), np.full(imu_t.size, G)])
    return imu_t, gyro, accel, np.concatenate(wheel_t), np.concatenate(ticks)


def test_bias_learnt_at_each_stop_and_heading_from_the_rest():
    b1, b2, w = 0.01, -0.02, 0.2
    phases = [(3.0, b1, (0, 0), False),          # stop: bias b1
              (5.0, b1 + w, (1000, 1000), True),  # driving, turning at w (ticks equal)
              (3.0, b2, (0, 0), False),          # stop: bias now b2
              (5.0, b2, (1000, 1000), True)]      # straight on
    imu_t, gyro, accel, wheel_t, ticks = _log(phases)
    out = gyro_at_stops(ROBOT, imu_t, gyro, accel, wheel_t, ticks)
    assert [s[2] for s in out.stops] == pytest.approx([b1, b2], abs=1e-15)
    assert out.rejected == []
    # heading: w for 5 s (the trapezoid is exact for a constant rate, but the first IMU
    # sample after the stop still carries half a step of the held rate)
    i_end = np.searchsorted(wheel_t, 11.0)
    assert out.poses[i_end, 2] == pytest.approx(w * 5.0, abs=w / 200)
    assert out.poses[-1, 2] == pytest.approx(out.poses[i_end, 2], abs=1e-12)
    # the last 5 s drive straight along that heading: 125 frames of 0.1 m
    d = out.poses[-1, :2] - out.poses[i_end, :2]
    assert np.hypot(*d) == pytest.approx(125 * 0.1, rel=1e-12)
    assert math.atan2(d[1], d[0]) == pytest.approx(out.poses[-1, 2], abs=1e-12)


def test_zero_ticks_while_the_imu_moves_is_no_stop():
    phases = [(3.0, 0.01, (0, 0), False),
              (4.0, 0.01, (0, 0), True),   # dead encoder feed: the IMU rocks
              (2.0, 0.01, (500, 500), True)]
    imu_t, gyro, accel, wheel_t, ticks = _log(phases)
    stops, rejected = detect_stops(ROBOT, imu_t, gyro, accel, wheel_t, ticks)
    # the zero-tick run spans both phases (7 s): the IMU moved during it -> rejected whole
    assert stops == [] and len(rejected) == 1
    stops, _ = detect_stops(ROBOT, imu_t[imu_t < 3.0], gyro[imu_t < 3.0], accel[imu_t < 3.0],
                            wheel_t[wheel_t <= 3.0], ticks[wheel_t <= 3.0])
    assert len(stops) == 1


def test_a_steady_rotation_with_zero_ticks_is_no_stop():
    # a robot spinning at a constant 0.5 rad/s: the gyro is steady but far from zero
    imu_t, gyro, accel, wheel_t, ticks = _log([(4.0, 0.5, (0, 0), False)])
    stops, rejected = detect_stops(ROBOT, imu_t, gyro, accel, wheel_t, ticks)
    assert stops == [] and len(rejected) == 1


def test_short_pauses_are_ignored():
    imu_t, gyro, accel, wheel_t, ticks = _log([(0.5, 0.0, (0, 0), False),
                                               (1.0, 0.0, (100, 100), False)])
    assert detect_stops(ROBOT, imu_t, gyro, accel, wheel_t, ticks,
                        StopDetector(min_duration=1.0)) == ([], [])


def test_twist_form_equals_the_tick_form():
    # twists of 0.04 s carrying the same distances as the ticks give the same track
    phases = [(3.0, 0.01, (0, 0), False), (5.0, 0.21, (1000, 1000), True),
              (3.0, -0.02, (0, 0), False), (5.0, -0.02, (1000, 1200), True)]
    imu_t, gyro, accel, wheel_t, ticks = _log(phases)
    a = gyro_at_stops(ROBOT, imu_t, gyro, accel, wheel_t, ticks)
    v = ticks.mean(axis=1) * ROBOT.speed_ratio / 0.04
    w = (ticks[:, 1] - ticks[:, 0]) * ROBOT.speed_ratio / 0.3 / 0.04
    b = gyro_at_stops_twist(imu_t, gyro, accel, wheel_t, v, w)
    assert np.array(b.stops) == pytest.approx(np.array(a.stops), abs=1e-12)
    assert b.poses == pytest.approx(a.poses, abs=1e-12)
