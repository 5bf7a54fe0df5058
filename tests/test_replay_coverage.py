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
