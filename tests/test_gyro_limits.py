"""What a gyro log cannot be (fusion.calibration.gyro_limits): beyond every MPU6050 full scale,
or held at one. Oracle: constructed MPU6050 readings (131 LSB per deg/s at +-250 deg/s, 16-bit
limits +32767/-32768, the driver taking a bias off), whose clipped samples are known."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion.calibration.gyro_limits import check_gyro_units, saturated_samples

LSB = math.radians(1.0 / 131.0)  # rad/s per count at +-250 deg/s


def _readings(true_z, bias_counts=400, noise_counts=6.0, seed=0):
    """(N, 3) rad/s as a driver gives them: counts = true/LSB + bias + noise, clipped to the
    16-bit range, then the bias (known to the driver) taken off. Returns also which samples
    the chip clipped."""
    rng = np.random.default_rng(seed)
    counts = np.round(true_z / LSB + bias_counts + rng.normal(0.0, noise_counts, true_z.size))
    clipped = (counts > 32767) | (counts < -32768)
    counts = np.clip(counts, -32768, 32767)
    z = (counts - bias_counts) * LSB
    xy = rng.normal(0.0, noise_counts, (true_z.size, 2)) * LSB
    return np.column_stack([xy, z]), clipped


def test_both_limits_of_a_biased_16_bit_gyro_are_found():
    # turns to +-300 deg/s at 200 Hz: the chip clips at +32767 and -32768 counts, which the
    # bias of 400 counts moves to +247.1 and -253.2 deg/s. One limit per axis (the larger
    # magnitude) missed every sample clipped at the other (a review's +25 % wheel_distance).
    t = np.arange(0.0, 20.0, 0.005)
    true = math.radians(300.0) * np.sin(2 * math.pi * t / 5.0)
    gyro, clipped = _readings(true)
    assert clipped[true > 0].any() and clipped[true < 0].any()
    found = saturated_samples(gyro)
    np.testing.assert_array_equal(found, clipped)


def test_a_real_peak_is_no_clip():
    # unclipped turns peaking at 240 and 100 deg/s with the chip's noise, and a 100 deg/s
    # plateau held for seconds (a constant turn: far from any full scale)
    t = np.arange(0.0, 20.0, 0.005)
    for peak in (240.0, 100.0):
        gyro, clipped = _readings(math.radians(peak) * np.sin(2 * math.pi * t / 5.0))
        assert not clipped.any() and not saturated_samples(gyro).any()
    steady = np.full(t.size, math.radians(100.0))
    gyro, _ = _readings(steady, noise_counts=0.0)
    assert not saturated_samples(gyro).any()


def test_a_gyro_in_degrees_per_second_is_named():
    gyro = np.zeros((10, 3))
    gyro[5, 1] = 57.3  # 1 rad/s written in deg/s
    with pytest.raises(ValueError, match=r"reads up to 57\.3 rad/s on one axis.*deg/s"):
        check_gyro_units(gyro)
    check_gyro_units(np.radians(gyro))  # 1 rad/s: fine
