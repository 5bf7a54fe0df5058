"""Wheel odometry on a slope, in the pose's own terms (fusion.pipeline.heading_frame): the
distance over the horizontal and the heading's rate.

Oracles: trigonometry (a straight drive up a constant incline covers ``s * cos(slope)`` over
the horizontal), attitudes built with scipy, and the conversion's stated rules (standstills
untouched, each frame converted with the IMU samples of its own period).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion.geometry.kinematics import DiffDriveParams
from fusion.pipeline.core import FusionPipeline
from fusion.pipeline.heading_frame import MAX_TWIST_SPAN, HeadingFrame
from fusion.planar.robot import RobotConfig

PERIOD, M_PER_TICK, TRACK = 0.04, 1e-4, 0.3
G = 9.80665


def _q(pitch: float) -> np.ndarray:
    """(w, x, y, z) of a body pitched nose-up by ``pitch`` rad (ZYX), from scipy."""
    x, y, z, w = Rotation.from_euler("ZYX", [0.0, -pitch, 0.0]).as_quat()
    return np.array([w, x, y, z])


def _frame(imu_t, pitch, rate_diff) -> HeadingFrame:
    frame = HeadingFrame(PERIOD, M_PER_TICK, TRACK)
    n = len(imu_t)
    frame.add_imu(np.asarray(imu_t, dtype=float), np.tile(_q(pitch), (n, 1)),
                  np.full(n, rate_diff))
    return frame


def test_a_frame_on_a_slope_gives_the_horizontal_speed_and_the_heading_rate():
    slope, diff = math.radians(12.0), 0.02
    frame = _frame(np.arange(1, 101) * 0.005, slope, diff)
    ticks = np.array([[100, 140]])  # 0.25 m/s forward ... and 0.1 rad/s of wheel yaw rate
    left, right = frame.ticks(np.array([0.4]), ticks)
    v = 0.5 * (left + right) * M_PER_TICK / PERIOD
    w = (right - left) * M_PER_TICK / (PERIOD * TRACK)
    assert v[0] == pytest.approx(0.3 * math.cos(slope), rel=1e-12)
    assert w[0] == pytest.approx(40 * M_PER_TICK / (PERIOD * TRACK) + diff, rel=1e-12)


def test_standstills_and_frames_without_imu_samples_are_left_as_measured():
    frame = _frame(np.arange(1, 101) * 0.005, math.radians(12.0), 0.02)
    ticks = np.array([[0, 0], [7, 9], [3, 4]])
    # a stop (both zero), a frame whose period has IMU samples, one after the last sample
    left, right = frame.ticks(np.array([0.2, 0.3, 5.0]), ticks)
    assert (left[0], right[0]) == (0.0, 0.0)
    assert (left[1], right[1]) != (7.0, 9.0)
    assert (left[2], right[2]) == (3.0, 4.0)
    v, w = frame.twists(np.array([0.3, 0.4]), np.array([0.0, 0.5]), np.array([0.0, 0.1]),
                        1e-3, 1e-3)
    assert (v[0], w[0]) == (0.0, 0.0)
    assert v[1] == pytest.approx(0.5 * math.cos(math.radians(12.0)), rel=1e-12)
    assert w[1] == pytest.approx(0.12, rel=1e-12)


def test_each_frame_takes_only_the_imu_samples_of_its_own_period():
    frame = HeadingFrame(PERIOD, M_PER_TICK, TRACK)
    t = np.arange(1, 41) * 0.005  # 0.005 .. 0.2 s
    diff = np.where(t <= 0.16, 0.0, 0.5)  # the last period (0.16, 0.2] differs
    frame.add_imu(t, np.tile(_q(0.0), (t.size, 1)), diff)
    left, right = frame.ticks(np.array([0.16, 0.2]), np.array([[10, 10], [10, 10]]))
    w = (right - left) * M_PER_TICK / (PERIOD * TRACK)
    assert w[0] == 0.0
    assert w[1] == pytest.approx(0.5, rel=1e-12)


def test_a_twist_averages_over_the_time_since_the_previous_one():
    frame = HeadingFrame(PERIOD, M_PER_TICK, TRACK)
    t = np.arange(1, 201) * 0.005  # 0.005 .. 1.0 s
    frame.add_imu(t, np.tile(_q(0.0), (t.size, 1)), np.where(t <= 0.9, 0.0, 0.3))
    _, w = frame.twists(np.array([0.8, 1.0]), np.array([1.0, 1.0]), np.array([0.0, 0.0]),
                        1e-3, 1e-3)
    assert w[0] == 0.0  # (0.3, 0.8]: all 0
    assert w[1] == pytest.approx(0.15, rel=1e-12)  # (0.8, 1.0]: half at 0.3
    assert MAX_TWIST_SPAN == 0.5


def test_samples_older_than_any_frame_can_need_are_forgotten():
    frame = _frame(np.arange(1, 2001) * 0.005, 0.0, 0.0)  # 10 s
    frame.forget_old()
    left, right = frame.ticks(np.array([1.0]), np.array([[10, 20]]))
    assert (left[0], right[0]) == (10.0, 20.0)  # no samples left there: as measured
    left, right = frame.ticks(np.array([9.9]), np.array([[10, 20]]))
    assert (left[0], right[0]) == pytest.approx((10.0, 20.0), abs=1e-9)


def _slope_drive(tilt: bool, slope: float, speed: float = 0.5, rest: float = 3.0,
                 drive: float = 20.0) -> FusionPipeline:
    """A robot on a constant incline (``slope`` rad, nose up): ``rest`` s still, then
    straight up the slope at ``speed`` m/s along the surface; exact IMU (gravity from scipy's
    rotation, no rate) and wheel ticks of the surface distance."""
    robot = RobotConfig(chassis=DiffDriveParams(wheel_distance=TRACK, speed_ratio=M_PER_TICK,
                                                encode_sampling_time=PERIOD))
    pipe = FusionPipeline(robot, imu_rate_hz=200.0, tilt=tilt)
    imu_t = np.arange(1, int((rest + drive) * 200) + 1) / 200.0
    body = Rotation.from_euler("ZYX", [0.0, -slope, 0.0])  # body -> world
    accel = np.tile(body.inv().apply([0.0, 0.0, G]), (imu_t.size, 1))
    wheel_t = np.arange(1, int((rest + drive) / PERIOD) + 1) * PERIOD
    surface = np.maximum(wheel_t - rest, 0.0) * speed
    counts = np.floor(surface / M_PER_TICK + 1e-9)
    per_frame = np.diff(np.concatenate([[0.0], counts]))
    ticks = np.column_stack([per_frame, per_frame]).astype(np.int64)
    with pipe:
        pipe.push_arrays(imu_t, np.zeros((imu_t.size, 3)), accel, wheel_t, ticks)
    return pipe


@pytest.mark.parametrize("slope_deg", [10.0, 20.0])
def test_driving_up_a_slope_moves_the_pose_by_the_horizontal_distance(slope_deg):
    slope = math.radians(slope_deg)
    surface = 0.5 * 20.0
    tilted = _slope_drive(True, slope)
    assert tilted.ekf.x[0] == pytest.approx(surface * math.cos(slope), rel=2e-3)
    assert abs(tilted.ekf.x[1]) < 1e-6 and abs(tilted.ekf.x[2]) < 1e-6
    # taken as level (--level), the pose moves by the distance along the surface
    level = _slope_drive(False, slope)
    assert level.ekf.x[0] == pytest.approx(surface, rel=2e-3)
