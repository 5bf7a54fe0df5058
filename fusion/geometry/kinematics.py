"""Differential-drive kinematics: body twist <-> wheel speeds <-> encoder ticks per period.

Conventions: body frame x forward, y left, z up (REP-103); ``v`` is the forward speed in m/s,
``w`` the yaw rate in rad/s, positive counter-clockwise seen from above. Wheel order is left,
right. Wheel speeds are ground speeds of the wheel contact points in m/s. Ticks are encoder
counts per sampling period, as on the miiboo DATA-uart2 wire (seed 000 section 3.2).

The command path follows seed 000's ``base_controller`` exactly:

1. clamp ``v`` to ``+-cmd_vel_linear_max`` and ``w`` to ``+-cmd_vel_angular_max``
   (:func:`clamp_twist`);
2. ``left = (v - 0.5*L*w) * T / speed_ratio``, ``right = (v + 0.5*L*w) * T / speed_ratio``
   (:func:`twist_to_wheel_speeds`, :func:`wheel_speeds_to_ticks`), converted to an integer by
   truncation toward zero as the seed's C ``int`` assignment does (``rounding="nearest"`` is
   offered because truncation biases every command toward zero by up to one tick).

Between steps 1 and 2 an optional per-wheel speed limit (``wheel_speed_max``) scales both
wheels by the same factor when either exceeds it, which keeps the path curvature ``w / v``
(seed 001's ``velocity_to_RPM``). Seed 001 reaches the limit by shrinking in steps of 1/30; the
scaling here is the exact factor ``wheel_speed_max / max(|vl|, |vr|)``, the limit that loop
approaches.

The inverse path (:func:`ticks_to_wheel_speeds`, :func:`wheel_speeds_to_twist`) is what the
odometry uses: ``vl = ticks_l * speed_ratio / T``, ``v = (vl + vr) / 2``, ``w = (vr - vl) / L``.

All functions accept scalars or numpy arrays (broadcasting); scalar inputs give Python floats
or ints.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from fusion.types.constants import TICKS_MAX

__all__ = [
    "TICKS_MAX",
    "DiffDriveParams",
    "clamp_twist",
    "limit_wheel_speeds",
    "ticks_to_twist",
    "ticks_to_wheel_speeds",
    "twist_to_ticks",
    "twist_to_wheel_speeds",
    "wheel_speeds_to_ticks",
    "wheel_speeds_to_twist",
]


@dataclass(frozen=True)
class DiffDriveParams:
    """Geometry and limits of a two-wheel differential-drive chassis (names of seed 000).

    Attributes:
        wheel_distance: distance between the wheel contact points, m (``L``).
        speed_ratio: wheel travel per encoder tick, m/tick.
        encode_sampling_time: firmware sampling period ``T``, s (the miiboo STM32 uses 40 ms).
        cmd_vel_linear_max: clamp on the commanded forward speed, m/s (``inf``: none).
        cmd_vel_angular_max: clamp on the commanded yaw rate, rad/s (``inf``: none).
        wheel_speed_max: largest ground speed of either wheel, m/s; above it both wheels are
            scaled by one factor, keeping the curvature (``inf``: none).

    Raises:
        ValueError: a length, ratio or period that is not finite and positive, or a limit
            that is not positive.
    """

    wheel_distance: float
    speed_ratio: float
    encode_sampling_time: float = 0.04
    cmd_vel_linear_max: float = math.inf
    cmd_vel_angular_max: float = math.inf
    wheel_speed_max: float = math.inf

    def __post_init__(self) -> None:
        for name in ("wheel_distance", "speed_ratio", "encode_sampling_time"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"DiffDriveParams.{name} must be finite and > 0, got {value!r}")
        for name in ("cmd_vel_linear_max", "cmd_vel_angular_max", "wheel_speed_max"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and value > 0):
                raise ValueError(f"DiffDriveParams.{name} must be > 0 (or inf), got {value!r}")

    @property
    def ticks_per_metre(self) -> float:
        """Encoder ticks per metre of wheel travel, 1/m."""
        return 1.0 / self.speed_ratio

    def max_ticks_per_period(self) -> float:
        """Largest plausible |ticks| per period implied by ``wheel_speed_max`` (inf if none)."""
        return self.wheel_speed_max * self.encode_sampling_time / self.speed_ratio


def _out(x: np.ndarray, scalar: bool):
    return float(x) if scalar else x


def _is_scalar(*xs: ArrayLike) -> bool:
    return all(np.ndim(x) == 0 for x in xs)


def clamp_twist(v: ArrayLike, w: ArrayLike, params: DiffDriveParams):
    """Clamp forward speed (m/s) and yaw rate (rad/s) to the ``cmd_vel_*_max`` limits.

    Each component is clamped independently, as seed 000 does (this can change the curvature;
    :func:`limit_wheel_speeds` is the curvature-preserving limit). Returns ``(v, w)``.
    """
    scalar = _is_scalar(v, w)
    vv = np.clip(np.asarray(v, dtype=float), -params.cmd_vel_linear_max, params.cmd_vel_linear_max)
    ww = np.clip(
        np.asarray(w, dtype=float), -params.cmd_vel_angular_max, params.cmd_vel_angular_max
    )
    return _out(vv, scalar), _out(ww, scalar)


def twist_to_wheel_speeds(v: ArrayLike, w: ArrayLike, wheel_distance: float):
    """Body twist -> wheel ground speeds: ``vl = v - w*L/2``, ``vr = v + w*L/2``.

    Args:
        v: forward speed, m/s.
        w: yaw rate, rad/s, CCW positive.
        wheel_distance: ``L``, m.

    Returns:
        ``(vl, vr)`` in m/s.
    """
    scalar = _is_scalar(v, w)
    vv = np.asarray(v, dtype=float)
    ww = np.asarray(w, dtype=float)
    half = 0.5 * wheel_distance * ww
    return _out(vv - half, scalar), _out(vv + half, scalar)


def wheel_speeds_to_twist(vl: ArrayLike, vr: ArrayLike, wheel_distance: float):
    """Wheel ground speeds (m/s) -> body twist ``(v, w)``: ``v = (vl+vr)/2``, ``w = (vr-vl)/L``."""
    scalar = _is_scalar(vl, vr)
    a = np.asarray(vl, dtype=float)
    b = np.asarray(vr, dtype=float)
    return _out(0.5 * (a + b), scalar), _out((b - a) / wheel_distance, scalar)


def limit_wheel_speeds(vl: ArrayLike, vr: ArrayLike, wheel_speed_max: float):
    """Scale both wheel speeds by one factor so that neither exceeds ``wheel_speed_max`` (m/s).

    The ratio ``vl / vr`` and therefore the curvature of the path is unchanged (seed 001).
    Pairs already within the limit are returned unchanged. Returns ``(vl, vr)`` in m/s.
    """
    if not wheel_speed_max > 0:
        raise ValueError(f"wheel_speed_max must be > 0, got {wheel_speed_max!r}")
    scalar = _is_scalar(vl, vr)
    a = np.asarray(vl, dtype=float)
    b = np.asarray(vr, dtype=float)
    peak = np.maximum(np.abs(a), np.abs(b))
    with np.errstate(divide="ignore", invalid="ignore"):
        factor = np.where(peak > wheel_speed_max, wheel_speed_max / peak, 1.0)
    return _out(a * factor, scalar), _out(b * factor, scalar)


def _to_int(x: np.ndarray, rounding: str) -> np.ndarray:
    if rounding == "truncate":
        out = np.trunc(x)
    elif rounding == "nearest":
        out = np.round(x)
    else:
        raise ValueError(f"rounding must be 'truncate' or 'nearest', got {rounding!r}")
    if not np.all(np.isfinite(out)):
        raise ValueError(f"wheel ticks must be finite, got {x!r}")
    if np.any(np.abs(out) > TICKS_MAX):
        raise ValueError(
            f"wheel ticks {x!r} exceed the 24-bit range +-{TICKS_MAX} of a DATA-uart2 frame; "
            "lower the command or set cmd_vel_*_max / wheel_speed_max"
        )
    return out.astype(np.int64)


def wheel_speeds_to_ticks(
    vl: ArrayLike, vr: ArrayLike, params: DiffDriveParams, rounding: str = "truncate"
):
    """Wheel ground speeds (m/s) -> target ticks per sampling period (integers).

    ``ticks = speed * encode_sampling_time / speed_ratio``, truncated toward zero like seed 000
    (``rounding="truncate"``) or rounded half to even (``"nearest"``).

    Raises:
        ValueError: a result outside the 24-bit wire range, a non-finite speed, or an unknown
            rounding mode.
    """
    scalar = _is_scalar(vl, vr)
    k = params.encode_sampling_time / params.speed_ratio
    left = _to_int(np.asarray(vl, dtype=float) * k, rounding)
    right = _to_int(np.asarray(vr, dtype=float) * k, rounding)
    if scalar:
        return int(left), int(right)
    return left, right


def ticks_to_wheel_speeds(left: ArrayLike, right: ArrayLike, params: DiffDriveParams):
    """Ticks per sampling period -> wheel ground speeds ``ticks * speed_ratio / T`` in m/s."""
    scalar = _is_scalar(left, right)
    k = params.speed_ratio / params.encode_sampling_time
    return (
        _out(np.asarray(left, dtype=float) * k, scalar),
        _out(np.asarray(right, dtype=float) * k, scalar),
    )


def twist_to_ticks(
    v: ArrayLike, w: ArrayLike, params: DiffDriveParams, rounding: str = "truncate"
):
    """The full command path of seed 000: clamp, wheel speeds, wheel limit, ticks per period.

    Args:
        v: commanded forward speed, m/s.
        w: commanded yaw rate, rad/s, CCW positive.
        params: chassis geometry and limits.
        rounding: ``"truncate"`` (seed 000) or ``"nearest"``.

    Returns:
        ``(left, right)`` target ticks per ``encode_sampling_time`` (int, or int64 arrays).
    """
    v, w = clamp_twist(v, w, params)
    vl, vr = twist_to_wheel_speeds(v, w, params.wheel_distance)
    if math.isfinite(params.wheel_speed_max):
        vl, vr = limit_wheel_speeds(vl, vr, params.wheel_speed_max)
    return wheel_speeds_to_ticks(vl, vr, params, rounding=rounding)


def ticks_to_twist(left: ArrayLike, right: ArrayLike, params: DiffDriveParams):
    """Ticks per sampling period -> body twist ``(v m/s, w rad/s)`` (seed 000's ``v = d/T``)."""
    vl, vr = ticks_to_wheel_speeds(left, right, params)
    return wheel_speeds_to_twist(vl, vr, params.wheel_distance)
