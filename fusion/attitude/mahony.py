"""Mahony complementary attitude filter (6-axis IMU and 9-axis MARG).

A port of the filter in seed 001 (``READ_DMP2``), corrected, and extended with the classic
MahonyAHRS magnetometer (MARG) form. Frames and units:

- inputs in the body (sensor) frame: angular rate rad/s, specific force m/s^2 (+g along up at
  rest), magnetic field in any consistent unit (uT by convention; only its direction is used);
- output quaternion scalar first ``[w, x, y, z]``, body -> world, world ENU (z up; with a
  magnetometer, y points to magnetic north); Euler angles roll, pitch, yaw of the ZYX sequence.

The algorithm, per sample with period ``dt`` (s)::

    v = world up expressed in the body frame (third row of R(q))
    e = a/|a| x v                                  (+ m/|m| x w  with a magnetometer)
    integral += Ki * e * dt                        (rad/s)
    omega = gyro + Kp * e + integral               (rad/s)
    q += 0.5 * q (x) [0, omega] * dt ; q /= |q|    (first-order, RK1)

where ``w`` is the horizontal-north/vertical reference field rotated into the body frame.

Defects of the seed listing, fixed here:

1. The error lines are missing: ``e`` is never computed from the measured and estimated gravity.
   Here ``e`` is their cross product.
2. The integral ``eInt += Ki*e`` appears twice, doubling the integral gain. Here it runs once.
3. The gyro is fed in the MPU6050 scaled unit (deg/s) where the quaternion kinematics need
   rad/s. This filter takes rad/s only (the driver converts at its edge).
4. The seed's ``Ki`` multiplies the error once per sample, so its effect depends on the sample
   rate. Here ``Ki`` is per second. **Gain mapping:** ``seed_Ki = Ki * dt`` and ``seed_Kp = Kp``
   (both on rad/s). The seed's ``q / q30`` output scaling (a DMP Q30 leftover) is dropped.

Beyond the seed (all optional, see :class:`MahonyParams`): rest detection that pulls the
gyro-bias estimate towards the measured rate while the sensor is still (this makes the yaw bias
observable without a magnetometer), acceleration rejection (no correction while ``|a|`` is far
from g), and a start-up gain ramp (large Kp at first so the attitude converges quickly).

Invalid samples are handled by documented skips, counted in :attr:`Mahony.counters`:
a non-finite gyro row, or one faster than ``max_gyro`` (a corrupt value: no gyro reads 1e200
rad/s), is skipped entirely (attitude held); a zero or non-finite accelerometer row, or one
above ``max_accel``, propagates the gyro (with the bias estimate) without correction; a zero or
non-finite magnetometer row falls back to the 6-axis correction. Non-positive or non-finite
``dt`` and wrong shapes raise ``ValueError``.

**Gap policy.** A period longer than ``max_gap`` s (data lost, the host stalled) is not
integrated as one first-order step (a 30 s gap at 0.01 rad/s gave a roll of 1.17 rad where
the truth is 0.30, and rest detection replaced 91 % of the bias with that one sample). Instead
the sample's rate is integrated over the last regular period only, the integral (bias) and
the rest detector's low-pass and timer see that period too (the rest detector restarts), and
the inclination is re-initialised from the accelerometer: from this sample, or from the first
later one that is usable (finite, non-zero, below ``max_accel`` and inside
``accel_rejection`` when that is set). The heading is kept (the gyro cannot tell what happened
in the gap; a 9-axis filter's magnetometer correction then pulls it back at ``kp``). The cost
is that of one sample for any gap; each gap is counted in ``counters.gaps``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion._jit import compiled_entry_point, njit
from fusion.attitude._base import AttitudeFilter, check_axes
from fusion.attitude._inputs import (
    check_dt,
    finite_vec3,
    unit_quaternion,
    vec3,
)
from fusion.attitude._keel_core import qmul, rotate, tilt_quaternion
from fusion.geometry import quaternion as quat
from fusion.types.constants import STANDARD_GRAVITY

__all__ = [
    "DEFAULT_KI",
    "DEFAULT_KP",
    "PRESETS",
    "Mahony",
    "MahonyCounters",
    "MahonyParams",
    "MahonyState",
]


# Defaults of the 6-axis filter, chosen by benchmarks/tune_mahony6.py on the ten bundled BROAD
# trials (mean inclination RMSE 1.53 deg; Ki = 0.0005 costs 0.001 deg against Ki = 0 and keeps
# the bias estimate learning while moving). Rest detection is on: it alone brings the mean from
# 1.81 deg (best plain Kp/Ki) to 1.53 deg. Acceleration rejection (skip) made BROAD worse
# (2.4-2.8 deg), so it stays off by default.
DEFAULT_KP = 0.15
DEFAULT_KI = 0.0005
DEFAULT_REST_DETECTION = True
# Defaults of the 9-axis filter: the BROAD authors' trial-agnostic best for the classic MARG
# Mahony (Kp 0.74, Ki 0.0012), without the extensions, so it is the published algorithm.
PRESETS = {
    6: {"kp": DEFAULT_KP, "ki": DEFAULT_KI, "rest_detection": DEFAULT_REST_DETECTION},
    9: {"kp": 0.74, "ki": 0.0012, "rest_detection": False},
}

# Layout of the packed arrays handed to the compiled core.
# Parameters P:
_P_KP, _P_KI, _P_G, _P_ACC_REJ, _P_REST_ON, _P_REST_GYR, _P_REST_ACC = range(7)
_P_REST_T, _P_REST_TAU, _P_LP_TAU, _P_RAMP_KP, _P_RAMP_T, _P_REST_MAX = range(7, 13)
_P_MAX_GAP, _P_MAX_GYRO, _P_MAX_ACC = range(13, 16)
_P_LEN = 16
# State S: quaternion, integral (= -bias), elapsed time, rest timer, low-passed gyro and accel,
# low-pass initialised flag, last regular period, inclination re-initialisation pending.
_S_Q, _S_I, _S_ELAPSED, _S_REST_TIMER, _S_GLP, _S_ALP, _S_LP_INIT = 0, 4, 7, 8, 9, 12, 15
_S_LAST_DT, _S_REINIT = 16, 17
_S_LEN = 18
# Counters C:
_C_GYRO_SKIP, _C_ACC_SKIP, _C_MAG_SKIP, _C_ACC_REJECT, _C_REST, _C_GAPS = range(6)
_C_LEN = 6


@dataclass(frozen=True)
class MahonyParams:
    """Filter parameters (immutable; derive a variant with :func:`dataclasses.replace`).

    Attributes:
        kp: proportional gain, rad/s per unit error (seed ``Kp``).
        ki: integral gain, rad/s^2 per unit error; ``seed_Ki = ki * dt``. 0 disables the
            integral feedback (the bias estimate then changes only by rest detection).
        sample_period: default ``dt`` in s when an update gives none; None to require one.
        gravity: magnitude of gravity, m/s^2 (acceleration rejection and rest detection).
        accel_rejection: skip the correction while ``| |a| - gravity |`` exceeds this, m/s^2;
            None disables it.
        rest_detection: refine the gyro-bias estimate while the sensor is still.
        rest_gyro_threshold: max deviation of the gyro from its low-pass mean at rest, rad/s.
        rest_max_rate: max magnitude of the low-pass gyro mean at rest, rad/s. A steady
            rotation at constant specific force (a robot spinning in place at a constant rate)
            looks like rest to an IMU alone; this bound keeps such rates (above it) from being
            learnt as bias. Slower steady turns are indistinguishable from bias: feed rest
            information from the wheels (the EKF's zero-velocity update) where it exists.
        rest_accel_threshold: max deviation of the accelerometer from its low-pass mean, m/s^2.
        rest_min_duration: how long the thresholds must hold before the bias is refined, s.
        rest_bias_time_constant: time constant of the bias refinement at rest, s.
        rest_lowpass_time_constant: time constant of the low-pass means used to detect rest, s.
        ramp_kp: initial proportional gain of the start-up ramp, rad/s per unit error.
        ramp_time: duration of the start-up ramp, s (0 disables it). During the ramp Kp falls
            linearly from ``ramp_kp`` to ``kp`` and the integral is frozen.
        max_gap: longest period integrated as one step, s (see the gap policy in the module
            docstring). Hand-set, not tuned: 25 periods at 100 Hz.
        max_gyro: a gyro row faster than this (rad/s) is corrupt and skipped. The default is
            above every MEMS gyro's full scale (+-4000 deg/s = 70 rad/s).
        max_accel: an accelerometer row above this (m/s^2) is corrupt: no correction. The
            default (about 100 g) is above every MEMS accelerometer's full scale.

    Raises:
        ValueError: a gain, threshold, time constant or limit that is not finite or out of
            range, or a ``sample_period`` longer than ``max_gap``; the message names the field
            and the value.
    """

    kp: float = DEFAULT_KP
    ki: float = DEFAULT_KI
    sample_period: float | None = None
    gravity: float = STANDARD_GRAVITY
    accel_rejection: float | None = None
    rest_detection: bool = DEFAULT_REST_DETECTION
    rest_gyro_threshold: float = math.radians(2.0)
    rest_accel_threshold: float = 0.5
    rest_max_rate: float = math.radians(5.0)
    rest_min_duration: float = 1.5
    rest_bias_time_constant: float = 3.0
    rest_lowpass_time_constant: float = 0.5
    ramp_kp: float = 10.0
    ramp_time: float = 0.0
    max_gap: float = 0.25
    max_gyro: float = 100.0
    max_accel: float = 1000.0

    def __post_init__(self) -> None:
        for name in ("kp", "ki", "ramp_kp", "ramp_time"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
        positive = [
            "gravity",
            "rest_gyro_threshold",
            "rest_accel_threshold",
            "rest_max_rate",
            "rest_bias_time_constant",
            "rest_lowpass_time_constant",
            "max_gap",
            "max_gyro",
            "max_accel",
        ]
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0, got {value!r}")
        if not (math.isfinite(self.rest_min_duration) and self.rest_min_duration >= 0):
            raise ValueError(f"rest_min_duration must be >= 0, got {self.rest_min_duration!r}")
        if self.sample_period is not None:
            check_dt(self.sample_period)
            if self.sample_period > self.max_gap:
                raise ValueError(f"sample_period {self.sample_period!r} s is longer than "
                                 f"max_gap {self.max_gap!r} s: every sample would be a gap")
        if self.accel_rejection is not None and not self.accel_rejection > 0:
            raise ValueError(f"accel_rejection must be > 0 or None, got {self.accel_rejection!r}")
        if not isinstance(self.rest_detection, bool):
            raise ValueError(f"rest_detection must be True or False, got "
                             f"{self.rest_detection!r}")

    def packed(self) -> NDArray[np.float64]:
        """The parameters as the flat float64 array the compiled core reads."""
        p = np.zeros(_P_LEN)
        p[_P_KP], p[_P_KI], p[_P_G] = self.kp, self.ki, self.gravity
        p[_P_ACC_REJ] = self.accel_rejection or 0.0
        p[_P_REST_ON] = 1.0 if self.rest_detection else 0.0
        p[_P_REST_GYR], p[_P_REST_ACC] = self.rest_gyro_threshold, self.rest_accel_threshold
        p[_P_REST_T], p[_P_REST_TAU] = self.rest_min_duration, self.rest_bias_time_constant
        p[_P_LP_TAU] = self.rest_lowpass_time_constant
        p[_P_RAMP_KP], p[_P_RAMP_T] = self.ramp_kp, self.ramp_time
        p[_P_REST_MAX] = self.rest_max_rate
        p[_P_MAX_GAP], p[_P_MAX_GYRO], p[_P_MAX_ACC] = self.max_gap, self.max_gyro, self.max_accel
        return p


@dataclass
class MahonyCounters:
    """Samples handled by a documented skip since the last reset."""

    gyro_skipped: int = 0  # non-finite or above max_gyro: sample skipped, attitude held
    accel_skipped: int = 0  # zero/non-finite/above max_accel accelerometer: gyro only
    mag_skipped: int = 0  # zero/non-finite magnetometer in 9-axis mode: 6-axis correction
    accel_rejected: int = 0  # |a| too far from g: correction skipped (accel_rejection)
    rest_samples: int = 0  # samples spent refining the bias at rest
    gaps: int = 0  # periods longer than max_gap (see the gap policy)


@dataclass
class MahonyState:
    """Complete filter state; :meth:`Mahony.set_state` of a saved state resumes exactly.

    Attributes:
        quaternion: attitude ``[w, x, y, z]``, body -> world ENU; None before initialisation.
        integral: integral feedback, rad/s (the gyro-bias estimate is ``-integral``).
        elapsed: time integrated since initialisation, s (drives the start-up ramp).
        rest_timer: how long the sensor has looked still, s.
        gyro_lowpass: low-pass gyro mean, rad/s (rest detection).
        accel_lowpass: low-pass accelerometer mean, m/s^2 (rest detection).
        lowpass_ready: whether the low-pass means hold data.
        last_timestamp: timestamp of the last sample given with timestamps, s, or None.
        counters: see :class:`MahonyCounters`.
        last_period: the last regular (not gap) period, s (0: none yet).
        reinit_pending: a gap happened and the inclination waits for a usable accelerometer.
    """

    quaternion: NDArray[np.float64] | None = None
    integral: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    elapsed: float = 0.0
    rest_timer: float = 0.0
    gyro_lowpass: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    accel_lowpass: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    lowpass_ready: bool = False
    last_timestamp: float | None = None
    counters: MahonyCounters = field(default_factory=MahonyCounters)
    last_period: float = 0.0
    reinit_pending: bool = False


# --------------------------------------------------------------------------------------------
# The core: one sample, shared by the streaming and the batch entry points.
# --------------------------------------------------------------------------------------------


@njit
def _step(S, P, C, gx, gy, gz, ax, ay, az, mx, my, mz, use_mag, dt):
    """Advance the packed state ``S`` by one sample. Returns nothing; mutates S and C."""
    mg = P[_P_MAX_GYRO]  # components first (false for NaN), so 1e200 never overflows
    if not (abs(gx) <= mg and abs(gy) <= mg and abs(gz) <= mg
            and gx * gx + gy * gy + gz * gz <= mg * mg):
        C[_C_GYRO_SKIP] += 1
        return
    q0, q1, q2, q3 = S[0], S[1], S[2], S[3]
    ix, iy, iz = S[4], S[5], S[6]
    elapsed = S[_S_ELAPSED]

    # Gap policy: a period longer than max_gap integrates over the last regular period only
    # and re-initialises the inclination from the accelerometer (module docstring).
    span = dt
    if dt > P[_P_MAX_GAP]:
        C[_C_GAPS] += 1
        dt = S[_S_LAST_DT]
        S[_S_REST_TIMER] = 0.0
        S[_S_LP_INIT] = 0.0
        S[_S_REINIT] = 1.0
    else:
        S[_S_LAST_DT] = dt

    ma = P[_P_MAX_ACC]
    anorm = 0.0
    if abs(ax) <= ma and abs(ay) <= ma and abs(az) <= ma:  # false for NaN and inf
        anorm = math.sqrt(ax * ax + ay * ay + az * az)
    acc_ok = 0.0 < anorm <= ma
    if not acc_ok:
        C[_C_ACC_SKIP] += 1

    # Rest detection: deviation of the current sample from low-pass means.
    if P[_P_REST_ON] != 0.0 and acc_ok:
        if S[_S_LP_INIT] == 0.0:
            S[9], S[10], S[11], S[12], S[13], S[14] = gx, gy, gz, ax, ay, az
            S[_S_LP_INIT] = 1.0
        alpha = dt / (P[_P_LP_TAU] + dt)
        S[9] += alpha * (gx - S[9])
        S[10] += alpha * (gy - S[10])
        S[11] += alpha * (gz - S[11])
        S[12] += alpha * (ax - S[12])
        S[13] += alpha * (ay - S[13])
        S[14] += alpha * (az - S[14])
        dg = math.sqrt((gx - S[9]) ** 2 + (gy - S[10]) ** 2 + (gz - S[11]) ** 2)
        da = math.sqrt((ax - S[12]) ** 2 + (ay - S[13]) ** 2 + (az - S[14]) ** 2)
        glp = math.sqrt(S[9] * S[9] + S[10] * S[10] + S[11] * S[11])
        still = dg < P[_P_REST_GYR] and da < P[_P_REST_ACC] and glp < P[_P_REST_MAX]
        if still and abs(anorm - P[_P_G]) < P[_P_REST_ACC]:
            S[_S_REST_TIMER] += dt
        else:
            S[_S_REST_TIMER] = 0.0
        if S[_S_REST_TIMER] >= P[_P_REST_T]:
            # At rest the true rate is zero: the gyro reads its bias, integral -> -gyro mean.
            beta = dt / (P[_P_REST_TAU] + dt)
            ix += beta * (-S[9] - ix)
            iy += beta * (-S[10] - iy)
            iz += beta * (-S[11] - iz)
            C[_C_REST] += 1

    correct = acc_ok
    if correct and P[_P_ACC_REJ] > 0.0 and abs(anorm - P[_P_G]) > P[_P_ACC_REJ]:
        correct = False
        C[_C_ACC_REJECT] += 1
    reinit = correct and S[_S_REINIT] != 0.0
    if reinit:
        correct = False  # the error of an attitude from before the gap: no feedback from it

    kp = P[_P_KP]
    ramping = P[_P_RAMP_T] > 0.0 and elapsed < P[_P_RAMP_T]
    if ramping:
        kp = P[_P_RAMP_KP] + (P[_P_KP] - P[_P_RAMP_KP]) * (elapsed / P[_P_RAMP_T])

    if correct:
        ax /= anorm
        ay /= anorm
        az /= anorm
        # World up in the body frame (third row of R(q)).
        vx = 2.0 * (q1 * q3 - q0 * q2)
        vy = 2.0 * (q0 * q1 + q2 * q3)
        vz = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
        ex = ay * vz - az * vy
        ey = az * vx - ax * vz
        ez = ax * vy - ay * vx
        if use_mag:
            mnorm = math.sqrt(mx * mx + my * my + mz * mz)
            if math.isfinite(mnorm) and mnorm > 0.0:
                mx /= mnorm
                my /= mnorm
                mz /= mnorm
                q0q1, q0q2, q0q3 = q0 * q1, q0 * q2, q0 * q3
                q1q1, q1q2, q1q3 = q1 * q1, q1 * q2, q1 * q3
                q2q2, q2q3, q3q3 = q2 * q2, q2 * q3, q3 * q3
                # Field in the world frame, h = R m.
                hx = 2.0 * (mx * (0.5 - q2q2 - q3q3) + my * (q1q2 - q0q3) + mz * (q1q3 + q0q2))
                hy = 2.0 * (mx * (q1q2 + q0q3) + my * (0.5 - q1q1 - q3q3) + mz * (q2q3 - q0q1))
                hz = 2.0 * (mx * (q1q3 - q0q2) + my * (q2q3 + q0q1) + mz * (0.5 - q1q1 - q2q2))
                # Reference: horizontal part along north (+y in ENU), vertical part kept.
                bn = math.sqrt(hx * hx + hy * hy)
                # w = R^T [0, bn, hz]: the reference seen from the body.
                wx = 2.0 * (bn * (q1q2 + q0q3) + hz * (q1q3 - q0q2))
                wy = 2.0 * (bn * (0.5 - q1q1 - q3q3) + hz * (q0q1 + q2q3))
                wz = 2.0 * (bn * (q2q3 - q0q1) + hz * (0.5 - q1q1 - q2q2))
                ex += my * wz - mz * wy
                ey += mz * wx - mx * wz
                ez += mx * wy - my * wx
            else:
                C[_C_MAG_SKIP] += 1
        if P[_P_KI] > 0.0 and not ramping:
            ix += P[_P_KI] * ex * dt
            iy += P[_P_KI] * ey * dt
            iz += P[_P_KI] * ez * dt
        gx += ix + kp * ex
        gy += iy + kp * ey
        gz += iz + kp * ez
    else:
        gx += ix
        gy += iy
        gz += iz

    # First-order integration of qdot = 0.5 * q (x) [0, omega].
    hdt = 0.5 * dt
    gx *= hdt
    gy *= hdt
    gz *= hdt
    n0 = q0 + (-q1 * gx - q2 * gy - q3 * gz)
    n1 = q1 + (q0 * gx + q2 * gz - q3 * gy)
    n2 = q2 + (q0 * gy - q1 * gz + q3 * gx)
    n3 = q3 + (q0 * gz + q1 * gy - q2 * gx)
    inv = 1.0 / math.sqrt(n0 * n0 + n1 * n1 + n2 * n2 + n3 * n3)
    n0, n1, n2, n3 = n0 * inv, n1 * inv, n2 * inv, n3 * inv
    if reinit:
        # After a gap: the inclination from this accelerometer sample, the heading kept (the
        # shortest world-frame rotation taking the measured up onto +z, applied on the left).
        ux, uy, uz = rotate(n0, n1, n2, n3, ax, ay, az)
        c0, c1, c2 = tilt_quaternion(ux, uy, uz)
        n0, n1, n2, n3 = qmul(c0, c1, c2, 0.0, n0, n1, n2, n3)
        inv = 1.0 / math.sqrt(n0 * n0 + n1 * n1 + n2 * n2 + n3 * n3)
        n0, n1, n2, n3 = n0 * inv, n1 * inv, n2 * inv, n3 * inv
        S[_S_REINIT] = 0.0
    S[0], S[1], S[2], S[3] = n0, n1, n2, n3
    S[4], S[5], S[6] = ix, iy, iz
    S[_S_ELAPSED] = elapsed + span


# One float64 buffer holds state, parameters and counters, so the compiled entry points take a
# single array (each argument costs time in a streaming call).
_B_S, _B_P, _B_C = 0, _S_LEN, _S_LEN + _P_LEN
_B_LEN = _S_LEN + _P_LEN + _C_LEN


@njit
def _run_batch(B, gyro, acc, mag, use_mag, dt, out):
    """Run ``_step`` over N rows; ``dt`` has N entries or 1 (constant); writes (N, 4) ``out``."""
    S, P, C = B[_B_S:_B_P], B[_B_P:_B_C], B[_B_C:]
    n = gyro.shape[0]
    const_dt = dt.shape[0] == 1
    for i in range(n):
        d = dt[0] if const_dt else dt[i]
        if use_mag:
            mx, my, mz = mag[i, 0], mag[i, 1], mag[i, 2]
        else:
            mx, my, mz = 0.0, 0.0, 0.0
        _step(
            S, P, C, gyro[i, 0], gyro[i, 1], gyro[i, 2], acc[i, 0], acc[i, 1], acc[i, 2],
            mx, my, mz, use_mag, d,
        )
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = S[0], S[1], S[2], S[3]


@njit
def _run_one6(B, g, a, dt):
    """Streaming entry without magnetometer: one sample through the same ``_step``."""
    _step(B[_B_S:_B_P], B[_B_P:_B_C], B[_B_C:], g[0], g[1], g[2], a[0], a[1], a[2],
          0.0, 0.0, 0.0, False, dt)


@njit
def _run_one9(B, g, a, m, dt):
    """Streaming entry with magnetometer."""
    _step(B[_B_S:_B_P], B[_B_P:_B_C], B[_B_C:], g[0], g[1], g[2], a[0], a[1], a[2],
          m[0], m[1], m[2], True, dt)


_run_one6_fast = None
_run_one9_fast = None
_F64 = np.dtype(np.float64)
_NDARRAY = np.ndarray
_SHAPE3 = (3,)


class Mahony(AttitudeFilter):
    """Mahony attitude filter: 6-axis (gyro + accelerometer) or 9-axis (+ magnetometer).

    Args:
        kp, ki: gains (see :class:`MahonyParams`).
        axes: 6 or 9. Settings not given come from the preset of that filter (``PRESETS``):
            6-axis Kp 0.15, Ki 0.0005, rest detection on (tuned on BROAD); 9-axis Kp 0.74,
            Ki 0.0012, no extensions (the classic MARG filter as published for BROAD).
            With 9 a magnetometer is expected (rows without one use the 6-axis correction,
            counted in :attr:`counters`).
        sample_period: default ``dt`` in s for updates that give none.
        initial_quaternion: known initial attitude ``[w, x, y, z]`` body -> world ENU. Without
            it the first valid sample initialises roll and pitch from the accelerometer (and
            yaw from the magnetometer with ``axes=9``; yaw 0 otherwise), and is then filtered.
        params: a full :class:`MahonyParams` (overrides kp, ki, sample_period and ``options``).
        **options: any other :class:`MahonyParams` field (rest_detection=True, ...).

    Example::

        f = Mahony(sample_period=0.01)
        for gyro, accel in samples:        # rad/s, m/s^2, body frame
            q = f.update(gyro, accel)      # [w, x, y, z], body -> ENU
        roll, pitch, yaw = f.euler
    """

    def __init__(
        self,
        kp: float | None = None,
        ki: float | None = None,
        *,
        axes: int = 6,
        sample_period: float | None = None,
        initial_quaternion: ArrayLike | None = None,
        params: MahonyParams | None = None,
        **options,
    ) -> None:
        check_axes(axes)
        if params is None:
            given = {"kp": kp, "ki": ki, "sample_period": sample_period}
            settings = {**PRESETS[axes], **{k: v for k, v in given.items() if v is not None}}
            params = MahonyParams(**{**settings, **options})
        elif kp is not None or ki is not None or sample_period is not None or options:
            raise ValueError("give either params or individual settings, not both")
        self._setup(axes, initial_quaternion, params)

    # -- parameters and state (params, with_params, euler: AttitudeFilter) --------------------

    _params_class = MahonyParams
    _layout = (_B_P, _B_C, _B_LEN)

    def _params_changed(self) -> None:
        self._fast6 = None  # re-armed by the next general update

    def _new_buffer(self) -> None:
        self._fast6 = None  # re-armed by the next general update
        super()._new_buffer()

    def reset(self) -> None:
        """Forget everything: back to the state before the first sample."""
        self._new_buffer()
        self._initialised = False
        self._last_t: float | None = None
        if self._initial is not None:
            self._S[:4] = self._initial
            self._initialised = True

    def get_state(self) -> MahonyState:
        """A copy of the complete state."""
        S, C = self._S, self._C
        return MahonyState(
            quaternion=S[:4].copy() if self._initialised else None,
            integral=S[4:7].copy(),
            elapsed=float(S[_S_ELAPSED]),
            rest_timer=float(S[_S_REST_TIMER]),
            gyro_lowpass=S[9:12].copy(),
            accel_lowpass=S[12:15].copy(),
            lowpass_ready=bool(S[_S_LP_INIT]),
            last_timestamp=self._last_t,
            counters=MahonyCounters(*(int(c) for c in C)),
            last_period=float(S[_S_LAST_DT]),
            reinit_pending=bool(S[_S_REINIT]),
        )

    def set_state(self, state: MahonyState) -> None:
        """Restore a state from :meth:`get_state` (or a hand-made one).

        Raises:
            ValueError: a field of the wrong shape, not finite, or out of range (a zero
                quaternion, a negative time, a bias above ``max_gyro``); the filter is
                left unchanged.
        """
        q = None
        if state.quaternion is not None:
            q = np.asarray(state.quaternion, dtype=float).reshape(4)
            unit_quaternion("state.quaternion", q)  # finite and non-zero, else ValueError
            # Re-normalising a unit quaternion could change its last bit: only fix real drift.
            q = q if abs(np.dot(q, q) - 1.0) < 1e-12 else quat.normalize(q)
        integral = self._check_rate("state.integral", state.integral)
        gyro_lp = self._check_rate("state.gyro_lowpass", state.gyro_lowpass)
        accel_lp = finite_vec3("state.accel_lowpass", state.accel_lowpass)
        times = {"state.elapsed": state.elapsed, "state.rest_timer": state.rest_timer,
                 "state.last_period": state.last_period}
        for name, value in times.items():
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0 s, got {value!r}")
        if state.last_timestamp is not None and not math.isfinite(state.last_timestamp):
            raise ValueError(f"state.last_timestamp must be finite or None, got "
                             f"{state.last_timestamp!r}")
        self._new_buffer()
        S = self._S
        if q is not None:
            S[:4] = q
        S[4:7] = integral
        S[_S_ELAPSED], S[_S_REST_TIMER] = state.elapsed, state.rest_timer
        S[9:12] = gyro_lp
        S[12:15] = accel_lp
        S[_S_LP_INIT] = 1.0 if state.lowpass_ready else 0.0
        S[_S_LAST_DT] = state.last_period
        S[_S_REINIT] = 1.0 if state.reinit_pending else 0.0
        c = state.counters
        self._C[:] = [c.gyro_skipped, c.accel_skipped, c.mag_skipped, c.accel_rejected,
                      c.rest_samples, c.gaps]
        self._initialised = q is not None
        self._last_t = state.last_timestamp

    def _check_rate(self, name: str, value: ArrayLike) -> NDArray[np.float64]:
        """A finite (3,) rate, rad/s, no faster than ``max_gyro``; ``ValueError`` else."""
        v = finite_vec3(name, value)
        with np.errstate(over="ignore"):  # 1e200: inf, refused below
            rate = float(np.linalg.norm(v))
        if rate > self._params.max_gyro:
            raise ValueError(f"{name} = {v.tolist()} rad/s is faster than max_gyro "
                             f"({self._params.max_gyro!r} rad/s)")
        return v

    @property
    def quaternion(self) -> NDArray[np.float64]:
        """Current attitude ``[w, x, y, z]``, body -> world ENU (identity before any sample)."""
        return self._S[:4].copy() if self._initialised else quat.IDENTITY.copy()

    @property
    def gyro_bias(self) -> NDArray[np.float64]:
        """Gyro-bias estimate, rad/s, body frame (``-integral``): subtract it from the gyro."""
        return -self._S[4:7].copy()

    @gyro_bias.setter
    def gyro_bias(self, bias: ArrayLike) -> None:
        """Set the bias estimate, rad/s (3,): finite and no faster than ``max_gyro``, else
        ``ValueError`` (a NaN bias would silently turn the attitude into NaN)."""
        self._S[4:7] = -self._check_rate("gyro_bias", bias)

    @property
    def counters(self) -> MahonyCounters:
        """Documented skips since the last reset (see :class:`MahonyCounters`)."""
        return MahonyCounters(*(int(c) for c in self._C))

    # -- initialisation ---------------------------------------------------------------------

    def _initialise(self, accel: NDArray, mag: NDArray | None) -> bool:
        """Initial attitude from one sample; False if the sample cannot initialise."""
        if not np.all(np.isfinite(accel)) or not np.any(accel != 0):
            return False
        if self.axes == 9 and mag is not None and np.all(np.isfinite(mag)):
            try:
                q = quat.from_accel_mag(accel, mag)
            except ValueError:
                q = quat.from_accel(accel)
        else:
            q = quat.from_accel(accel)
        self._S[:4] = q
        self._initialised = True
        return True

    # -- streaming -------------------------------------------------------------------------

    def update(
        self,
        gyro: ArrayLike,
        accel: ArrayLike,
        mag: ArrayLike | None = None,
        dt: float | None = None,
        *,
        timestamp: float | None = None,
    ) -> NDArray[np.float64]:
        """Filter one sample and return the attitude ``[w, x, y, z]`` (body -> world ENU).

        Args:
            gyro: angular rate (3,), rad/s, body frame.
            accel: specific force (3,), m/s^2, body frame.
            mag: magnetic field (3,), uT, body frame (9-axis filter only).
            dt: time since the previous sample, s. Defaults to the difference of ``timestamp``
                and the previous timestamp, else ``params.sample_period``.
            timestamp: sample time, s (optional; see ``dt``).
        """
        # Hot path of live use (float64 (3,) arrays, no magnetometer, the default period):
        # the fewest Python operations around one compiled call.
        fast = self._fast6
        if (fast is not None and mag is None and dt is None and timestamp is None
                and type(gyro) is _NDARRAY and type(accel) is _NDARRAY
                and gyro.dtype is _F64 and accel.dtype is _F64
                and gyro.shape == _SHAPE3 and accel.shape == _SHAPE3):
            fast(self._B, gyro, accel, self._default_dt)
            return self._q.copy()
        return self._update_general(gyro, accel, mag, dt, timestamp)

    def _update_general(self, gyro, accel, mag, dt, timestamp) -> NDArray[np.float64]:
        g = vec3("gyro", gyro)
        a = vec3("accel", accel)
        if dt is None and timestamp is None and self._default_dt is not None:
            dt = self._default_dt  # already validated
        else:
            dt = self._resolve_dt(dt, timestamp)
        global _run_one6_fast, _run_one9_fast
        if mag is None or self.axes == 6:
            if not self._initialised and not self._initialise(a, None):
                self._C[_C_ACC_SKIP] += 1
                return quat.IDENTITY.copy()
            if _run_one6_fast is None:
                _run_one6_fast = compiled_entry_point(_run_one6, 2)
            _run_one6_fast(self._B, g, a, dt)
            self._arm_fast_path()
        else:
            m = vec3("mag", mag)
            if not self._initialised and not self._initialise(a, m):
                self._C[_C_ACC_SKIP] += 1
                return quat.IDENTITY.copy()
            if _run_one9_fast is None:
                _run_one9_fast = compiled_entry_point(_run_one9, 3)
            _run_one9_fast(self._B, g, a, m, dt)
        return self._q.copy()

    def _arm_fast_path(self) -> None:
        """Enable the hot path once it is valid: initialised, with a default period."""
        if self._initialised and self._default_dt is not None:
            self._fast6 = _run_one6_fast

    def _resolve_dt(self, dt: float | None, timestamp: float | None) -> float:
        if timestamp is not None:
            timestamp = float(timestamp)
            if not math.isfinite(timestamp):
                raise ValueError(f"timestamp must be finite, got {timestamp!r}")
            if dt is None and self._last_t is not None:
                dt = timestamp - self._last_t
                if not dt > 0:
                    raise ValueError(
                        f"timestamp {timestamp!r} s is not after the previous one "
                        f"({self._last_t!r} s)"
                    )
            self._last_t = timestamp
        if dt is None:
            dt = self._params.sample_period
            if dt is None:
                raise ValueError("no dt: pass dt=, timestamps, or set sample_period")
        return check_dt(dt)

    # -- batch --------------------------------------------------------------------------------

    def update_batch(
        self,
        gyro: ArrayLike,
        accel: ArrayLike,
        mag: ArrayLike | None = None,
        dt: float | ArrayLike | None = None,
        *,
        timestamps: ArrayLike | None = None,
    ) -> NDArray[np.float64]:
        """Filter N samples; returns the attitude after each one, shape (N, 4).

        Exactly equivalent to N calls of :meth:`update` (same compiled step).

        Args:
            gyro: (N, 3) rad/s; accel: (N, 3) m/s^2; mag: (N, 3) uT or None.
            dt: a constant sample period (s) or N per-sample periods (the period before each
                sample). Defaults to differences of ``timestamps``, else ``sample_period``.
            timestamps: (N,) sample times, s, strictly increasing. The first sample's period is
                measured from the previous call's last timestamp when there was one, else it is
                ``sample_period`` if set, else the first difference.
        """
        g, a, m, use_mag = self._batch_rows(gyro, accel, mag)
        n = g.shape[0]
        dts = self._batch_periods(n, dt, timestamps)
        out = np.empty((n, 4))
        if n == 0:
            return out
        start = 0
        if not self._initialised:
            # Rows that cannot initialise (no valid accelerometer) are counted and held at
            # identity, as in streaming use.
            while start < n and not self._initialise(a[start], m[start] if use_mag else None):
                self._C[_C_ACC_SKIP] += 1
                out[start] = quat.IDENTITY
                start += 1
            if start == n:
                return out
        d = dts if dts.shape[0] == 1 else dts[start:]
        _run_batch(
            self._B, g[start:], a[start:], m[start:] if use_mag else m, use_mag, d, out[start:]
        )
        return out

    def _first_period(self, t: NDArray[np.float64]) -> float:
        """The first period of a batch with no earlier timestamp: ``sample_period``, else
        the first stamp difference."""
        if self._params.sample_period is not None:
            return self._params.sample_period
        if t.size > 1:
            return float(t[1] - t[0])
        raise ValueError("one timestamp alone gives no dt: pass dt= or sample_period")
