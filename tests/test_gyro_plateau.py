"""fusion.jobs.streams.gyro_plateau: a gyro axis that sits at its largest magnitude on runs
of samples has saturated; on real MPU-6050 recordings and on constructed rates."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fusion.io.mpu6050_csv import read_mpu6050_csv
from fusion.jobs.streams import PLATEAU_RUN, gyro_plateau


def test_the_bundled_real_mpu6050_recording_saturates_where_its_register_does():
    # A real MPU-6050 calibration recording (datasets/mpu6050_raw, raw counts): its gyro x
    # axis sits at -32768, the int16 register's end, on runs of samples while the board was
    # turned faster than its full scale; the other two recordings never get there.
    root = Path(__file__).resolve().parents[1] / "datasets" / "mpu6050_raw"
    top, samples, axis = gyro_plateau(np.asarray(
        read_mpu6050_csv(root / "example_data_calibration.csv").gyro, dtype=float))
    assert (top, axis) == (32768.0, 0) and samples >= 5
    for name in ("imu_90_x_rot.csv", "imu_static_test.csv"):
        assert gyro_plateau(np.asarray(read_mpu6050_csv(root / name).gyro, dtype=float)) is None


def test_a_lone_largest_reading_is_no_plateau_and_a_run_is():
    rng = np.random.default_rng(3)
    gyro = 0.6 * np.sin(np.linspace(0, 20, 3000))[:, None] * [0.1, 1.0, 0.2]
    gyro = np.round((gyro + 0.003 * rng.standard_normal(gyro.shape)) * 131 * 57.3) / (131 * 57.3)
    assert gyro_plateau(gyro) is None  # quantised like the chip, noise never repeats the top
    clipped = np.clip(gyro, -0.5, 0.5)
    top, samples, axis = gyro_plateau(clipped)
    assert (top, axis) == (0.5, 1) and samples == int(np.sum(np.abs(gyro[:, 1]) >= 0.5))
    short = gyro.copy()
    short[1000:1000 + PLATEAU_RUN - 1, 1] = 0.9  # a run one short of PLATEAU_RUN
    assert gyro_plateau(short) is None
