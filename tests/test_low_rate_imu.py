"""A gyro sampled more slowly than the wheel frames come (10 Hz against 25 Hz), both exact, on a
robot that turns left 19 times (a ramp to 1 rad/s over 0.5 s, 1 s at it, a ramp down) while
driving at 0.3 m/s: the heading after the run, against the analytic truth.

Found by an independent probe (its 100 Hz log decimated to 20 Hz: yaw RMSE 0.19 -> 2.04 deg,
nothing said) and reproduced here with perfect sensors. Fused from the gyro alone (the wheels'
yaw rate given no weight) the heading ends exact; with the wheels' yaw rate fused it ends
2.2 deg off when every turn starts at a multiple of 6 s, by an amount and sign that change
with the phase between the two streams (wheel stamps moved by -40, -20, 0, +20, +40 ms: +4.5,
-2.2, +2.2, +0.1, +1.7 deg) and with the wheel period (0.02 and 0.05 s: under 0.01 deg; 0.04 s:
2.2). Not the yaw budget, the stamp noise, the wheel latency, k or c, the tilt, nor lost ZUPTs.

What it is (2026-11-29, session 16): a residue at the rate's kinks, the same in every turn.
The filter holds w between events (the left-rectangle rule) on the merged grid of gyro samples
and wheel-frame midpoints, and a wheel frame that straddles a kink reads the period's mean, not
the midpoint's rate (1 rad/s x 0.04 s / 8 off at a ramp's end). Over a ramp up and its ramp
down these cancel when both ramps meet the merged grid at the same phase; 10 Hz and 0.04 s
make a grid of period 0.2 s, which the ramps (starting at 0, 0.5, 1.5, 2 s) meet at two
phases, so about 0.12 deg is left per turn, and since every turn starts at a multiple of 6 s
(a whole number of periods of both streams, its kinks on sample instants of both) it is left
the same way 19 times. (Turns locked at other phases leave other amounts: -0.5 to +0.6 deg,
a review found.) With the turns'
starts spread over a second (any robot whose motion is not locked to its sensors' clocks) the
residues do not add up: final errors over four motions -0.48 to +0.03 deg at 10 Hz, -0.42 to
+0.08 at 20, -0.55 to +0.11 at 30 (the 100 Hz gyro: -0.27 to +0.14, the gyro bias and k
learnt in the turns), where the locked motion gives +2.2, +1.2, +0.9 and -0.03. A robot whose
turns are timed by the clock that also samples its IMU and its wheels (a controller stepping
its setpoints on the sensors' ticks) would see the locked case.

Adding the exact (yaw, w) process-noise cross terms (q_w dt^2/2, q_w dt^3/3) was tried
(2026-11-29): the ramps then track (100 Hz RMS over the run 0.13 -> 0.005 deg; held-out
black-box seeds 413-414, yaw RMSE plain 0.23/0.19 -> 0.16/0.13, the other scenarios within
+-0.2), but the locked 10 Hz final error stayed at 2.2 deg (the straddled frames' share) and
the heading's variance grew with the walk of w the gyro had held (NEES inside its bounds on
dead 414: 0.79 -> 0.59); not kept. Fusing each frame's ticks as the heading's change over its
period (a delayed-state measurement) would remove both shares; not done.
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


def _motion(seed=None):
    """Time, yaw rate, yaw and distance on a 0.1 ms grid: 19 left turns, the k-th starting at
    6k s (locked to the sensors' clocks), or with ``seed`` 3 + 6k s plus up to 1 s drawn."""
    t = np.arange(0.0, T, DT)
    if seed is None:
        starts = 6.0 * np.arange(1, 20)
    else:
        starts = 3.0 + 6.0 * np.arange(19) + np.random.default_rng(seed).uniform(0.0, 1.0, 19)
    w = np.zeros_like(t)
    for start in starts:
        c = t - start
        w += np.where((c >= 0.0) & (c < 0.5), c / 0.5, np.where(
            (c >= 0.5) & (c < 1.5), 1.0, np.where((c >= 1.5) & (c < 2.0), 1.0 - (c - 1.5) / 0.5,
                                                  0.0)))
    v = np.full_like(t, 0.3)
    v[t < 3.0] = 0.0
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * DT)])
    dist = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * DT)])
    return t, w, yaw, dist


def _final_heading_error(imu_rate: float, wheel_w_std: float | None, seed=None) -> float:
    t, w, yaw, dist = _motion(seed)
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
    "open: with a gyro slower than the wheel frames and turns locked to the sensors' clocks, "
    "fusing the wheels' exact yaw rate costs 2.2 deg over 19 turns (module docstring)"))
def test_exact_wheels_and_a_slow_gyro_keep_the_heading():
    assert abs(_final_heading_error(10.0, None)) < 0.5


@pytest.mark.parametrize("imu_rate", [10.0, 20.0, 30.0])
def test_a_slow_gyro_keeps_the_heading_when_the_turns_are_not_locked_to_its_clock(imu_rate):
    # the locked case's residue is the same in every turn; spread over a second, the turns'
    # residues do not add up. Bound: a third of issue 11's 1.5 deg yaw budget, for sensors
    # without error (measured RMS 0.24, 0.22, 0.28 deg; locked 2.2, 1.2, 0.9)
    errors = [_final_heading_error(imu_rate, None, seed) for seed in range(4)]
    assert np.sqrt(np.mean(np.square(errors))) < 0.5, errors
