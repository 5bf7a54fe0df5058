"""The accelerometer's forward specific force driving the EKF's speed (EkfNoise.accel_speed_psd):
against closed forms (constant acceleration; a dead encoder feed while the robot slows) and
the physics simulator's truth. The filterpy reference mirrors the rule
(tests/test_ekf.py::test_core_equals_filterpy_driven_by_the_model[accel-speed])."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion.evaluation.physics_sim import physics_scenario
from fusion.evaluation.synthetic import EXAMPLE_ROBOT
from fusion.planar import _ekf_core as core
from fusion.planar.ekf import EkfNoise, fuse
from fusion.planar.imu_motion import imu_motion_codes

ROBOT = EXAMPLE_ROBOT
STILL, MOVING = 1, 3  # fusion.planar.imu_motion codes
IMU_RATE = 100.0  # Hz
OFFSET = 0.35  # m/s^2: accelerometer bias + gravity through a 2 deg pitch (9.81 sin 2 deg)
ON = EkfNoise(accel_speed_psd=0.005)


def _imu(t_end: float, accel, rest_until: float):
    """IMU stamps at IMU_RATE over [0, t_end], a zero yaw rate, the forward specific force
    OFFSET + accel(t) and the motion codes (still before ``rest_until``)."""
    t = np.arange(0.0, t_end + 1e-9, 1.0 / IMU_RATE)
    codes = np.where(t < rest_until, STILL, MOVING)
    return t, np.zeros(t.size), OFFSET + accel(t), codes


def test_constant_acceleration_without_wheels_integrates_in_closed_form():
    # 1 s standing (zero ticks, IMU still: the offset is learnt), then 2 s of a constant
    # 0.5 m/s^2 with no wheel frame at all: the speed is a * elapsed and the distance
    # the sum of the steps' speeds times the step (Euler: a h^2 N (N - 1) / 2), exactly
    a = 0.5
    imu_t, gz, fx, codes = _imu(3.0, lambda t: np.where(t < 1.0, 0.0, a), 1.0)
    wheel_t = np.arange(ROBOT.encode_sampling_time, 1.0 + 1e-9, ROBOT.encode_sampling_time)
    ticks = np.zeros((wheel_t.size, 2))
    track, ekf = fuse(ROBOT, imu_t, gz, wheel_t, ticks, noise=ON, imu_motion=codes,
                      accel_x=fx)
    assert ekf._aux[core.A_FX_OFFSET] == pytest.approx(OFFSET, abs=1e-12)
    assert track.kind.size == imu_t.size + wheel_t.size  # the accelerometer gives no rows
    first = np.flatnonzero(imu_t >= 1.0)[0]  # its gyro sample ends the stop
    k = track.kind == core.EV_GYRO
    states = track.states[k]
    h = 1.0 / IMU_RATE
    n = imu_t.size - 1 - first
    assert states[-1, 3] - states[first, 3] == pytest.approx(a * n * h, abs=1e-9)
    assert states[-1, 0] - states[first, 0] == pytest.approx(
        a * h * h * n * (n - 1) / 2 + states[first, 3] * n * h, abs=1e-9)
    # the default (a random walk) holds the speed instead
    _, off = fuse(ROBOT, imu_t, gz, wheel_t, ticks, imu_motion=codes, accel_x=fx)
    assert abs(off.x[3]) < 1e-3 and ekf.x[3] == pytest.approx(1.0, abs=1e-9)


def _slowing_with_a_dead_feed():
    """2 s standing, 2 s at +0.5 m/s^2 to 1 m/s, 2 s cruising, 4 s at -0.2 m/s^2 with zero
    ticks on both wheels (a dead encoder feed; the IMU says moving), 2 s at 0.2 m/s with
    the ticks back. Straight ahead. Returns the IMU streams, the wheel frames and the true
    distance (closed form) at each IMU stamp."""
    def accel(t):
        return np.select([t < 2.0, t < 4.0, t < 6.0, t < 10.0], [0.0, 0.5, 0.0, -0.2], 0.0)

    def distance(t):
        t1 = np.clip(t - 2.0, 0.0, 2.0)
        t2 = np.clip(t - 4.0, 0.0, 2.0)
        t3 = np.clip(t - 6.0, 0.0, 4.0)
        t4 = np.clip(t - 10.0, 0.0, None)
        return 0.25 * t1 ** 2 + t2 + (t3 - 0.1 * t3 ** 2) + 0.2 * t4

    imu = _imu(12.0, accel, 2.0)
    T = ROBOT.encode_sampling_time
    wheel_t = np.arange(T, 12.0 + 1e-9, T)
    counts = np.floor(distance(np.concatenate([[0.0], wheel_t])) / ROBOT.speed_ratio)
    per_frame = np.diff(counts)
    dead = (wheel_t > 6.0) & (wheel_t <= 10.0)
    per_frame[dead] = 0.0
    return imu, wheel_t, np.column_stack([per_frame, per_frame]), distance(imu[0])


def test_a_dead_encoder_while_slowing_follows_the_accelerometer():
    # held speed: 1 m/s for 4 s where the robot covered 2.4 m (1.6 m too far); driven by the
    # accelerometer the distance stays within 2 cm of the closed form
    (imu_t, gz, fx, codes), wheel_t, ticks, truth = _slowing_with_a_dead_feed()
    errors = {}
    for name, noise in (("held", EkfNoise()), ("accelerometer", ON)):
        track, ekf = fuse(ROBOT, imu_t, gz, wheel_t, ticks, noise=noise, imu_motion=codes,
                          accel_x=fx)
        assert ekf.stats["encoder_faults"] >= 90  # the 4 s are flagged, not fused
        k = track.kind == core.EV_GYRO
        end_of_dead = imu_t <= 10.0
        errors[name] = np.abs(track.states[k, 0] - truth)[end_of_dead].max()
    assert errors["accelerometer"] < 0.02
    assert errors["held"] > 1.0


def test_physics_simulator_speed_follows_the_ramps():
    # the physics simulator (written without the EKF's model), every error on, the gyro scale
    # calibrated: the random-walk speed lags the 1 m/s^2 ramps; driven by the accelerometer
    # its error against the true speed shrinks on every seed (measured: to 0.18-0.70 of the
    # random walk's RMS, 0.38 on average over seeds 0-3)
    ratios = []
    for seed in range(4):
        run = physics_scenario("all", seed=seed, duration=60.0)
        gz = run.gyro[:, 2] / (1.0 + run.sensors.gyro_scale[2])
        codes = imu_motion_codes(run.imu_t, run.gyro, run.accel)
        rms = []
        for psd in (0.0, ON.accel_speed_psd):
            noise = EkfNoise(accel_speed_psd=psd, gyro_scale_std=5e-4)
            track, _ = fuse(run.robot.chassis, run.imu_t, gz, run.wheel_t, run.ticks,
                            noise=noise, imu_motion=codes, accel_x=run.accel[:, 0])
            k = track.kind == core.EV_GYRO
            speed = track.states[k, 3] / (1.0 + track.states[k, 9])  # the true-scale speed
            truth = np.interp(track.t[k], run.truth_t, run.truth_v)
            rms.append(math.sqrt(np.mean((speed - truth) ** 2)))
        ratios.append(rms[1] / rms[0])
    assert max(ratios) < 0.8 and np.mean(ratios) < 0.5
