"""SLAMWARE payloads (seed 002): golden vectors by hand from the packed little-endian structs,
round trips and the reference formulas."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.slamware import (
    DeadreckonIntegrator,
    DeadreckonResponse,
    VelocityRequest,
    deadreckon_from_wheels,
    decode_deadreckon,
    decode_motor_data,
    decode_set_base_motor,
    decode_velocity_request,
    encode_deadreckon,
    encode_motor_data,
    encode_set_base_motor,
    encode_velocity_request,
    from_q16,
    pulses_per_metre,
    to_q16,
    wheel_speeds_from_velocity,
)


def test_velocity_request_golden():
    payload = encode_velocity_request(0.5, -0.25, 1.0)
    assert payload == bytes(
        [
            0x00, 0x80, 0x00, 0x00,  # vx = 0.5 m/s -> 0.5*65536 = 32768 = 0x00008000, LE
            0x00, 0xC0, 0xFF, 0xFF,  # vy = -0.25 -> -16384 = 0xFFFFC000 (two's complement), LE
            0x00, 0x00, 0x01, 0x00,  # w = 1 rad/s -> 65536 = 0x00010000, LE
        ]
    )
    assert decode_velocity_request(payload) == VelocityRequest(0.5, -0.25, 1.0)


def test_deadreckon_straight_golden():
    # dl = dr = 10 mm: dyaw = 0, d = 10 mm -> dx = 10, dy = 0, dtheta = 0
    dx, dy, dth = deadreckon_from_wheels(10.0, 10.0)
    payload = encode_deadreckon(dx, dy, dth, status=0)
    assert payload == bytes(
        [
            0x00, 0x00, 0x0A, 0x00,  # dx = 10 mm -> 655360 = 0x000A0000, LE
            0x00, 0x00, 0x00, 0x00,  # dy = 0
            0x00, 0x00, 0x00, 0x00,  # dtheta = 0
            0x00,  # status bitmap: no fault
        ]
    )


def test_deadreckon_turn_in_place_golden():
    # dl = -59, dr = 59 mm, R = 118 mm: dyaw = 118/(2*118) = 0.5 rad = 28.6478897565 deg;
    # * 65536 = 1877468.103 -> truncated 1877468 = 0x001CA5DC; d = 0 -> dx = dy = 0
    dx, dy, dth = deadreckon_from_wheels(-59.0, 59.0)
    assert (dx, dy) == (0.0, 0.0)
    payload = encode_deadreckon(dx, dy, dth, status=0x01)
    assert payload == bytes([0] * 8 + [0xDC, 0xA5, 0x1C, 0x00] + [0x01])
    r = decode_deadreckon(payload)
    assert r.dtheta_deg == pytest.approx(28.6478897565, abs=1 / 65536)
    assert r.status_bitmap == 1


def test_motor_data_and_set_base_motor_golden():
    payload = encode_motor_data([1000, 2000])
    assert payload == bytes(
        [
            0xE8, 0x03, 0x00, 0x00,  # left cumulative 1000 mm = 0x3E8, LE
            0xD0, 0x07, 0x00, 0x00,  # right 2000 mm = 0x7D0, LE
            *[0] * 8,  # motors 3 and 4 unused
        ]
    )
    assert decode_motor_data(payload) == (1000.0, 2000.0, 0.0, 0.0)
    assert decode_motor_data(payload, q16=True)[0] == pytest.approx(1000 / 65536)
    p = encode_set_base_motor([-100, 250])
    # -100 = 0xFFFFFF9C, 250 = 0xFA
    assert p[:8] == bytes([0x9C, 0xFF, 0xFF, 0xFF, 0xFA, 0x00, 0x00, 0x00])
    assert decode_set_base_motor(p) == (-100, 250, 0, 0)


def test_q16_truncates_like_c_and_checks_range():
    assert to_q16(1.0) == 65536
    assert to_q16(-1e-6) == 0  # -0.0655 truncates toward zero
    assert to_q16(-1.5 / 65536) == -1
    with pytest.raises(ValueError, match="s32"):
        to_q16(40000.0)
    with pytest.raises(ValueError, match="finite"):
        to_q16(math.nan)
    with pytest.raises(ValueError, match="13 bytes"):
        decode_deadreckon(b"\x00" * 12)
    with pytest.raises(ValueError, match="u8"):
        encode_deadreckon(0, 0, 0, status=256)


@given(st.integers(-(1 << 31), (1 << 31) - 1))
def test_q16_round_trip(q):
    assert to_q16(from_q16(q)) == q


def test_formulas():
    # vl = vx - w R, vr = vx + w R in mm/s: 0.2 m/s, 1 rad/s, R = 118 mm -> 82, 318
    assert wheel_speeds_from_velocity(0.2, 1.0) == (pytest.approx(82.0), pytest.approx(318.0))
    # seed 002's example: 6390 pulses per metre, e.g. 1300 ppr on a 64.76 mm wheel
    assert pulses_per_metre(1300, 0.06476) == pytest.approx(6390, rel=1e-3)
    # a quarter circle of radius 1 m in one response: exact arc vs the seed's chord direction
    R = 118.0
    dyaw = math.pi / 2
    rc = 1000.0  # mm
    dl, dr = (rc - R) * dyaw, (rc + R) * dyaw
    dx, dy, dth = deadreckon_from_wheels(dl, dr, R, method="arc")
    assert (dx, dy) == (pytest.approx(rc), pytest.approx(rc))  # lands on the circle
    assert dth == pytest.approx(90.0)
    sx, sy, _ = deadreckon_from_wheels(dl, dr, R, method="seed")
    # the seed puts the whole arc length along the final heading: (0, pi/2 * 1000)
    assert (sx, sy) == (pytest.approx(0.0, abs=1e-9), pytest.approx(rc * dyaw))


def test_integrator_closes_a_square():
    integ = DeadreckonIntegrator()
    for _ in range(4):
        integ.update(DeadreckonResponse(1000.0, 0.0, 0.0))
        integ.update(decode_deadreckon(encode_deadreckon(0.0, 0.0, 90.0)))
    assert integ.x == pytest.approx(0.0, abs=1e-9)
    assert integ.y == pytest.approx(0.0, abs=1e-9)
    assert integ.theta == pytest.approx(2 * math.pi)
