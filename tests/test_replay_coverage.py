"""What a replay's output cannot cover is said (fusion.jobs.replay.coverage_warnings), and a
gap does not turn into a turn in the counters the trust checks read. Found by a probe of
real-bag quirks: an IMU topic ending 60 s early cut the CSV short without a word, a 20 s
odometry dropout froze the pose unannounced, and its first yaw rate times the gap became
"the odometry turned -704 deg" (it turned +760)."""

from __future__ import annotations

import numpy as np

from fusion.evaluation.synthetic import EXAMPLE_ROBOT
from fusion.jobs.replay import coverage_warnings
from fusion.pipeline.core import FusionPipeline
from fusion.planar.robot import RobotConfig


def test_spans_and_gaps_beyond_the_extrapolation_limit_are_named():
    imu = np.arange(0.0, 100.0, 0.01)
    odom = np.arange(0.0, 160.0, 0.1)
    (text,) = coverage_warnings(imu, odom, 3.0)
    assert "0.0 s before and 59.9 s after the IMU's samples are not in a CSV output" in text
    (text,) = coverage_warnings(odom, imu, 3.0)
    assert "over the 0.0 s before and 59.9 s after the odometry the pose stands still" in text
    gappy = np.concatenate([odom[odom < 50.0], odom[odom >= 70.0]])
    (text,) = coverage_warnings(np.arange(0.0, 160.0, 0.01), gappy, 3.0)
    assert text.startswith("odometry gaps longer than 3 s: 1, 20.1 s in all")
    assert "over them the pose stopped" in text
    # within the limit: nothing (a 2 s head start of the IMU is the normal case)
    assert coverage_warnings(np.arange(-2.0, 100.0, 0.01), odom[odom < 101.0], 3.0) == []


def test_one_recording_on_two_clocks_is_named():
    # the same 300 s, the odometry's stamps 100 s later (an independent probe's wheels.csv on
    # another clock: fused into a -19 deg/s bias, the clocks never named)
    imu = np.arange(0.0, 300.0, 0.01)
    odom = np.arange(0.04, 300.0, 0.04) + 100.0
    shifted, *spans = coverage_warnings(imu, odom, 3.0, "wheel frames")
    assert shifted.startswith("the wheel frames and the IMU span the same 300.0 s shifted by "
                              "+100.040 s: their stamps are on two clocks"), shifted
    assert len(spans) == 2
    # a recording that only started late is no clock: its end is the IMU's
    assert not any("two clocks" in w for w in coverage_warnings(imu, odom[odom < 300.0], 3.0))
    assert not any("two clocks" in w for w in coverage_warnings(imu, odom - 100.0, 3.0))


def test_a_gap_does_not_multiply_the_next_rate_into_the_turn_counters():
    # twists turning at 0.5 rad/s for 10 s, a 20 s gap, 10 s more: 10 rad turned, not 20
    robot = RobotConfig(EXAMPLE_ROBOT)
    t = np.concatenate([np.arange(0.0, 10.0, 0.1), np.arange(30.0, 40.0, 0.1)])
    with FusionPipeline(robot, sources=["twist"]) as pipe:
        pipe.push_arrays(twist_t=t, twist_v=np.full(t.size, 0.5), twist_w=np.full(t.size, 0.5))
    # 99 + 99 intervals of 0.1 s at 0.5 rad/s (the first twist after the gap adds nothing)
    assert abs(pipe.stats.twist_turn - 0.5 * 19.8) < 1e-9, pipe.stats.twist_turn


def test_an_accelerometer_that_does_not_read_gravity_is_fused_level():
    # zero rows (not provided), gravity removed by the driver, g units: no tilt to take from
    # it (the outdoor terrain bag with gravity removed: 13.1 m of GPS RMSE tilted, 1.6 level)
    from fusion.jobs.replay import Streams
    from fusion.types.constants import STANDARD_GRAVITY

    t = np.arange(0.0, 10.0, 0.01)
    rng = np.random.default_rng(0)

    def streams(mean_z):
        accel = np.column_stack([rng.normal(0.0, 0.3, t.size), rng.normal(0.0, 0.3, t.size),
                                 np.full(t.size, mean_z)])
        return Streams(t, np.zeros((t.size, 3)), accel)

    assert streams(STANDARD_GRAVITY).level_note() == ""
    assert streams(0.85 * STANDARD_GRAVITY).level_note() == ""  # sensor error, a slope
    assert "does not read gravity (its mean is" in streams(0.0).level_note()
    assert "does not read gravity" in streams(1.0).level_note()  # in g
    zero = Streams(t, np.zeros((t.size, 3)), np.zeros((t.size, 3)))
    assert zero.level_note().startswith("the accelerometer reads zero throughout")


def test_odometry_turns_in_an_imu_gap_are_not_counted_against_the_gyro():
    # twists turning at 0.5 rad/s for 60 s, the IMU (gyro reading the same turn) silent from
    # 20 to 50 s: the gyro counts 30 s of turning, and so must the odometry, or
    # heading_divergence compares 30 s of turns with 60 (the terrain outdoor bag with a
    # 30 s IMU gap in a turn: "the odometry turned +510 deg, the gyro +100 deg" on a track
    # 2 m RMS off GPS). Counted up to max_extrapolation after the last sample before the
    # gap, and the same bits in one batch or one event at a time (a live run finds the gap
    # only when the IMU comes back).
    from fusion.types.samples import ImuSample

    robot = RobotConfig(EXAMPLE_ROBOT)
    longest = robot.ekf.max_extrapolation
    twist_t = np.arange(0.0, 60.0, 0.1)
    imu_t = np.arange(0.0, 60.0, 0.01)
    imu_t = imu_t[(imu_t < 20.0) | (imu_t >= 50.0)]
    gyro = np.tile([0.0, 0.0, 0.5], (imu_t.size, 1))
    accel = np.tile([0.0, 0.0, 9.81], (imu_t.size, 1))
    v = np.full(twist_t.size, 0.5)
    with FusionPipeline(robot, sources=["imu", "twist"], tilt=False) as batch:
        batch.push_arrays(imu_t, gyro, accel, twist_t=twist_t, twist_v=v, twist_w=v)
    covered = (twist_t <= imu_t[imu_t < 20.0][-1] + longest) | (twist_t >= 50.0)
    steps = np.diff(twist_t, prepend=twist_t[0])
    expected = float(np.sum(0.5 * steps[covered]))
    assert abs(batch.stats.twist_turn - expected) < 1e-9, (batch.stats.twist_turn, expected)
    assert abs(batch.stats.gyro_turn - 0.5 * (imu_t.size - 2) * 0.01) < 1e-6
    events = sorted([(t, 0, i) for i, t in enumerate(imu_t.tolist())]
                    + [(t, 1, i) for i, t in enumerate(twist_t.tolist())])
    with FusionPipeline(robot, sources=["imu", "twist"], tilt=False) as live:
        for t, kind, i in events:
            if kind == 0:
                live.push(ImuSample(t, gyro[i], accel[i]))
            else:
                live.push_twist(t, 0.5, 0.5)
    assert live.stats.twist_turn == batch.stats.twist_turn
