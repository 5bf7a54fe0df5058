"""SLAMWARE (Slamtec) base odometry payloads and formulas (seed 002), sans-I/O.

The SLAMWARE Core talks to the base MCU with request/response commands; this module encodes
and decodes the *payloads* of the three odometry commands (the transport framing around them
is Slamtec's and out of scope). Payloads are the packed C structs of the reference firmware on
an ARM Cortex-M, hence little-endian:

- ``SET_V_AND_GET_DEADRECKON`` (0x41) request: ``s32 vx_q16, vy_q16, w_q16``: body velocity
  vx, vy in m/s and yaw rate w in rad/s (CCW), each Q16.16 fixed point (12 bytes).
- 0x41 response: ``s32 dx_mm_q16, dy_mm_q16, dtheta_degree_q16; u8 status_bitmap``: the
  displacement since the previous response, in the robot frame of the previous response, in
  mm, mm and degrees CCW, Q16.16; status bits report faults such as lost traction (13 bytes).
- ``GET_BASE_MOTOR_DATA`` (0x31) response: four ``s32`` cumulative wheel distances in mm
  (16 bytes). The struct field is named ``..._q16`` but the reference code stores whole mm
  (``(_s32)cumulate_walkingmotor_ldist_mm()``); :func:`decode_motor_data` follows the code and
  offers ``q16=True`` for firmware that really sends Q16.16.
- ``SET_BASE_MOTOR`` (0x40) request: wheel speeds in mm/s, four ``s32`` (16 bytes).

Formulas of the reference firmware (R = half the wheel separation, ``robot_radius_mm`` = 118):
``vl = vx - w*R``, ``vr = vx + w*R``; from wheel travel dl, dr (mm):
``dyaw = (dr - dl)/(2R)``, ``d = (dl + dr)/2``, ``dx = d*cos(dyaw)``, ``dy = d*sin(dyaw)``.
Note that the seed points the chord along the *final* heading ``dyaw``; the exact chord of an
arc points along ``dyaw/2`` (``method="arc"``), which matters at low update rates. Conversions
to Q16.16 truncate toward zero like the C casts.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from fusion.geometry.dead_reckoning import step

__all__ = [
    "GET_BASE_MOTOR_DATA",
    "ROBOT_RADIUS_MM",
    "SET_BASE_MOTOR",
    "SET_V_AND_GET_DEADRECKON",
    "DeadreckonIntegrator",
    "DeadreckonResponse",
    "VelocityRequest",
    "deadreckon_from_wheels",
    "decode_deadreckon",
    "decode_motor_data",
    "decode_set_base_motor",
    "decode_velocity_request",
    "encode_deadreckon",
    "encode_motor_data",
    "encode_set_base_motor",
    "encode_velocity_request",
    "from_q16",
    "pulses_per_metre",
    "to_q16",
    "wheel_speeds_from_velocity",
]

SET_BASE_MOTOR = 0x40
GET_BASE_MOTOR_DATA = 0x31
SET_V_AND_GET_DEADRECKON = 0x41
#: half the wheel separation of the reference base, mm
ROBOT_RADIUS_MM = 118.0

_S32_MIN, _S32_MAX = -(1 << 31), (1 << 31) - 1


def to_q16(x: float, name: str = "value") -> int:
    """Real -> Q16.16 ``s32``, truncating toward zero like ``(_s32)(x * (1 << 16))``.

    Raises:
        ValueError: not finite, or outside the s32 range (|x| < 32768).
    """
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {x!r}")
    q = math.trunc(x * 65536.0)
    if not _S32_MIN <= q <= _S32_MAX:
        raise ValueError(f"{name} = {x!r} does not fit Q16.16 in an s32 (|{name}| < 32768)")
    return q


def from_q16(q: int) -> float:
    """Q16.16 ``s32`` -> real."""
    return q / 65536.0


def _s32(v: int, name: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not _S32_MIN <= v <= _S32_MAX:
        raise ValueError(f"{name} must be an s32 integer, got {v!r}")
    return v


def _need(payload: bytes, n: int, what: str) -> None:
    if len(payload) != n:
        raise ValueError(f"{what} payload has {n} bytes, got {len(payload)}")


@dataclass(frozen=True, slots=True)
class VelocityRequest:
    """0x41 request: vx, vy in m/s (body frame), w in rad/s (CCW)."""

    vx: float
    vy: float
    w: float


def encode_velocity_request(vx: float, vy: float, w: float) -> bytes:
    """0x41 request payload: three little-endian s32 Q16.16 (m/s, m/s, rad/s)."""
    return struct.pack("<iii", to_q16(vx, "vx"), to_q16(vy, "vy"), to_q16(w, "w"))


def decode_velocity_request(payload: bytes) -> VelocityRequest:
    _need(payload, 12, "SET_V_AND_GET_DEADRECKON request")
    vx, vy, w = struct.unpack("<iii", payload)
    return VelocityRequest(from_q16(vx), from_q16(vy), from_q16(w))


@dataclass(frozen=True, slots=True)
class DeadreckonResponse:
    """0x41 response: displacement since the previous response, robot frame of that response.

    Attributes:
        dx_mm, dy_mm: mm. dtheta_deg: degrees CCW. status_bitmap: fault bits (0 = none).
    """

    dx_mm: float
    dy_mm: float
    dtheta_deg: float
    status_bitmap: int = 0


def encode_deadreckon(dx_mm: float, dy_mm: float, dtheta_deg: float, status: int = 0) -> bytes:
    """0x41 response payload: three little-endian s32 Q16.16 (mm, mm, deg) and a u8 status."""
    if not 0 <= int(status) <= 0xFF:
        raise ValueError(f"status bitmap must be a u8, got {status!r}")
    return struct.pack(
        "<iiiB", to_q16(dx_mm, "dx_mm"), to_q16(dy_mm, "dy_mm"),
        to_q16(dtheta_deg, "dtheta_deg"), int(status),
    )


def decode_deadreckon(payload: bytes) -> DeadreckonResponse:
    _need(payload, 13, "SET_V_AND_GET_DEADRECKON response")
    dx, dy, dth, status = struct.unpack("<iiiB", payload)
    return DeadreckonResponse(from_q16(dx), from_q16(dy), from_q16(dth), status)


def encode_motor_data(cumulative_mm: tuple[int, ...] | list[int]) -> bytes:
    """0x31 response payload: four little-endian s32 cumulative distances, whole mm (as the
    reference code fills them). Fewer than four values are padded with zeros."""
    vals = list(cumulative_mm)
    if len(vals) > 4:
        raise ValueError(f"at most 4 motors, got {len(vals)}")
    vals += [0] * (4 - len(vals))
    return struct.pack("<4i", *(_s32(v, f"motor {i} distance") for i, v in enumerate(vals)))


def decode_motor_data(payload: bytes, q16: bool = False) -> tuple[float, float, float, float]:
    """0x31 response payload -> four cumulative distances in mm (``q16``: Q16.16 encoded)."""
    _need(payload, 16, "GET_BASE_MOTOR_DATA response")
    vals = struct.unpack("<4i", payload)
    if q16:
        return tuple(from_q16(v) for v in vals)  # type: ignore[return-value]
    return tuple(float(v) for v in vals)  # type: ignore[return-value]


def encode_set_base_motor(speeds_mm_s: tuple[int, ...] | list[int]) -> bytes:
    """0x40 request payload: four little-endian s32 wheel speeds, mm/s (forward positive)."""
    vals = list(speeds_mm_s)
    if len(vals) > 4:
        raise ValueError(f"at most 4 motors, got {len(vals)}")
    vals += [0] * (4 - len(vals))
    return struct.pack("<4i", *(_s32(int(v), f"motor {i} speed") for i, v in enumerate(vals)))


def decode_set_base_motor(payload: bytes) -> tuple[int, int, int, int]:
    _need(payload, 16, "SET_BASE_MOTOR request")
    return struct.unpack("<4i", payload)  # type: ignore[return-value]


def wheel_speeds_from_velocity(
    vx: float, w: float, robot_radius_mm: float = ROBOT_RADIUS_MM
) -> tuple[float, float]:
    """Reference firmware's wheel speeds: ``vl = vx - w*R``, ``vr = vx + w*R``.

    Args:
        vx: forward speed, m/s. w: yaw rate, rad/s (CCW). robot_radius_mm: R, mm.

    Returns:
        ``(vl, vr)`` in mm/s.
    """
    v_mm = vx * 1000.0
    t = w * robot_radius_mm
    return v_mm - t, v_mm + t


def deadreckon_from_wheels(
    dl_mm: float, dr_mm: float, robot_radius_mm: float = ROBOT_RADIUS_MM,
    method: str = "seed",
) -> tuple[float, float, float]:
    """Wheel travel since the last response -> (dx mm, dy mm, dtheta deg), robot frame.

    ``method="seed"``: ``dx = d*cos(dyaw)``, ``dy = d*sin(dyaw)`` as the reference firmware;
    ``method="arc"``: the exact chord, ``d*sinc(dyaw/2)`` along ``dyaw/2``.
    """
    if robot_radius_mm <= 0:
        raise ValueError(f"robot_radius_mm must be > 0, got {robot_radius_mm!r}")
    dyaw = (dr_mm - dl_mm) / 2.0 / robot_radius_mm
    d = 0.5 * (dl_mm + dr_mm)
    if method == "seed":  # the chord of length d along the final heading
        dx, dy = d * math.cos(dyaw), d * math.sin(dyaw)
    elif method == "arc":  # one exact-arc step from the pose (0, 0, 0)
        dx, dy, _ = step(0.0, 0.0, 0.0, d, dyaw, rule="arc")
    else:
        raise ValueError(f"method must be 'seed' or 'arc', got {method!r}")
    return dx, dy, math.degrees(dyaw)


def pulses_per_metre(pulses_per_rev: float, wheel_diameter_m: float) -> float:
    """Encoder pulses per metre of travel = pulses per revolution / (pi * wheel diameter)."""
    if pulses_per_rev <= 0 or wheel_diameter_m <= 0:
        raise ValueError("pulses_per_rev and wheel_diameter_m must be > 0")
    return pulses_per_rev / (math.pi * wheel_diameter_m)


class DeadreckonIntegrator:
    """Host side: accumulate 0x41 responses into a pose in the odom frame.

    Each response is a displacement in the robot frame at the previous response:
    ``x += dx*cos(theta) - dy*sin(theta)``, ``y += dx*sin(theta) + dy*cos(theta)``,
    ``theta += dtheta``. Pose in m, m, rad (theta continuous).
    """

    def __init__(self) -> None:
        self.x = 0.0
        self.y = 0.0
        self.theta = 0.0
        self.faults = 0

    def update(self, resp: DeadreckonResponse) -> tuple[float, float, float]:
        dx = resp.dx_mm / 1000.0
        dy = resp.dy_mm / 1000.0
        c, s = math.cos(self.theta), math.sin(self.theta)
        self.x += dx * c - dy * s
        self.y += dx * s + dy * c
        self.theta += math.radians(resp.dtheta_deg)
        if resp.status_bitmap:
            self.faults += 1
        return self.x, self.y, self.theta
