"""Kinematics against hand-computed values of seed 000's base_controller and seed 001."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from fusion.geometry.kinematics import (
    TICKS_MAX,
    DiffDriveParams,
    clamp_twist,
    limit_wheel_speeds,
    ticks_to_twist,
    ticks_to_wheel_speeds,
    twist_to_ticks,
    twist_to_wheel_speeds,
    wheel_speeds_to_ticks,
    wheel_speeds_to_twist,
)

P = DiffDriveParams(wheel_distance=0.3, speed_ratio=3e-4, encode_sampling_time=0.04)


def test_twist_to_wheel_speeds_by_hand():
    # vl = 0.5 - 0.5*0.3*1.0 = 0.35, vr = 0.5 + 0.15 = 0.65
    vl, vr = twist_to_wheel_speeds(0.5, 1.0, 0.3)
    assert vl == pytest.approx(0.35, abs=1e-15)
    assert vr == pytest.approx(0.65, abs=1e-15)
    assert isinstance(vl, float)


def test_twist_to_ticks_seed_truncation_and_nearest():
    # left = 0.35 * 0.04 / 3e-4 = 46.67 -> int() truncates to 46; right = 86.67 -> 86
    assert twist_to_ticks(0.5, 1.0, P) == (46, 86)
    # nearest rounds to 47, 87
    assert twist_to_ticks(0.5, 1.0, P, rounding="nearest") == (47, 87)
    # reverse: left = -0.65*0.04/3e-4 = -86.67: truncation goes toward zero (-86), nearest -87
    assert twist_to_ticks(-0.5, 1.0, P) == (-86, -46)
    assert twist_to_ticks(-0.5, 1.0, P, rounding="nearest") == (-87, -47)


def test_clamp_is_per_component_as_seed():
    p = DiffDriveParams(0.3, 3e-4, 0.04, cmd_vel_linear_max=0.4, cmd_vel_angular_max=1.5)
    assert clamp_twist(2.0, -9.0, p) == (0.4, -1.5)
    assert clamp_twist(-2.0, 0.3, p) == (-0.4, 0.3)
    # clamped command: v = 0.4, w = 1.5 -> vl = 0.4 - 0.225 = 0.175 -> 0.175*0.04/3e-4 = 23.3
    # -> 23; vr = 0.625 -> 83.3 -> 83
    assert twist_to_ticks(5.0, 5.0, p) == (23, 83)


def test_wheel_limit_keeps_curvature():
    # vl = 0.5, vr = 1.5, limit 1.0 -> factor 2/3 -> (1/3, 1.0)
    vl, vr = limit_wheel_speeds(0.5, 1.5, 1.0)
    assert vl == pytest.approx(1 / 3, rel=1e-15)
    assert vr == pytest.approx(1.0, rel=1e-15)
    v0, w0 = wheel_speeds_to_twist(0.5, 1.5, 0.3)
    v1, w1 = wheel_speeds_to_twist(vl, vr, 0.3)
    assert w1 / v1 == pytest.approx(w0 / v0, rel=1e-14)
    # within the limit nothing changes, arrays broadcast
    a, b = limit_wheel_speeds(np.array([0.2, -3.0]), np.array([0.1, 1.0]), 1.0)
    np.testing.assert_allclose(a, [0.2, -1.0])
    np.testing.assert_allclose(b, [0.1, 1.0 / 3.0])


def test_twist_to_ticks_with_wheel_limit():
    p = DiffDriveParams(0.3, 3e-4, 0.04, wheel_speed_max=0.6)
    # v=0.5, w=1: vr = 0.65 > 0.6 -> factor 0.6/0.65; vl = 0.35*0.6/0.65 = 0.3230769
    # ticks: 0.3230769*0.04/3e-4 = 43.08 -> 43; vr = 0.6 -> 80.0 (exactly 80 up to rounding)
    left, right = twist_to_ticks(0.5, 1.0, p, rounding="nearest")
    assert (left, right) == (43, 80)


def test_inverse_by_hand():
    p = DiffDriveParams(wheel_distance=0.2, speed_ratio=1e-4, encode_sampling_time=0.04)
    # 100 ticks * 1e-4 = 0.01 m in 0.04 s = 0.25 m/s; 300 -> 0.75 m/s
    vl, vr = ticks_to_wheel_speeds(100, 300, p)
    assert (vl, vr) == (pytest.approx(0.25), pytest.approx(0.75))
    v, w = ticks_to_twist(100, 300, p)
    assert v == pytest.approx(0.5)
    assert w == pytest.approx(2.5)  # (0.75 - 0.25) / 0.2


@given(
    st.floats(-3, 3, allow_nan=False),
    st.floats(-10, 10, allow_nan=False),
    st.floats(0.05, 2.0),
)
def test_twist_wheel_round_trip(v, w, L):
    vl, vr = twist_to_wheel_speeds(v, w, L)
    v2, w2 = wheel_speeds_to_twist(vl, vr, L)
    assert v2 == pytest.approx(v, abs=1e-12)
    assert w2 == pytest.approx(w, abs=1e-9)


@given(st.integers(-100000, 100000), st.integers(-100000, 100000))
def test_ticks_round_trip_nearest(left, right):
    vl, vr = ticks_to_wheel_speeds(left, right, P)
    assert wheel_speeds_to_ticks(vl, vr, P, rounding="nearest") == (left, right)


def test_arrays():
    left, right = twist_to_ticks(np.array([0.5, -0.5]), np.array([1.0, 1.0]), P)
    assert left.dtype == np.int64
    np.testing.assert_array_equal(left, [46, -86])
    np.testing.assert_array_equal(right, [86, -46])


def test_errors():
    with pytest.raises(ValueError, match="wheel_distance"):
        DiffDriveParams(wheel_distance=0.0, speed_ratio=1e-4)
    with pytest.raises(ValueError, match="speed_ratio"):
        DiffDriveParams(wheel_distance=0.2, speed_ratio=math.nan)
    with pytest.raises(ValueError, match="cmd_vel_linear_max"):
        DiffDriveParams(0.2, 1e-4, cmd_vel_linear_max=-1.0)
    with pytest.raises(ValueError, match="24-bit"):
        # 1000 m/s * 0.04 s / 1e-6 m = 4e7 ticks > 2^24 - 1
        twist_to_ticks(1000.0, 0.0, DiffDriveParams(0.2, 1e-6))
    with pytest.raises(ValueError, match="rounding"):
        twist_to_ticks(0.1, 0.0, P, rounding="up")
    with pytest.raises(ValueError, match="finite"):
        wheel_speeds_to_ticks(math.inf, 0.0, P)
    assert TICKS_MAX == 0xFFFFFF
