"""The attitude filters across gaps (the gap policy of fusion.attitude.mahony and
fusion.attitude.keel) and against corrupt samples: attitude after a gap against the closed-form
rotation, the bias never replaced by one sample, constant cost, nothing poisoned."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusion.attitude.keel import Keel
from fusion.attitude.mahony import Mahony
from fusion.types.constants import STANDARD_GRAVITY as G

UP = np.array([0.0, 0.0, G])
RATE = 0.01  # rad/s about the body x axis: roll = RATE * t
DT = 0.01


def truth(t: float) -> Rotation:
    """Body -> world at time t s of a constant roll rate from level (closed form)."""
    return Rotation.from_rotvec([RATE * t, 0.0, 0.0])


def accel_at(t: float) -> np.ndarray:
    """Specific force in the body frame, m/s^2 (at rest but for the slow roll)."""
    return truth(t).inv().apply(UP)


def up_error(q: np.ndarray, t: float) -> float:
    """Angle (rad) between the estimated and the true world-up seen from the body."""
    est = Rotation.from_quat([q[1], q[2], q[3], q[0]]).inv().apply([0.0, 0.0, 1.0])
    true = truth(t).inv().apply([0.0, 0.0, 1.0])
    return math.atan2(float(np.linalg.norm(np.cross(est, true))), float(np.dot(est, true)))


FILTERS = {
    "mahony": lambda: Mahony(sample_period=DT),
    "keel": lambda: Keel(sample_period=DT),
}


@pytest.mark.parametrize("name", FILTERS)
@pytest.mark.parametrize("gap", [30.0, 1e5])
def test_attitude_after_a_gap_at_constant_rate_matches_the_closed_form(name, gap):
    f = FILTERS[name]()
    gyro = np.array([RATE, 0.0, 0.0])
    for t in np.arange(0.0, 10.0, DT):
        f.update(gyro, accel_at(t), timestamp=t)
    t_end = 10.0 - DT + gap
    q = f.update(gyro, accel_at(t_end), timestamp=t_end)
    # roll = RATE * t_end (0.40 rad after 30 s; not the 1.17 rad of one first-order step):
    # the inclination re-initialised from the accelerometer is the closed form's
    assert up_error(q, t_end) < 1e-9
    roll, pitch, yaw = f.euler
    assert math.remainder(roll - RATE * t_end, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
    assert abs(pitch) < 1e-9 and abs(yaw) < 1e-9  # the heading is kept
    assert f.counters.gaps == 1
    assert np.all(np.isfinite(f.gyro_bias))


@pytest.mark.parametrize("name", FILTERS)
def test_the_bias_is_not_replaced_by_the_sample_after_a_gap(name):
    f = FILTERS[name]()
    bias = np.array([0.01, -0.02, 0.005])
    t = np.arange(0.0, 20.0, DT)
    for ti in t:  # 20 s at rest: the bias is learnt
        f.update(bias, UP, timestamp=ti)
    learnt = f.gyro_bias
    np.testing.assert_allclose(learnt, bias, atol=2e-3)
    rest_before = f.counters.rest_samples
    # after 30 s of silence, a reading 0.02 rad/s off (still inside the rest thresholds):
    # one step of rest refinement over the gap (dt / (tau + dt) = 30 / 33) would have moved
    # 91 % of the bias to it
    t_gap = t[-1] + 30.0
    f.update(bias + np.array([0.02, 0.0, 0.0]), UP, timestamp=t_gap)
    np.testing.assert_array_equal(f.gyro_bias, learnt)
    assert f.counters.rest_samples == rest_before  # the rest detector restarted
    # rest detection resumes after rest_min_duration (1.5 s) of regular samples
    n_quiet = 0
    for k in range(1, 301):
        f.update(bias, UP, timestamp=t_gap + k * DT)
        if f.counters.rest_samples == rest_before:
            n_quiet = k
    assert 1.4 / DT <= n_quiet <= 1.6 / DT


@pytest.mark.parametrize("name", FILTERS)
def test_after_a_gap_the_inclination_waits_for_a_usable_accelerometer(name):
    f = FILTERS[name]()
    gyro = np.array([RATE, 0.0, 0.0])
    for t in np.arange(0.0, 5.0, DT):
        f.update(gyro, accel_at(t), timestamp=t)
    t1 = 5.0 - DT + 30.0
    f.update(gyro, np.zeros(3), timestamp=t1)  # no accelerometer on the gap's sample
    assert f.counters.gaps == 1
    q = f.update(gyro, accel_at(t1 + DT), timestamp=t1 + DT)
    assert up_error(q, t1 + DT) < 1e-9


@pytest.mark.parametrize("name", FILTERS)
@pytest.mark.parametrize(
    ("gyro", "accel"),
    [
        ([1e200, 0.0, 0.0], UP),
        ([0.0, -1e200, 0.0], UP),
        ([150.0, 0.0, 0.0], UP),  # faster than max_gyro (100 rad/s): no MEMS gyro reads it
        ([math.nan, 0.0, 0.0], UP),
        ([0.0, 0.0, 0.0], [0.0, 0.0, 1e200]),
        ([0.0, 0.0, 0.0], [1e150, 0.0, 0.0]),
        ([0.0, 0.0, 0.0], [0.0, 0.0, 2000.0]),  # above max_accel (1000 m/s^2)
        ([0.0, 0.0, 0.0], [math.inf, 0.0, 0.0]),
    ],
)
def test_corrupt_samples_are_skipped_and_counted_never_poisoning_the_state(name, gyro, accel):
    f = FILTERS[name]()
    for _ in range(50):
        f.update(np.zeros(3), UP)
    before = f.quaternion
    q = f.update(np.array(gyro, dtype=float), np.array(accel, dtype=float))
    c = f.counters
    assert c.gyro_skipped + c.accel_skipped == 1
    assert np.all(np.isfinite(q)) and np.all(np.isfinite(f.gyro_bias))
    assert up_error(q, 0.0) < 1e-6 and up_error(before, 0.0) < 1e-6
    for _ in range(10):  # and it goes on (a zero quaternion used to raise ZeroDivisionError)
        q = f.update(np.zeros(3), UP)
    assert up_error(q, 0.0) < 1e-6


def test_keel_ignores_a_corrupt_known_acceleration():
    plain, told = Keel(sample_period=DT), Keel(sample_period=DT)
    for k in range(200):
        a = accel_at(k * DT)
        q_plain = plain.update(np.array([RATE, 0.0, 0.0]), a)
        bad = [1e200, 0.0, 0.0] if k == 100 else [0.0, 0.0, 0.0]
        q_told = told.update(np.array([RATE, 0.0, 0.0]), a, known_accel=bad)
    np.testing.assert_array_equal(q_told, q_plain)
