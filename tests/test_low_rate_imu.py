"""A gyro sampled more slowly than the wheel frames come (10 Hz against 25 Hz), both exact, on a
robot that turns left 19 times (a ramp to 1 rad/s over 0.5 s, 1 s at it, a ramp down) while
driving at 0.3 m/s: the heading after the run, against the analytic truth.

Found by an independent probe (its 100 Hz log decimated to 20 Hz: yaw RMSE 0.19 -> 2.04 deg,
nothing said) and reproduced here with perfect sensors. Fused from the gyro alone (the wheels'
yaw rate given no weight) the heading ends exact; with the wheels' yaw rate fused it ends
2.2 deg off, by an amount and sign that change with the phase between the two streams
(wheel stamps moved by -40, -20, 0, +20, +40 ms: +4.5, -2.2, +2.2, +0.1, +1.7 deg), and with
the wheel period (0.02 and 0.05 s: under 0.01 deg; 0.04 s: 2.2). Not the yaw budget, the
stamp noise, the wheel latency, k or c, the tilt, nor lost ZUPTs. Traced event by event: the
heading lags in every ramp by the left-rectangle rule (Q has no (yaw, w) cross term, so an
update of w moves the heading by nothing of the ramp it reveals; 1 deg per ramp here) and
gets it back in the next, up to a residue at the rate's kinks. Adding the exact cross terms
(q_w dt^2/2, q_w dt^3/3) was tried (2026-11-29): the ramps then track (100 Hz RMS over the
run 0.13 -> 0.005 deg; held-out black-box seeds 413-414, yaw RMSE plain 0.23/0.19 -> 0.16/0.13,
the other scenarios within +-0.2), but the final 10 Hz error stayed at 2.2 deg and the
heading's variance grew with the walk of w the gyro had held (NEES inside its bounds on dead
414: 0.79 -> 0.59); not kept. Open.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fusion.geometry.kinematics import DiffDriveParams
from fusion.pipeline.core import FusionPipeline
from fusion.planar.ekf import EkfNoise
from fusion.planar.robot import RobotConfig

CHASSIS = DiffDriveParams(wheel_distance=0.3, speed_ratio=1e-5, encode_sampling_time=0.04)
DT = 1e-4
T = 120.0


def _motion():
    t = np.arange(0.0, T, DT)
    c = t % 6.0
    w = np.where(c < 0.5, c / 0.5, np.where(c < 1.5, 1.0,
                                            np.where(c < 2.0, 1.0 - (c - 1.5) / 0.5, 0.0)))
    v = np.full_like(t, 0.3)
    w[t < 3.0] = 0.0
    v[t < 3.0] = 0.0
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * DT)])
    dist = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * DT)])
    return t, w, yaw, dist


def _final_heading_error(imu_rate: float, wheel_w_std: float | None) -> float:
    t, w, yaw, dist = _motion()
    imu_t = np.arange(1.0, T - 1.0, 1.0 / imu_rate)
    gz = np.interp(imu_t, t, w)
    gyro = np.column_stack([np.zeros_like(gz), np.zeros_like(gz), gz])
    accel = np.tile([0.0, 0.0, 9.81], (imu_t.size, 1))
    wheel_t = np.arange(1.0, T - 1.0, CHASSIS.encode_sampling_time)
    edges = np.concatenate([[wheel_t[0] - CHASSIS.encode_sampling_time], wheel_t])
    half = 0.5 * CHASSIS.wheel_distance
    ticks = np.column_stack([
        np.diff(np.round(np.interp(edges, t, dist - yaw * half) / CHASSIS.speed_ratio)),
        np.diff(np.round(np.interp(edges, t, dist + yaw * half) / CHASSIS.speed_ratio)),
    ]).astype(np.int64)
    noise = EkfNoise() if wheel_w_std is None else dataclasses.replace(
        EkfNoise(), wheel_w_std=wheel_w_std)
    pipe = FusionPipeline(RobotConfig(chassis=CHASSIS, ekf=noise), tilt=False,
                          state_rows=("imu",))
    with pipe:
        pipe.push_arrays(imu_t, gyro, accel, wheel_t, ticks)
    rows = pipe.state_rows
    return float(np.degrees(rows[-1, 3] - np.interp(rows[-1, 0], t, yaw)))


@pytest.mark.parametrize("imu_rate", [100.0, 10.0])
def test_the_gyro_alone_keeps_the_heading_at_any_rate(imu_rate):
    assert abs(_final_heading_error(imu_rate, wheel_w_std=5.0)) < 0.05


def test_exact_wheels_and_a_fast_gyro_keep_the_heading():
    assert abs(_final_heading_error(100.0, None)) < 0.1


@pytest.mark.xfail(strict=True, reason=(
    "open: with a gyro slower than the wheel frames, fusing the wheels' exact yaw rate costs "
    "2.2 deg over 19 turns (module docstring)"))
def test_exact_wheels_and_a_slow_gyro_keep_the_heading():
    assert abs(_final_heading_error(10.0, None)) < 0.5
