"""The pipeline across a silence of both sources (a stalled host, an epoch stamp after a
monotonic one): bounded cost, bounded extrapolation, the gaps counted in its stats, and
streaming == batch bit for bit with the gap in the stream."""

from __future__ import annotations

import io

import numpy as np
import pytest

from fusion.evaluation.synthetic import EXAMPLE_ROBOT
from fusion.pipeline.core import FusionPipeline
from fusion.pipeline.sources import merge_by_time
from fusion.planar.robot import RobotConfig
from fusion.sinks.text import JsonLinesSink
from fusion.types.constants import STANDARD_GRAVITY as G
from fusion.types.samples import ImuSample, WheelTicks

V = 0.25  # m/s, straight ahead
T = EXAMPLE_ROBOT.encode_sampling_time


def streams(gap: float):
    """5 s at V (IMU 100 Hz, wheel frames every T), silence for ``gap`` s, 5 s more."""
    imu_t = np.arange(0.0, 5.0, 0.01)
    wheel_t = np.arange(T, 5.0, T)
    imu_t = np.concatenate([imu_t, imu_t + 5.0 + gap])
    wheel_t = np.concatenate([wheel_t, wheel_t + 5.0 + gap])
    gyro = np.zeros((imu_t.size, 3))
    accel = np.tile([0.0, 0.0, G], (imu_t.size, 1))
    ticks = np.full((wheel_t.size, 2), round(V * T / EXAMPLE_ROBOT.speed_ratio))
    return imu_t, gyro, accel, wheel_t, ticks


def run(gap: float, batch: bool):
    buf = io.StringIO()
    pipe = FusionPipeline(RobotConfig(chassis=EXAMPLE_ROBOT), [JsonLinesSink(buf, flush=False)])
    imu_t, gyro, accel, wheel_t, ticks = streams(gap)
    with pipe:
        if batch:
            pipe.push_arrays(imu_t, gyro, accel, wheel_t, ticks)
        else:
            imu = [ImuSample(t, g, a) for t, g, a in zip(imu_t.tolist(), gyro, accel)]
            wheels = [WheelTicks(t, int(a), int(b)) for t, (a, b) in zip(wheel_t.tolist(), ticks)]
            for ev in merge_by_time(imu, wheels):
                pipe.push(ev)
    return pipe, buf.getvalue()


@pytest.mark.parametrize("gap", [30.0, 1e5])
def test_a_silence_of_both_sources_costs_bounded_steps_and_moves_the_pose_a_bounded_distance(gap):
    pipe, _ = run(gap, batch=True)
    stats = pipe.finish_stats()
    assert stats.attitude_gaps == 1  # the IMU's 30 s: integrated over one regular period
    assert stats.speed_resets == 2  # v and w forgotten after max_extrapolation
    assert stats.gap_count == 1  # the wheel gap, as before
    events = stats.imu_samples + stats.wheel_frames
    # one or two steps per event between samples, plus the gap's bounded extrapolation: the
    # same for a 30 s and a 1e5 s gap (was 2 million steps for 1e5 s)
    assert pipe.ekf.stats["predictions"] < events + 50
    # distance: 10 s at V measured, at most max_extrapolation at V across the gap
    horizon = pipe.ekf.noise.max_extrapolation
    assert pipe.ekf.x[0] == pytest.approx(V * 10.0, abs=V * horizon + 0.05)
    assert pipe.ekf.x[0] <= V * (10.0 + horizon) + 0.01


def test_streaming_equals_batch_across_the_gap():
    a_pipe, a = run(30.0, batch=True)
    b_pipe, b = run(30.0, batch=False)
    assert a == b and a.count("\n") > 200
    assert a_pipe.finish_stats().as_dict() == b_pipe.finish_stats().as_dict()
