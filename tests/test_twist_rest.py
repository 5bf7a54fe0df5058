"""fusion.jobs.twist_rest: a twist odometry's noise at rest, read where the IMU is still, raises
the EKF's stop thresholds (and only then). Constructed streams: a robot that drives (the IMU
shaking by 0.5 m/s^2, as a drive does) and stops six times for 5 s (the IMU still: MPU-6050
noise), its twists at 10 Hz. End to end on a simulated bag: tests/test_terrain_bag.py."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fusion.geometry.kinematics import DiffDriveParams
from fusion.jobs.streams import Streams
from fusion.jobs.twist_rest import MAX_ZERO_V, MAX_ZERO_W, with_twist_rest_floor
from fusion.planar.ekf import EkfNoise
from fusion.planar.robot import RobotConfig

ROBOT = RobotConfig(chassis=DiffDriveParams(wheel_distance=0.4, speed_ratio=1e-4))


def _streams(rest_v, rest_w, seed=0):
    """Streams of 60 s: 5 s stops starting every 10 s; ``rest_v(n, rng)``, ``rest_w(n, rng)``
    give the n twists of the stops."""
    rng = np.random.default_rng(seed)
    imu_t = np.arange(0.0, 60.0, 0.01)
    stopped = (imu_t % 10.0) >= 5.0
    gyro = rng.normal(0.0, 7e-4, (imu_t.size, 3)) + np.array([0.0, 0.0, 0.004])  # a bias
    accel = rng.normal(0.0, 0.04, (imu_t.size, 3)) + np.array([0.0, 0.0, 9.81])
    accel[~stopped] += rng.normal(0.0, 0.5, (np.count_nonzero(~stopped), 3))
    gyro[~stopped] += rng.normal(0.0, 0.05, (np.count_nonzero(~stopped), 3))
    twist_t = np.arange(0.05, 60.0, 0.1)
    rest = (twist_t % 10.0) >= 5.0
    v = np.full(twist_t.size, 0.4)
    w = 0.3 * np.sin(twist_t)
    v[rest] = rest_v(np.count_nonzero(rest), rng)
    w[rest] = rest_w(np.count_nonzero(rest), rng)
    return Streams(imu_t, gyro, accel, twist_t=twist_t, twist_v=v, twist_w=w)


def _noise(std):
    return lambda n, rng: rng.normal(0.0, std, n)


def _zero(n, rng):
    return np.zeros(n)


def test_noise_at_rest_raises_both_thresholds_to_cover_it():
    robot, note = with_twist_rest_floor(ROBOT, _streams(_noise(0.002), _noise(0.003)))
    # 4 x the median magnitude of N(0, s) = 2.7 s, rounded up to two digits
    assert robot.ekf.twist_zero_v == pytest.approx(2.7 * 0.002, rel=0.15)
    assert robot.ekf.twist_zero_w == pytest.approx(2.7 * 0.003, rel=0.15)
    assert "twist_zero_v = " in note and "twist_zero_w = " in note and "[ekf]" in note
    # what the EKF would now take for a stop: nearly every twist at rest, no driving one
    s = _streams(_noise(0.002), _noise(0.003))
    stop = ((np.abs(s.twist_v) <= robot.ekf.twist_zero_v)
            & (np.abs(s.twist_w) <= robot.ekf.twist_zero_w))
    rest = (s.twist_t % 10.0) >= 5.0
    assert np.mean(stop[rest]) > 0.97 and not np.any(stop[~rest])
    # the rest of the configuration untouched
    assert dataclasses.replace(robot.ekf, twist_zero_v=1e-3, twist_zero_w=1e-3) == EkfNoise()


def test_twists_that_read_zero_at_rest_change_nothing():
    robot, note = with_twist_rest_floor(ROBOT, _streams(_zero, _zero))
    assert robot is ROBOT and note == ""


def _per_stop(values):
    """Twists at the six stops holding ``values[k]`` (plus 5 % noise) at the k-th."""
    def make(n, rng):
        stop = np.repeat(np.arange(6), n // 6)
        level = np.asarray(values, dtype=float)[stop]
        return level + rng.normal(0.0, 0.05, n) * level
    return make


def test_creeping_or_turning_at_varied_rates_with_the_imu_still_is_not_taken_for_a_stop():
    # the IMU still while the twists read 1-2 cm/s and 0.1-0.6 deg/s turns, a different
    # rate at each stop: motion (one sign at each), not noise, not one offset; a
    # zero-velocity update would pin it to zero and, for the turns, teach the gyro bias
    # their rate
    creep = _per_stop([0.010, 0.020, 0.012, 0.018, 0.010, 0.015])
    turn = _per_stop([0.005, 0.002, 0.010, 0.004, 0.008, 0.003])
    robot, note = with_twist_rest_floor(ROBOT, _streams(creep, turn))
    assert robot is ROBOT and note == ""
    # noise on v with such turns: v raised, w not
    robot, note = with_twist_rest_floor(ROBOT, _streams(_noise(0.002), turn))
    assert robot.ekf.twist_zero_v > 0.004 and robot.ekf.twist_zero_w == 1e-3
    assert "twist_zero_w" not in note


def test_one_steady_offset_at_every_stop_is_taken_for_the_drivers_and_said():
    # the twists' yaw rate reads +5 mrad/s at every stop (a base whose odometry's yaw rate
    # is its own gyro's residual bias; an independent probe's bag so lost all 98 of its
    # zero-velocity updates, GPS RMSE 1.55 -> 6.58 m). Twists and an IMU cannot tell this
    # from a robot that turns at that very rate whenever it stops; the offset is taken
    for sign in (1.0, -1.0):
        offset = _per_stop([sign * 0.005] * 6)
        s = _streams(_zero, offset)
        robot, note = with_twist_rest_floor(ROBOT, s)
        assert robot.ekf.twist_zero_v == 1e-3
        # the offset and 4 x the median magnitude of its 5 % noise (N(0, 0.25 mrad/s):
        # 0.17 mrad/s), rounded up to two digits
        assert robot.ekf.twist_zero_w == pytest.approx(0.005 + 4 * 0.6745 * 0.00025,
                                                       rel=0.05)
        assert f"w held {sign * 0.005:+.2g} rad/s at every stop" in note
        assert "or the robot moved at that rate whenever it stopped" in note
        rest = (s.twist_t % 10.0) >= 5.0
        stop = np.abs(s.twist_w) <= robot.ekf.twist_zero_w
        assert np.mean(stop[rest]) > 0.97
    # noise on v beside the offset on w: both raised, both said
    robot, note = with_twist_rest_floor(ROBOT, _streams(_noise(0.002), _per_stop([0.005] * 6)))
    assert robot.ekf.twist_zero_v > 0.004 and robot.ekf.twist_zero_w > 0.005
    assert "w held +0.005 rad/s at every stop" in note
    assert "the other scattered around zero: its driver reports noise at rest" in note
    # an offset the cap cannot cover, 0.02 rad/s (1.1 deg/s), is left alone
    robot, note = with_twist_rest_floor(ROBOT, _streams(_zero, _per_stop([0.02] * 6)))
    assert robot is ROBOT and note == ""


def test_large_noise_is_capped_and_said():
    robot, note = with_twist_rest_floor(ROBOT, _streams(_noise(0.02), _noise(0.02)))
    assert robot.ekf.twist_zero_v == MAX_ZERO_V and robot.ekf.twist_zero_w == MAX_ZERO_W
    assert "capped" in note


def test_thresholds_robot_toml_set_higher_are_kept():
    mine = dataclasses.replace(ROBOT, ekf=dataclasses.replace(ROBOT.ekf, twist_zero_v=0.015,
                                                              twist_zero_w=0.012))
    robot, note = with_twist_rest_floor(mine, _streams(_noise(0.002), _noise(0.002)))
    assert robot is mine and note == ""


def test_no_still_imu_no_change():
    # an IMU that shakes at rest too (an engine): nothing says where the robot stood
    s = _streams(_noise(0.002), _noise(0.002))
    shaking = s.accel + np.random.default_rng(1).normal(0.0, 0.5, s.accel.shape)
    robot, note = with_twist_rest_floor(ROBOT, dataclasses.replace(s, accel=shaking))
    assert robot is ROBOT and note == ""
    # nor without an IMU, or with wheel ticks instead of twists
    assert with_twist_rest_floor(ROBOT, dataclasses.replace(s, imu_t=None)) == (ROBOT, "")
    assert with_twist_rest_floor(ROBOT, Streams(s.imu_t, s.gyro, s.accel)) == (ROBOT, "")


def test_a_creep_beside_noisy_stops_is_not_taken_for_noise():
    # four stops with 2 mm/s of noise, two where the robot creeps at 7 mm/s, its IMU still
    # (review: pooled, the creep read as noise, twist_zero_v went to 0.0099 and every
    # creeping twist became a stop); each still stretch is tested for a creep of its own
    def rest_v(n, rng):
        v = rng.normal(0.0, 0.002, n)
        v[: n // 3] = 0.007 + rng.normal(0.0, 0.0005, n // 3)  # the first two stops
        return v

    s = _streams(rest_v, _noise(0.002))
    robot, _ = with_twist_rest_floor(ROBOT, s)
    rest = np.flatnonzero(s.twist_t % 10.0 >= 5.0)
    creeping = rest[: rest.size // 3]
    # the creeping twists stay above the threshold (0.0052 measured, the creep 0.007 +- 0.0005;
    # 0.0099 pooled, above all of them)
    assert np.mean(np.abs(s.twist_v[creeping]) > robot.ekf.twist_zero_v) > 0.99
    assert robot.ekf.twist_zero_v > 0.004  # the noisy stops still raise it


def test_a_threshold_robot_toml_set_above_the_cap_is_not_said_as_raised():
    # noise beyond the cap, robot.toml's 3 cm/s above it: nothing raised, nothing said
    # (review: the note claimed 'this replay uses twist_zero_v = 0.03', the value kept)
    mine = dataclasses.replace(ROBOT, ekf=dataclasses.replace(ROBOT.ekf, twist_zero_v=0.03,
                                                              twist_zero_w=0.03))
    robot, note = with_twist_rest_floor(mine, _streams(_noise(0.02), _noise(0.02)))
    assert robot is mine and note == ""
