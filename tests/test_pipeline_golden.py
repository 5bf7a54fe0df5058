"""Golden-output regression: replaying a raw capture gives the same bytes every time.

Inputs (committed, ``tests/data/golden_replay/``): ``robot.toml`` (a tilted IMU mount and EKF
tuning), ``imu.csv`` (IMU frame) and ``wheels.uart2``, a timed DATA-uart2 capture
(:class:`fusion.io.uart2.Uart2CaptureWriter`: the host time and the bytes of each read) of the
wheel frames with line noise between some of them. They were made by :func:`make_inputs` from
fusion.evaluation.synthetic with a fixed seed. The expected output ``fused.jsonl`` (JSON lines,
10 Hz as seed 000 publishes) is compared byte for byte.

To change the output *intentionally* (a deliberate change of the filters or of the record
format), regenerate it and review the diff before committing::

    FUSION_REGENERATE_GOLDEN=1 python -m pytest tests/test_pipeline_golden.py
    git diff --stat tests/data/golden_replay/fused.jsonl

The inputs themselves only change with ``python tests/test_pipeline_golden.py --inputs``.
"""

from __future__ import annotations

import io
import math
import os
import sys
from pathlib import Path

import numpy as np

from fusion.pipeline.core import FusionPipeline
from fusion.pipeline.sources import capture_events, logdir_events, replay
from fusion.planar.robot import RobotConfig
from fusion.sinks.text import JsonLinesSink

DATA = Path(__file__).parent / "data" / "golden_replay"
GOLDEN = DATA / "fused.jsonl"
RATE_HZ = 10.0


def make_inputs(folder: Path = DATA) -> None:
    """Write the committed inputs (deterministic: fixed seeds)."""
    from drivers.chassis import encode_wheel_frame
    from fusion.evaluation.synthetic import (
        EXAMPLE_ROBOT,
        EncoderModel,
        ImuModel,
        SlipPatch,
        arc,
        simulate,
        spin,
        stop,
        straight,
    )
    from fusion.geometry import quaternion as quat
    from fusion.io.logdir import write_logdir
    from fusion.planar.ekf import EkfNoise

    segs = (stop(1.5) + straight(1.2, 0.4) + spin(math.pi / 2, 1.0) + arc(0.8, math.pi / 2)
            + stop(1.5))
    imu = ImuModel(gyro_bias=(0.002, -0.001, math.radians(0.5)), vibration=0.3)
    enc = EncoderModel(separation_error=0.03, left_scale_error=-0.0025,
                       right_scale_error=0.0025, slip_patches=(SlipPatch(3.0, 3.5, "left"),))
    run = simulate(segs, EXAMPLE_ROBOT, imu, enc, seed=2026)
    robot = RobotConfig(chassis=EXAMPLE_ROBOT, imu_mount_rpy=(0.03, -0.02, 0.0),
                        ekf=EkfNoise(late_tolerance=0.04))
    # the sensor is tilted on the robot: IMU-frame vectors = inverse mount rotation of body ones
    q = robot.imu_to_base()
    gyro, accel = quat.rotate_inverse(q, run.gyro), quat.rotate_inverse(q, run.accel)
    folder.mkdir(parents=True, exist_ok=True)
    write_logdir(folder, robot, run.imu_t, gyro, accel, truth_t=run.truth_t[::10],
                 truth=run.truth[::10])
    rng = np.random.default_rng(2026)
    from fusion.io.uart2 import Uart2CaptureWriter

    with Uart2CaptureWriter(folder / "wheels.uart2", overwrite=True) as cap:
        for k, (left, right) in enumerate(run.ticks.tolist()):
            data = b""
            if k % 17 == 5:
                data += bytes(rng.integers(0, 256, int(rng.integers(1, 6)), dtype=np.uint8))
            data += encode_wheel_frame(left, right)
            # one read per frame, returning 1-3 ms after the period ended
            cap.write(round(float(run.wheel_t[k]) + float(rng.uniform(0.001, 0.003)), 6), data)


def replay_bytes(batch: bool = False) -> str:
    robot, events = logdir_events(DATA)
    buf = io.StringIO()
    pipe = FusionPipeline(robot, [JsonLinesSink(buf, flush=False)], publish_rate_hz=RATE_HZ)
    if batch:
        from fusion.io.imu_csv import read_imu_csv

        imu = read_imu_csv(DATA / "imu.csv")
        frames, _ = capture_events(DATA / "wheels.uart2", robot.chassis.encode_sampling_time)
        with pipe:
            pipe.push_arrays(imu.t, imu.gyro, imu.accel, [f.t for f in frames],
                             [(f.left, f.right) for f in frames])
    else:
        replay(pipe, events)
    return buf.getvalue()


def test_replay_of_the_raw_capture_matches_the_golden_output_byte_for_byte():
    out = replay_bytes()
    if os.environ.get("FUSION_REGENERATE_GOLDEN"):
        GOLDEN.write_text(out, encoding="utf-8")
    golden = GOLDEN.read_text(encoding="utf-8")
    assert out.count("\n") == golden.count("\n") > 80
    if out != golden:
        for n, (a, b) in enumerate(zip(out.splitlines(), golden.splitlines()), start=1):
            assert a == b, f"{GOLDEN}:{n} differs (see this file's docstring to regenerate)"
    assert out == golden


def test_replay_is_repeatable_and_the_batch_path_agrees():
    first = replay_bytes()
    assert replay_bytes() == first
    assert replay_bytes(batch=True) == first


def test_the_golden_output_follows_the_simulated_truth():
    """The golden bytes are not just stable but right: the last record is within 2 cm and
    1 deg of the simulator's truth (truth.csv) despite the 3 % separation error, a 0.5 %
    radius mismatch, a slip patch and a 0.5 deg/s gyro bias."""
    import json

    from fusion.io.logdir import read_truth_csv

    t_truth, truth = read_truth_csv(DATA / "truth.csv")
    last = json.loads(GOLDEN.read_text().splitlines()[-1])
    x = np.interp(last["t"], t_truth, truth[:, 0])
    y = np.interp(last["t"], t_truth, truth[:, 1])
    yaw = np.interp(last["t"], t_truth, np.unwrap(truth[:, 2]))
    assert math.hypot(last["x"] - x, last["y"] - y) < 0.02
    assert abs(math.remainder(last["yaw"] - yaw, 2 * math.pi)) < math.radians(1.0)


def test_the_capture_decodes_to_every_frame():
    """The noise between frames costs no frame (one read per frame was recorded)."""
    frames, stats = capture_events(DATA / "wheels.uart2", 0.04)
    sent = len((DATA / "wheels.uart2").read_text().splitlines()) - 1
    assert len(frames) == stats["frames"] == sent > 250
    assert stats["bytes_skipped"] > 0


if __name__ == "__main__":  # python tests/test_pipeline_golden.py --inputs
    if sys.argv[1:] == ["--inputs"]:
        make_inputs()
        print(f"wrote the inputs in {DATA}; now regenerate {GOLDEN.name} (see the docstring)")
    else:
        print(__doc__)
