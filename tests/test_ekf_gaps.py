"""The planar EKF across gaps (its module docstring's gap policy) and against implausible
inputs: bounded cost for any gap, bounded extrapolation, a covariance that covers what the
robot could have done meanwhile, corrupt values counted and never fused."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion.evaluation.synthetic import EXAMPLE_ROBOT
from fusion.planar.ekf import EkfNoise, PlanarEKF
from fusion.planar.model import NX

ROBOT = EXAMPLE_ROBOT
NOISE = EkfNoise()
V = 0.25  # m/s
W = 0.0


def moving_filter() -> PlanarEKF:
    """A filter driving straight at V m/s, speeds measured at t = 0 (x0 counts as measured
    at the first input)."""
    x0 = np.zeros(NX)
    x0[3], x0[4] = V, W
    ekf = PlanarEKF(ROBOT, NOISE, x0=x0)
    ekf.update_gyro(0.0, W)
    return ekf


@pytest.mark.parametrize("gap", [10.0, 1e3, 1e5, 1.7e9])  # 1.7e9: an epoch stamp after a
def test_a_gap_of_any_length_costs_a_bounded_number_of_steps(gap):  # monotonic one
    ekf = moving_filter()
    before = ekf.stats["predictions"]
    ekf.update_gyro(gap, W)
    steps = ekf.stats["predictions"] - before
    # extrapolation to max_extrapolation in max_dt steps (60, or 61 with a rounding
    # remainder), then one step for the rest: the same for every gap longer than the horizon
    horizon_steps = math.ceil(NOISE.max_extrapolation / NOISE.max_dt)
    assert horizon_steps + 1 <= steps <= horizon_steps + 2
    assert ekf.stats["speed_resets"] == 2  # v and w forgotten once each
    assert np.all(np.isfinite(ekf.x)) and np.all(np.isfinite(ekf.P))


def test_a_silent_gap_moves_the_pose_at_most_the_horizon_and_the_covariance_covers_the_rest():
    ekf = moving_filter()
    gap = 100.0
    ekf.predict_to(gap)
    # constant-twist motion for max_extrapolation s, then the speeds are unknown (mean 0):
    # 0.75 m, not the 25 m of extrapolating at 0.25 m/s for 100 s
    assert ekf.x[0] == pytest.approx(V * NOISE.max_extrapolation, abs=1e-12)
    assert ekf.x[1] == 0.0 and ekf.x[2] == 0.0
    assert ekf.x[3] == 0.0 and ekf.x[4] == 0.0
    # the forgotten speed keeps its second moment (at least V^2), so the position's standard
    # deviation covers the distance the old speed would have carried the robot
    assert ekf.P[3, 3] >= V ** 2
    assert math.sqrt(ekf.P[0, 0]) >= V * (gap - NOISE.max_extrapolation)
    assert np.linalg.eigvalsh(ekf.P).min() > 0
    np.testing.assert_allclose(ekf.P, ekf.P.T, rtol=1e-12, atol=0)


def test_wheels_lost_while_the_gyro_flows_stop_the_pose_after_the_horizon():
    # wheel frames at 0.25 m/s for 1 s, then only the gyro (100 Hz, no rotation) for 100 s
    T, sr = ROBOT.encode_sampling_time, ROBOT.speed_ratio
    ticks = V * T / sr
    ekf = PlanarEKF(ROBOT, NOISE)
    frames = np.arange(1, 26) * T
    for t in np.arange(0.0, 100.0, 0.01):
        ekf.update_gyro(t, 0.0)
        while frames.size and frames[0] - 0.5 * T <= t:  # in effective-time order
            ekf.update_wheels(frames[0], ticks, ticks)
            frames = frames[1:]
    last_eff = 25 * T - 0.5 * T  # the last frame's effective time (its period's middle)
    # the pose moved with the measured speed until the last frame, then at most the
    # horizon more: <= 0.25 * (0.98 + 3) m, not 25 m
    assert ekf.x[0] <= V * (last_eff + NOISE.max_extrapolation) + 1e-3
    assert ekf.x[0] >= V * (last_eff + NOISE.max_extrapolation) - 0.05  # v took frames to learn
    assert ekf.stats["speed_resets"] == 1  # v; w stays measured by the gyro
    assert math.sqrt(ekf.P[0, 0]) >= V * (100.0 - 0.01 - last_eff - NOISE.max_extrapolation)


def test_the_covariance_after_a_gap_does_not_depend_on_how_the_gap_is_split():
    whole, split = moving_filter(), moving_filter()
    whole.predict_to(100.0)
    for t in (0.3, 0.7, 3.0, 50.0, 99.99, 100.0):
        split.predict_to(t)
    np.testing.assert_allclose(split.P, whole.P, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(split.x, whole.x, rtol=0, atol=1e-15)  # steps split differently


def test_wheels_back_after_an_outage_do_not_move_the_pose_by_the_outage_distance():
    # a robot stopped during the outage and one that kept going look alike afterwards: the
    # returning speed measurement must not be read back into the outage (the random-walk
    # correlation of a plain EKF would add most of V * outage here)
    T, sr = ROBOT.encode_sampling_time, ROBOT.speed_ratio
    ticks = V * T / sr
    ekf = PlanarEKF(ROBOT, NOISE)
    frame_t = [k * T for k in range(1, 26)] + [60.0 + k * T for k in range(1, 26)]
    for t in np.arange(0.0, 61.0, 0.01):
        ekf.update_gyro(t, 0.0)
        while frame_t and frame_t[0] - 0.5 * T <= t:
            ekf.update_wheels(frame_t.pop(0), ticks, ticks)
        if abs(t - 59.99) < 1e-6:
            x_before = ekf.x[0]
    assert x_before <= V * (25 * T - 0.5 * T + NOISE.max_extrapolation) + 1e-3
    # after the outage: about V * (1 s of frames), not V * 59 s more
    assert ekf.x[0] - x_before == pytest.approx(V * 1.0, abs=0.1)
    assert math.sqrt(ekf.P[0, 0]) >= V * 50.0  # the outage's uncertainty stays


def test_a_measurement_after_a_gap_resumes_normal_extrapolation():
    ekf = moving_filter()
    ekf.update_gyro(50.0, 0.0)
    T, sr = ROBOT.encode_sampling_time, ROBOT.speed_ratio
    for k in range(1, 40):  # frames at V again: v is learnt and extrapolated again
        ekf.update_wheels(50.0 + k * T, V * T / sr, V * T / sr)
    x = ekf.x[0]
    ekf.predict_to(ekf.t + 0.2)
    assert ekf.x[0] - x == pytest.approx(V * 0.2, rel=0.02)


@pytest.mark.parametrize(
    ("update", "args"),
    [
        ("update_gyro", (1e200,)),
        ("update_gyro", (-150.0,)),  # > max_rate (100 rad/s)
        ("update_wheels", (1e200, 0)),
        ("update_wheels", (0, 1e6)),  # 1e6 ticks per 40 ms: > max_speed
        ("update_twist", (1e200, 0.0)),
        ("update_twist", (0.0, 1e200)),
        ("update_gyro", (math.nan,)),
        ("update_twist", (math.inf, 0.0)),
    ],
)
def test_implausible_inputs_are_counted_and_never_fused(update, args):
    ekf = moving_filter()
    x, P = ekf.x.copy(), ekf.P.copy()
    status = getattr(ekf, update)(0.01, *args)
    assert status == 6
    assert ekf.stats["invalid"] == 1
    np.testing.assert_array_equal(ekf.x, x)
    np.testing.assert_array_equal(ekf.P, P)
    # and the filter goes on
    assert ekf.update_gyro(0.02, 0.0) == 0
    assert np.all(np.isfinite(ekf.x))
