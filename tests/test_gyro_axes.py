"""fusion.calibration.gyro_axes: the gyro axis a log's odometry turns about, against rotations
built with scipy (the IMU frame's up is the mount's inverse applied to the base's z)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion.calibration.gyro_axes import MIN_TURN, axis_angle, gyro_yaw_axis


def _log(mount_rpy, seconds=120.0, scale=1.0, seed=0, rate=100.0, odom_rate=10.0):
    """A robot turning back and forth (0.8 rad/s peaks, with pitch and roll wobble) under an
    IMU mounted at ``mount_rpy`` (base <- IMU, URDF); the odometry's yaw rate ``scale`` times
    the true one plus an offset, at ``odom_rate`` Hz."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / rate)
    yaw_rate = 0.8 * np.sin(2 * np.pi * t / 7.0) * np.sign(np.sin(2 * np.pi * t / 23.0))
    wobble = 0.05 * rng.standard_normal((t.size, 2))
    base = np.column_stack([wobble, yaw_rate])
    to_imu = Rotation.from_euler("xyz", mount_rpy).inv()
    gyro = to_imu.apply(base) + 0.01 * rng.standard_normal((t.size, 3)) + [0.01, -0.02, 0.005]
    accel = to_imu.apply(np.tile([0.0, 0.0, 9.81], (t.size, 1)))
    s = np.arange(0.0, seconds, 1.0 / odom_rate) + 0.003
    w = scale * np.interp(s, t, yaw_rate) + 0.02 + 0.02 * rng.standard_normal(s.size)
    return t, gyro, accel, s, w, to_imu.apply([0.0, 0.0, 1.0])


@pytest.mark.parametrize("mount", [(0.0, 0.0, 0.0), (math.pi / 2, 0.0, -math.pi / 2),
                                   (0.3, -0.2, 2.0), (math.pi, 0.0, 0.0)])
def test_the_axis_is_the_mounts_vertical_at_any_odometry_scale(mount):
    t, gyro, accel, s, w, up = _log(mount, scale=1.5)
    fit = gyro_yaw_axis(t, gyro, s, w)
    assert fit is not None
    assert math.degrees(axis_angle(fit.axis, up)) < 1.0
    assert math.degrees(axis_angle(fit.axis, accel.mean(axis=0))) < 1.0
    assert fit.scale == pytest.approx(1.5, rel=0.02)
    assert fit.correlation > 0.99
    assert fit.turn > MIN_TURN


def test_swapped_gyro_axes_put_the_turns_off_the_accelerometers_up():
    # the outdoor robot's mount (IMU y up); its driver swaps the gyro's x and y
    t, gyro, accel, s, w, _up = _log((math.pi / 2, 0.0, -math.pi / 2))
    fit = gyro_yaw_axis(t, gyro[:, [1, 0, 2]], s, w)
    assert fit is not None
    assert math.degrees(axis_angle(fit.axis, accel.mean(axis=0))) == pytest.approx(90.0, abs=1)
    assert abs(fit.axis[0]) > 0.999  # the IMU's x, where its y should be


def test_too_little_turning_or_an_unrelated_odometry_says_nothing():
    t, gyro, _accel, s, w, _ = _log((0.0, 0.0, 0.0), seconds=5.0)  # about 2 rad of turns
    assert gyro_yaw_axis(t, gyro, s, w) is None
    t, gyro, _accel, s, w, _ = _log((0.0, 0.0, 0.0))
    rng = np.random.default_rng(1)
    assert gyro_yaw_axis(t, gyro, s, rng.permutation(w)) is None  # another run's odometry
    assert gyro_yaw_axis(t, gyro, s + 1e4, w) is None  # no overlap
