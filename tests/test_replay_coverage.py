"""What a replay's output cannot cover is said (fusion.jobs.replay.coverage_warnings), and a
gap does not turn into a turn in the counters the trust checks read. Found by a probe of
real-bag quirks: an IMU topic ending 60 s early cut the CSV short without a word, a 20 s
odometry dropout froze the pose unannounced, and its first yaw rate times the gap became
"the odometry turned -704 deg" (it turned +760)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from fusion.evaluation.synthetic import EXAMPLE_ROBOT
from fusion.io.fused_csv import FUSED_CSV_COLUMNS
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
    assert "over them the speed ran on at its last value for 3 s, then the pose stopped" in text
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


def _turning_logdir(path, step_at=None, step=0.0):
    """A log directory of a robot driving a circle (0.2 m/s, 0.5 rad/s) for 40 s, exact
    sensors (IMU 100 Hz, wheel frames 25 Hz); with ``step_at``, every stamp from then on
    moved by ``step`` s (a host clock stepped: the data goes on unbroken)."""
    from fusion.geometry.kinematics import DiffDriveParams
    from fusion.io.logdir import write_logdir

    chassis = DiffDriveParams(wheel_distance=0.3, speed_ratio=1e-4, encode_sampling_time=0.04)
    v, w = 0.2, 0.5
    imu_t = np.arange(0.0, 40.0, 0.01)
    wheel_t = np.arange(0.04, 40.0, 0.04)
    per = chassis.encode_sampling_time / chassis.speed_ratio
    ticks = np.tile([round((v - 0.15 * w) * per), round((v + 0.15 * w) * per)],
                    (wheel_t.size, 1))
    n = imu_t.size
    gyro = np.tile([0.0, 0.0, w], (n, 1))
    accel = np.column_stack([np.zeros(n), np.full(n, v * w), np.full(n, 9.81)])
    if step_at is not None:
        imu_t = np.where(imu_t >= step_at, imu_t + step, imu_t)
        wheel_t = np.where(wheel_t >= step_at, wheel_t + step, wheel_t)
    return write_logdir(path, chassis, imu_t, gyro, accel, wheel_t, ticks)


def test_motion_made_up_where_both_streams_are_silent_is_said(tmp_path):
    # an independent probe's +5 s clock step in a turn (-0.91 rad/s): the heading ran on
    # -156 deg with nothing measured, and the notes only said two gaps ("the pose stopped")
    from fusion.io.fused_csv import read_fused_csv
    from fusion.jobs.replay import replay_logdir

    stepped = replay_logdir(_turning_logdir(tmp_path / "step", 20.0, 5.0), tmp_path / "s.csv")
    (made_up,) = [n for n in stepped.notes if n.startswith("no IMU sample and nothing from")]
    turn, travel = (float(s) for s in re.search(
        r"([-+]?\d+\.\d) deg of turn and (\d+\.\d+) m of travel", made_up).groups())
    # the rate and speed run on for max_extrapolation (3 s), then stop: 0.5 rad/s x 3 s
    assert turn == pytest.approx(np.degrees(0.5 * 3.0), abs=0.5), made_up
    assert travel == pytest.approx(0.2 * 3.0, abs=0.02), made_up
    assert "5.0 s after 19.990 s" in made_up, made_up
    # what the note says is what the output did: the heading's jump over the silence, up to
    # where the run-on starts (at the speeds' own last measurement, within two wheel periods
    # of the silence: 0.04 rad here) and the real turning after it (0.02 s to the first row)
    table = read_fused_csv(tmp_path / "s.csv")
    before, after = np.searchsorted(table["t"], [19.99, 25.0])
    jump = np.degrees(np.unwrap(table["yaw"][[before, after]])[1] - table["yaw"][before])
    assert jump == pytest.approx(turn, abs=np.degrees(0.5 * 2 * 0.04)), (jump, turn)
    # the IMU gap's sentence no longer says the wheels carried the heading
    (imu_gap,) = [n for n in stepped.notes if n.startswith("IMU gaps")]
    assert "had no sample either" in imu_gap and "rested on" not in imu_gap, imu_gap
    unbroken = replay_logdir(_turning_logdir(tmp_path / "ok"), tmp_path / "o.csv")
    assert not [n for n in unbroken.notes if "no IMU sample" in n], unbroken.notes


def test_a_silence_while_standing_still_makes_nothing_up():
    stamps = np.concatenate([np.arange(0.0, 10.0, 0.01), np.arange(20.0, 30.0, 0.01)])
    still = np.zeros((stamps.size, len(FUSED_CSV_COLUMNS)))
    still[:, 0] = stamps
    assert coverage_warnings(stamps, stamps, 3.0, fused=still)[-1].startswith("odometry gaps")
    turning = still.copy()
    turning[:, 5] = 0.01  # rad/s: 3 s of it is 1.7 deg
    assert coverage_warnings(stamps, stamps, 3.0, fused=turning)[-1].startswith(
        "no IMU sample and nothing from the odometry over 1 gap of 1 s or more (10.0 s")
    # a silence under a second (a recorder's flush) is not looked at
    short = np.concatenate([np.arange(0.0, 10.0, 0.01), np.arange(10.9, 30.0, 0.01)])
    turning = np.zeros((short.size, len(FUSED_CSV_COLUMNS)))
    turning[:, 0], turning[:, 5] = short, 1.0
    assert coverage_warnings(short, short, 3.0, fused=turning) == []
