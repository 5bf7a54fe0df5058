"""The planar EKF on data it was not built around (issue 11): no pose jumps, stops confirmed by
the IMU, dead encoders flagged, slips that do not bend the heading, a bias learnt while moving.

Oracles: the motion model's own bound (a rate measurement never moves the position; the
heading only within its stated budget), the simulators' truth (fusion.evaluation.synthetic and
the independent physics simulator), the bundled Jackal bag's twist speeds, and a real MPU6050's
recordings at rest and turned by hand (datasets/mpu6050_raw) for the stillness detector.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from fusion.evaluation.physics_sim import indoor_mission, physics_scenario, simulate_physics
from fusion.evaluation.physics_sim.sensor_model import all_errors
from fusion.evaluation.synthetic import (
    EXAMPLE_ROBOT,
    EncoderModel,
    ImuModel,
    SlipPatch,
    arc,
    simulate,
    straight,
)
from fusion.io.mpu6050_csv import read_mpu6050_csv
from fusion.planar import _ekf_core as core
from fusion.planar.ekf import EkfNoise, PlanarEKF, fuse, merge_events
from fusion.planar.imu_motion import (
    MOTION_MOVING,
    MOTION_STILL,
    ImuMotionDetector,
    MotionThresholds,
    imu_motion_codes,
)
from fusion.planar.model import NX

BAG = Path(__file__).resolve().parent.parent / "datasets" / "rosbag" / "jackal_sim_test2.bag"
RAW_MPU6050 = Path(__file__).resolve().parent.parent / "datasets" / "mpu6050_raw"


def _heading_corrections(states, t):
    """Per event: the yaw change that the motion model does not explain (rad)."""
    return np.diff(states[:, 2]) - states[:-1, 4] * np.diff(t)


def test_worst_case_no_pose_jump():
    """Long drive without a stop, a large yaw and bias uncertainty, a burst of slips on both
    wheels: every position step is exactly the motion model's (v*dt along the heading), and
    the heading moves beyond w*dt by at most the yaw budget over any stretch of time."""
    patches = tuple(SlipPatch(t0, t0 + 0.6, wheel, 0.5)
                    for t0, wheel in ((20.0, "left"), (21.0, "right"), (22.0, "left"),
                                      (23.0, "right"), (24.0, "left")))
    segments = (straight(6.0, 0.5) + arc(1.0, math.pi, 0.5) + straight(8.0, 0.5)
                + arc(1.5, -math.pi, 0.5) + straight(6.0, 0.5))
    run = simulate(segments, EXAMPLE_ROBOT,
                   ImuModel(gyro_bias=(0.0, 0.0, math.radians(1.5)), vibration=1.0),
                   EncoderModel(separation_error=0.05, slip_patches=patches), seed=3)
    noise = EkfNoise()
    P0 = np.diag([1e-9, 1e-9, math.radians(30.0) ** 2, 0.25, 0.25, math.radians(5.0) ** 2,
                  0.1 ** 2, 0.1 ** 2, noise.gyro_scale_std ** 2, noise.distance_scale_std ** 2])
    x0 = np.zeros(NX)
    x0[3] = 0.5
    ekf = PlanarEKF(EXAMPLE_ROBOT, noise, x0=x0, P0=P0)
    kinds, t, a, b, _ = merge_events(run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks,
                                     EXAMPLE_ROBOT.encode_sampling_time,
                                     imu_motion=imu_motion_codes(run.imu_t, run.gyro,
                                                                 run.accel))
    states, status = ekf.process_batch(kinds, t, a, b)
    assert (status == 1).sum() >= 20  # the slips were seen
    # position: exactly the prediction of the previous state (the rate updates add nothing)
    dt = np.diff(t)
    step = np.hypot(np.diff(states[:, 0]), np.diff(states[:, 1]))
    np.testing.assert_allclose(step, np.abs(states[:-1, 3]) * dt, rtol=1e-9, atol=1e-12)
    assert step.max() <= 0.6 * dt.max()  # never faster than the robot drives (0.5 m/s)
    # heading: the corrections over any 1 s window stay within burst + rate * 1 s
    corr = np.abs(_heading_corrections(states, t))
    edges = np.searchsorted(t[1:], np.arange(t[0], t[-1], 0.1))
    csum = np.concatenate([[0.0], np.cumsum(corr)])
    window = csum[edges[10:]] - csum[edges[:-10]]
    assert window.max() <= noise.yaw_fix_burst + noise.yaw_fix_rate * 1.1 + 1e-12


@pytest.fixture(scope="module")
def jackal():
    """The bundled Jackal bag fused from its IMU and odometry twists: ``(bag, track, ekf)``."""
    from fusion.io.bags import read_bag

    bag = read_bag(BAG, imu_topic="/imu/data", odom_topic="/jackal_velocity_controller/odom")
    imu, odom = bag.imu, bag.odometry
    robot = type(EXAMPLE_ROBOT)(wheel_distance=0.5, speed_ratio=1e-4, encode_sampling_time=0.02)
    track, ekf = fuse(robot, imu.t, imu.gyro[:, 2], twist_t=odom.t, twist_v=odom.v,
                      twist_w=odom.w, imu_motion=imu_motion_codes(imu.t, imu.gyro, imu.accel))
    return bag, track, ekf


def test_jackal_bag_has_no_step_beyond_three_times_the_fastest_twist(jackal):
    bag, track, _ = jackal
    rows = track.output_rows()
    xy = track.states[rows, :2]
    step = np.hypot(*np.diff(xy, axis=0).T)
    bound = 3.0 * np.abs(bag.odometry.v).max() * np.diff(track.t[rows])
    assert np.all(step <= bound), float(step.max())


def test_jackal_skid_steer_twists_do_not_bend_the_gyro_bias(jackal):
    # The bag's skid-steer twists turn 1.4-4 times as fast as the gyro (and not in a fixed
    # ratio): their yaw rate is no measurement of the robot's rotation. The robot never stops,
    # so nothing else tells the bias. Reference: the bag's own IMU orientation (the
    # simulator's attitude), which the raw gyro integral follows within 1.1 deg RMS, so the
    # true bias is about 0. Issue 11 measured a bias of 1.76 deg/s; before the slip-share
    # trust and the vague prior on the first yaw rate: 1.80 deg/s and a yaw RMSE of 58.5 deg;
    # then 0.003 deg/s and 0.97 deg; since the first gyro sample sets w alone (the bias no
    # longer takes a share of the first turn), 0.0000 deg/s and 1.07 deg, the raw gyro
    # integral's own error.
    bag, track, ekf = jackal
    imu, odom = bag.imu, bag.odometry
    q = imu.orientation
    ref = np.unwrap(np.arctan2(2 * (q[:, 0] * q[:, 3] + q[:, 1] * q[:, 2]),
                               1 - 2 * (q[:, 2] ** 2 + q[:, 3] ** 2)))
    rows = track.kind == core.EV_GYRO
    err = track.states[rows, 2] - (np.interp(track.t[rows], imu.t, ref) - ref[0])
    assert math.degrees(np.sqrt(np.mean(err ** 2))) < 3.0
    assert abs(math.degrees(ekf.x[5])) < 0.1
    # most turning twists disagreed: first flagged as slips, then (the wheels' yaw rate
    # disproven) no longer fused for their yaw rate at all, agreeing or not
    stats = ekf.stats
    assert stats["wheel_rate_distrusted"] > 1000
    assert stats["slips"] + stats["wheel_rate_distrusted"] > 0.5 * odom.t.size


def test_imu_motion_separates_rest_from_driving_vibration():
    rng = np.random.default_rng(0)
    t = np.arange(0, 4.0, 0.005)  # 200 Hz
    gyro = rng.normal(0.0, 7e-4, (t.size, 3))
    accel = rng.normal(0.0, 0.04, (t.size, 3)) + np.array([0.0, 0.0, 9.81])
    driving = (t >= 2.0)
    # 1 m/s^2 RMS vibration at 28 Hz and the gyro shaking with it, while driving
    accel[driving] += math.sqrt(2) * np.sin(2 * np.pi * 28 * t[driving])[:, None]
    gyro[driving] += 0.01 * rng.standard_normal((int(driving.sum()), 3))
    codes = imu_motion_codes(t, gyro, accel)
    th = MotionThresholds()
    assert np.all(codes[(t > th.still_time + 0.05) & (t < 2.0)] == MOTION_STILL)
    assert np.all(codes[t > 2.0 + 3 * th.tau] == MOTION_MOVING)
    # streaming equals batch exactly, in any split
    det = ImuMotionDetector()
    parts = [det.update_batch(t[i:i + 37], gyro[i:i + 37], accel[i:i + 37])
             for i in range(0, t.size, 37)]
    np.testing.assert_array_equal(np.concatenate(parts), codes)


def _real_mpu6050(name: str):
    """A bundled raw MPU6050 recording (100 Hz, datasets/mpu6050_raw) in SI units."""
    log = read_mpu6050_csv(RAW_MPU6050 / name)
    return log.t, log.gyro_si(), log.accel_si()


def test_a_real_mpu6050_at_rest_is_still_at_100_and_33_hz():
    # 100 s of a real sensor lying still (noise 0.0013-0.002 rad/s, 0.03-0.05 m/s^2 per
    # sample): thresholds chosen on simulated noise must hold on the real chip's, at its
    # rate and at an outdoor robot's 30-odd Hz (every third sample).
    t, gyro, accel = _real_mpu6050("imu_static_test.csv")
    settled = t > t[0] + MotionThresholds().still_time + 0.05
    for step in (1, 3):
        codes = imu_motion_codes(t[::step], gyro[::step], accel[::step])
        assert not np.any(codes == MOTION_MOVING), step
        assert np.mean(codes[settled[::step]] == MOTION_STILL) > 0.99, step


def test_a_real_mpu6050_turned_by_hand_is_never_still_while_it_turns():
    # The recording turned by hand 90 deg about x: every sample turning faster than 0.1
    # rad/s above the gyro's bias counts as moving (432 of them), while the rest before and
    # after the turn is still again.
    t, gyro, accel = _real_mpu6050("imu_90_x_rot.csv")
    codes = imu_motion_codes(t, gyro, accel)
    rate = gyro[:, 0] - np.median(gyro[t < t[0] + 5.0, 0])
    turning = np.abs(rate) > 0.1
    assert turning.sum() > 300
    assert np.all(codes[turning] == MOTION_MOVING)
    quiet_before = (t > t[0] + 1.0) & (t < t[0] + 12.0)
    quiet_after = t > t[0] + 50.0
    assert np.mean(codes[quiet_before] == MOTION_STILL) > 0.95
    assert np.mean(codes[quiet_after] == MOTION_STILL) > 0.95


@pytest.fixture(scope="module")
def dead_run():
    return physics_scenario("all+dead", seed=11)


def test_dead_encoder_is_flagged_not_fused_and_the_pose_coasts(dead_run):
    run = dead_run
    (t0, length), = run.dead_windows()
    t1 = t0 + length
    codes = imu_motion_codes(run.imu_t, run.gyro, run.accel)
    track, ekf = fuse(run.robot.chassis, run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks,
                      imu_motion=codes)
    wheel = track.kind == core.EV_WHEELS
    inside = wheel & (track.t > t0 + 0.2) & (track.t < t1)
    # (nearly) every frame of the dead feed is a flagged fault; no ZUPT happens inside it
    assert np.mean(track.status[inside] == 7) > 0.95
    assert not np.any(track.status[inside] == 4)
    assert ekf.stats["encoder_faults"] >= inside.sum() * 0.95
    # the pose kept moving: over the window it travelled about as far as the truth did
    g = track.kind == core.EV_GYRO
    at = np.searchsorted(track.t[g], [t0, t1])
    est = track.states[g][at, :2]
    truth = run.truth_at(np.array([t0, t1]))[:, :2]
    moved_true = np.hypot(*(truth[1] - truth[0]))
    moved_est = np.hypot(*(est[1] - est[0]))
    assert moved_true > 1.0
    assert abs(moved_est - moved_true) < 0.25 * moved_true
    # and its position variance grew meanwhile
    assert track.states[g][at[1], NX] > track.states[g][at[0], NX]


def test_bias_is_learnt_within_a_minute_from_a_moving_start():
    """Already driving at the first sample (no rest to take the bias from). Oracle: the gyro's
    effective z offset (additive bias, g-sensitivity, tilt and all) measured as the mean rate
    over the samples where the truth stands still in the second minute. NB: this mission's
    first stop comes after about 10 s."""
    seed = 21
    mission = indoor_mission(seed, 120.0, moving_start=True)
    run = simulate_physics(mission, all_errors(seed), seed)
    codes = imu_motion_codes(run.imu_t, run.gyro, run.accel)
    # already driving at the first sample: no rest to take the bias from
    assert run.truth_v[0] > 0.3
    track, _ = fuse(run.robot.chassis, run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks,
                    imu_motion=codes)
    g = track.kind == core.EV_GYRO
    k = np.searchsorted(track.t[g], 60.0)
    v = np.interp(run.imu_t, run.truth_t, np.abs(run.truth_v))
    w = np.interp(run.imu_t, run.truth_t, np.abs(run.truth_w))
    rest = (v < 1e-6) & (w < 1e-6) & (run.imu_t >= 60.0)
    assert rest.sum() > 200
    assert abs(track.states[g][k, 5] - run.gyro[rest, 2].mean()) < math.radians(0.05)


@pytest.mark.parametrize("seed", [4, 6])
def test_heading_drifted_before_the_first_stop_is_paid_back(seed):
    """A moving start whose first stop comes late (23 s and 27 s): until then the bias is
    poorly known and the heading drifts; the stop teaches the bias, and through its
    correlation the heading drift. The correction beyond the yaw budget is owed and paid as
    the budget refills, not dropped. Oracle: the physics simulator's truth (plain sensors).
    Measured: yaw RMSE 2.1 and 3.6 deg (with the excess dropped: 7.6 and 8.8 deg; with no
    budget at all: 1.6 and 2.7)."""
    from fusion.evaluation.physics_sim import plain_sensors
    from fusion.evaluation.trajectory import yaw_rmse

    run = simulate_physics(indoor_mission(seed, 300.0, moving_start=True),
                           plain_sensors(seed), seed)
    track, _ = fuse(run.robot.chassis, run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks,
                    imu_motion=imu_motion_codes(run.imu_t, run.gyro, run.accel))
    g = track.kind == core.EV_GYRO
    assert math.degrees(yaw_rmse(track.states[g, 2], run.truth_at(track.t[g])[:, 2])) < 4.5
