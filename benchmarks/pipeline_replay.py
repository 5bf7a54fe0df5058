"""Replay throughput and live latency of fusion.pipeline.core.FusionPipeline.

1. Replay: one hour of a synthetic mission with a 200 Hz IMU and 25 Hz wheel frames
   (720 000 + 90 000 events) through the whole pipeline (IMU mount rotation, the wheels'
   knowledge, Keel, tilt-compensated yaw rate, reorder policy, EKF, a FusedOdometry record
   per wheel frame), by the batch entry point ``push_arrays`` (bit-identical to streaming, see
   tests/test_pipeline.py), without a sink and into a JSON lines file; the streaming path
   ``push()`` on a 5-minute slice; and, as the reference, the bare EKF batch
   (``fusion.planar.ekf.fuse`` after ``Keel.update_batch``, no records) on the same hour.
   Target: the hour in under 10 s.
2. Live latency: the demo's simulated robot (STM32 on a pty through the real ChassisLink,
   MPU6050 through the real driver) at 1x real time for ``--live`` seconds; latency from a
   wheel frame's arrival (the link's stamp) to its fused record leaving the pipeline, p50/p99.
   A frame waits until the IMU samples up to the middle of its period are in (the sources'
   watermark); the IMU FIFO is read every 20 ms, so that wait is 0-20 ms. The 60 ms reorder
   window is only the bound when a source stalls.

Usage: python benchmarks/pipeline_replay.py [--hours 1] [--live 20]
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile
import time

import numpy as np


def synthetic_hour(hours: float):
    from fusion.evaluation.synthetic import (
        EXAMPLE_ROBOT,
        EncoderModel,
        ImuModel,
        random_mission,
        simulate,
    )

    duration = 3600.0 * hours
    imu = ImuModel(rate=200.0, gyro_bias=(0.001, -0.001, math.radians(0.5)),
                   gyro_bias_walk=2e-5, vibration=0.5)
    enc = EncoderModel(separation_error=0.03, left_scale_error=-0.0025,
                       right_scale_error=0.0025)
    return simulate(random_mission(duration, seed=11), EXAMPLE_ROBOT, imu, enc, seed=11,
                    dt=0.005)


def replay(run, sinks=(), rate=None) -> tuple[float, int]:
    from fusion.pipeline.core import FusionPipeline
    from fusion.planar.robot import RobotConfig

    pipe = FusionPipeline(RobotConfig(chassis=run.robot), list(sinks), imu_rate_hz=200.0,
                          publish_rate_hz=rate)
    t0 = time.perf_counter()
    with pipe:
        pipe.push_arrays(run.imu_t, run.gyro, run.accel, run.wheel_t, run.ticks)
    return time.perf_counter() - t0, pipe.stats.records


def streaming(run, seconds: float) -> tuple[float, int]:
    from fusion.pipeline.core import FusionPipeline
    from fusion.pipeline.sources import merge_by_time
    from fusion.planar.robot import RobotConfig
    from fusion.types.samples import ImuSample, WheelTicks

    ni = int(np.searchsorted(run.imu_t, seconds))
    nw = int(np.searchsorted(run.wheel_t, seconds))
    imu = [ImuSample(t, run.gyro[i], run.accel[i]) for i, t in enumerate(run.imu_t[:ni])]
    wh = [WheelTicks(t, int(a), int(b)) for t, (a, b) in zip(run.wheel_t[:nw].tolist(),
                                                             run.ticks[:nw].tolist())]
    events = list(merge_by_time(imu, wh))
    pipe = FusionPipeline(RobotConfig(chassis=run.robot), imu_rate_hz=200.0)
    t0 = time.perf_counter()
    with pipe:
        for ev in events:
            pipe.push(ev)
    return time.perf_counter() - t0, len(events)


def bare_ekf(run) -> float:
    from fusion.attitude.keel import Keel
    from fusion.geometry.mount import vertical_rate
    from fusion.planar.ekf import fuse

    t0 = time.perf_counter()
    q = Keel(sample_period=0.005).update_batch(run.gyro, run.accel, timestamps=run.imu_t)
    fuse(run.robot, run.imu_t, vertical_rate(run.gyro, q), run.wheel_t, run.ticks)
    return time.perf_counter() - t0


def live_latency(seconds: float, speed: float = 1.0) -> tuple[float, float, int]:
    from drivers.mpu6050 import MPU6050
    from drivers.serial_link import ChassisLink
    from drivers.sim.robot import LoopingMission, ScaledClock, SimRobot, SimRobotParams
    from fusion.cli.demo import nominal_config, warm_up
    from fusion.pipeline.core import FusionPipeline
    from fusion.pipeline.live import LiveRunner

    params = SimRobotParams()
    cfg = nominal_config(params)
    warm_up(cfg)
    clock = ScaledClock(speed)
    robot = SimRobot(clock, params, keep_truth=False)
    ch = cfg.robot.chassis
    link = ChassisLink(robot.port, period=ch.encode_sampling_time, clock=clock)
    link.start(wait=5.0)
    imu = MPU6050(robot.bus, clock=clock, sample_rate_hz=100.0)
    pipe = FusionPipeline(cfg.robot, reorder_window=0.06, clock=clock).open()
    robot.start()
    runner = LiveRunner(pipe, link=link, imu=imu).start()
    t0 = clock()
    mission = LoopingMission(link, ch, clock, t0)

    def tick() -> bool:
        return mission() - t0 >= seconds * speed

    try:
        runner.run(until=tick, poll=0.01)
    finally:
        runner.stop()
        link.close()
        robot.close()
        imu.close()
        pipe.close()
    p50, p99 = pipe.latency_percentiles(50, 99)
    return p50 / speed, p99 / speed, pipe.stats.records


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--live", type=float, default=20.0, help="live seconds (0: skip)")
    args = ap.parse_args()
    from fusion.sinks.text import JsonLinesSink

    t = time.perf_counter()
    run = synthetic_hour(args.hours)
    n = run.imu_t.size + run.wheel_t.size
    print(f"synthetic log: {run.imu_t.size} IMU samples (200 Hz) + {run.wheel_t.size} wheel "
          f"frames (25 Hz), {run.duration / 3600:.2f} h; made in {time.perf_counter() - t:.1f} s")
    replay(synthetic_hour(0.01))  # compile / load the numba cores first
    ref = bare_ekf(run)
    print(f"reference, bare Keel + EKF batch (no records):   {ref:6.2f} s  "
          f"{n / ref:10.0f} samples/s")
    dt, recs = replay(run)
    print(f"pipeline replay, a record per wheel frame:      {dt:6.2f} s  {n / dt:10.0f} "
          f"samples/s  ({recs} records; {dt / ref:.2f}x the bare filters; target < 10 s "
          f"per hour: {'met' if dt / args.hours < 10 else 'NOT met'})")
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "fused.jsonl")
        dt_j, _ = replay(run, [JsonLinesSink(path, flush=False)])
        size = os.path.getsize(path) / 1e6
    print(f"  + JSON lines file sink ({size:.0f} MB):            {dt_j:6.2f} s  "
          f"{n / dt_j:10.0f} samples/s")
    dt_r, recs_r = replay(run, rate=10.0)
    print(f"pipeline replay, 10 Hz records (seed 000):      {dt_r:6.2f} s  "
          f"{n / dt_r:10.0f} samples/s  ({recs_r} records)")
    dt_s, ns = streaming(run, min(300.0, run.duration))
    print(f"streaming push(), first {min(300.0, run.duration):.0f} s:                "
          f"{dt_s:6.2f} s  {ns / dt_s:10.0f} samples/s  (batch is "
          f"{(n / dt) / (ns / dt_s):.1f}x faster)")
    if args.live > 0:
        p50, p99, recs = live_latency(args.live)
        print(f"live latency, wheel frame arrival -> fused record, {args.live:.0f} s at 1x "
              f"({recs} records): p50 {p50 * 1e3:.1f} ms, p99 {p99 * 1e3:.1f} ms "
              f"(IMU FIFO read every 20 ms; reorder window bound 60 ms)")


if __name__ == "__main__":
    main()
