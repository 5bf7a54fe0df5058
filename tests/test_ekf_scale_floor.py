"""How much of the heading the gyro's scale error alone costs on the physics simulator (issue 11).

Issue 11 asks, on the second simulator with every error on, for a yaw RMSE of at most 1.5 deg
on every seed, also without calibration. The simulated gyro's scale error (0.5-2 %; the
MPU6050's datasheet allows 3 %) is observable from nothing on the robot: the wheels' yaw rate
carries the wheel distance's own error. ``PhysicsRun.reference_heading`` integrates the gyro
with the TRUE bias about the TRUE vertical, so what is left is what the scale (and cross-axis)
error costs: about the best yaw anything gets without a scale calibration or an absolute
heading.

Seeds 0-7 of "all" (none used to choose a parameter; benchmarks/tune_ekf.py tunes on 100-105):

- the reference isolates the scale: on the same missions with every error but the gyro's scale
  and cross-axis it stays within 0.3 deg (measured 0.13-0.19), on "plain" within 0.15
  (0.05-0.09);
- the EKF, uncalibrated, is within 0.5 deg of the reference on every seed (measured: from
  0.75 deg better to 0.31 deg worse): it loses nothing beyond what the scale costs (without
  zero-velocity updates, zupt_frames 10^6, seeds 0 and 5 end 2.5 and 0.75 deg above it: the
  check can fail);
- not asserted (it is what these seeds drew, not a property): the reference itself is above
  1.5 deg on 7 of the 8 seeds (1.25-9.59 deg, printed by benchmarks/ekf_accuracy.py), so the
  issue's uncalibrated bound is below what these sensors allow. With the gyro-scale
  calibration the EKF meets it (benchmarks/ekf_accuracy.py: worst 0.25 deg).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion.evaluation.physics_sim import (
    indoor_mission,
    physics_scenario,
    simulate_physics,
    with_errors,
)
from fusion.evaluation.physics_sim.sensor_model import ERROR_GROUPS
from fusion.evaluation.trajectory import yaw_rmse
from fusion.planar import _ekf_core as core
from fusion.planar.ekf import fuse
from fusion.planar.imu_motion import imu_motion_codes

SEEDS = range(8)


def _fused_deg(run) -> float:
    """Yaw RMSE (deg) of the EKF with its defaults, fed the IMU's z rate as logged."""
    track, _ = fuse(run.robot.chassis, run.imu_t, run.gyro[:, 2], run.wheel_t, run.ticks,
                    imu_motion=imu_motion_codes(run.imu_t, run.gyro, run.accel))
    rows = track.kind == core.EV_GYRO
    return math.degrees(yaw_rmse(track.states[rows, 2], run.truth_at(track.t[rows])[:, 2]))


@pytest.fixture(scope="module")
def all_runs():
    return [physics_scenario("all", seed=seed) for seed in SEEDS]


def test_the_reference_heading_isolates_the_gyro_scale():
    without_scale = [g for g in ERROR_GROUPS if g not in ("gyro-scale", "gyro-cross-axis")]
    for seed in (0, 6):  # 6: the largest reference with every error on
        run = simulate_physics(indoor_mission(seed, 300.0, low_friction=True),
                               with_errors(without_scale, seed=seed), seed)
        assert math.degrees(run.reference_yaw_rmse()) < 0.3, seed
        assert math.degrees(physics_scenario("plain", seed=seed).reference_yaw_rmse()) < 0.15, seed


def test_uncalibrated_ekf_heading_is_as_good_as_the_gyro_scale_allows(all_runs):
    reference = np.array([math.degrees(run.reference_yaw_rmse()) for run in all_runs])
    fused = np.array([_fused_deg(run) for run in all_runs])
    assert np.all(fused <= reference + 0.5), (fused, reference)
