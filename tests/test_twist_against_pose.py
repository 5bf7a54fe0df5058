"""fusion.io.twist_against_pose: a twist compared with its own pose, interval by interval, on
analytic motions (a circle driven at constant speed, its poses written from the circle's
equations, not integrated by the library)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion.io.twist_against_pose import MIN_PATH, twist_against_pose


def _circle(speed=0.5, radius=2.0, period=0.1, duration=40.0, start=1.7e9):
    """Stamps, poses and twists of a robot driving a circle counter-clockwise (speed m/s,
    radius m) from (radius, 0) heading +y; epoch stamps as a bag's."""
    t = start + np.arange(0.0, duration, period)
    w = speed / radius
    phase = w * (t - t[0])
    x, y = radius * np.cos(phase), radius * np.sin(phase)
    yaw = np.angle(np.exp(1j * (phase + math.pi / 2)))
    return t, x, y, yaw, np.full(t.size, speed), np.full(t.size, w)


def test_a_driver_whose_twist_and_pose_agree():
    t, x, y, yaw, v, w = _circle()
    fit = twist_against_pose(t, x, y, yaw, v, w)
    assert fit.path == pytest.approx(0.5 * (t[-1] - t[0]), rel=1e-9)  # speed x duration
    assert fit.turn == pytest.approx(0.25 * (t[-1] - t[0]), rel=1e-9)
    assert fit.speed_cosine == pytest.approx(1.0, abs=1e-9)
    assert fit.speed_ratio == pytest.approx(1.0, abs=1e-9)
    assert fit.rate_cosine == pytest.approx(1.0, abs=1e-9)
    assert fit.rate_ratio == pytest.approx(1.0, abs=1e-9)
    assert not (fit.speed_opposite or fit.rate_opposite)
    assert fit.intervals == t.size - 1


def test_a_flipped_sign_in_either_reads_minus_one():
    t, x, y, yaw, v, w = _circle()
    fit = twist_against_pose(t, x, y, yaw, -v, w)
    assert fit.speed_opposite and not fit.rate_opposite
    assert fit.speed_ratio == pytest.approx(-1.0, abs=1e-9)
    fit = twist_against_pose(t, x, y, yaw, v, -w)
    assert fit.rate_opposite and not fit.speed_opposite
    # driving the circle backwards (clockwise, heading -y): the pose's travel is negative,
    # and a twist that says so agrees
    fit = twist_against_pose(t, x[::-1], y[::-1], yaw[::-1], -v, -w)
    assert fit.speed_cosine == pytest.approx(1.0, abs=1e-9)
    assert fit.rate_cosine == pytest.approx(1.0, abs=1e-9)


def test_a_scaled_twist_shows_in_the_ratio_not_the_cosine():
    # a twist 1.5 times the pose (a skid-steer driver's yaw rate from its geometric track,
    # its pose integrated from another) and noisy stamps: still the same direction
    t, x, y, yaw, v, w = _circle()
    rng = np.random.default_rng(0)
    fit = twist_against_pose(t, x, y, yaw, v * (1 + 0.05 * rng.standard_normal(t.size)),
                             1.5 * w)
    assert fit.rate_ratio == pytest.approx(1.5, rel=1e-6)
    assert fit.speed_ratio == pytest.approx(1.0, abs=0.01)
    assert fit.speed_cosine > 0.99 and fit.rate_cosine > 0.99


def test_a_pose_left_at_zero_or_standing_says_nothing():
    t, x, y, yaw, v, w = _circle()
    zero = np.zeros(t.size)
    fit = twist_against_pose(t, zero, zero, zero, v, w)
    assert math.isnan(fit.speed_cosine) and math.isnan(fit.rate_cosine)
    assert not (fit.speed_opposite or fit.rate_opposite)
    # less than MIN_PATH of travel: not compared
    short = t.size // 4
    n = int(MIN_PATH / 0.05) - 2  # 0.05 m per 0.1 s interval
    assert n < short
    fit = twist_against_pose(t[:n], x[:n], y[:n], yaw[:n], -v[:n], w[:n])
    assert math.isnan(fit.speed_cosine) and not fit.speed_opposite


def test_gaps_jumps_and_bad_values_are_left_out():
    t, x, y, yaw, v, w = _circle()
    x, y = x.copy(), y.copy()
    x[100:] += 5.0  # the pose jumps sideways (a correction): that interval is not motion
    t = np.delete(t, range(200, 230))  # a 3 s gap: no rate of any instant
    x, y, yaw, v, w = (np.delete(a, range(200, 230)) for a in (x, y, yaw, v, w))
    v = v.copy()
    v[300] = np.nan
    fit = twist_against_pose(t, x, y, yaw, -v, w)
    assert fit.speed_ratio == pytest.approx(-1.0, abs=1e-9)
    # the jump and the gap left out; the NaN message left out joins its two intervals
    assert fit.intervals == t.size - 1 - 3
    with pytest.raises(ValueError, match="same length"):
        twist_against_pose(t, x, y, yaw, v[:-1], w)
