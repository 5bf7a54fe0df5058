"""Sensor models sampled from the physics trace at their own clocks.

IMU (MPU6050-like): the true angular rate and specific force of the body at the IMU's lever
arm (``BodyParams.imu_position``), plus band-limited vibration scaling with speed, through a
first-order low-pass at the physics rate, into the IMU frame by the TRUE mount, sampled at the
IMU clock (``imu_rate`` Hz, rate off by ``imu_clock_error``), then the gyro errors
``(I + diag(scale) + cross) @ rate + G @ specific_force + bias(temperature) + noise`` and the
accelerometer's ``specific_force + bias + noise``. Stamps: true sample time + latency +
half-normal jitter.

Encoders: the wheel angle (rad, integrated by the physics) read at the end of every firmware
period (firmware clock off by ``firmware_clock_error``), floored to whole counts; a frame
carries the counts of its period. Dead windows zero both wheels; lost frames are dropped;
stamps as for the IMU.

Host stamps are made strictly increasing (a stamp not after its predecessor is moved 1 us
after it), as ``datasets/LOGDIR.md`` requires.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from fusion.evaluation.physics_sim.body import BodyParams
from fusion.evaluation.physics_sim.dynamics import PHYSICS_RATE, BodyTrace
from fusion.evaluation.physics_sim.sensor_model import SensorModel
from fusion.geometry.mount import base_to_imu, mount_matrix

__all__ = ["body_rates_and_forces", "sample_encoders", "sample_imu"]


def body_rates_and_forces(trace: BodyTrace, body: BodyParams
                          ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """True angular rate (rad/s) and specific force (m/s^2) at the IMU position, base frame,
    (N, 3) each at the physics rate (level floor: the specific force reads +g on z)."""
    px, py, _ = body.imu_position
    r, rd = trace.r, trace.r_dot
    ax = trace.ax - rd * py - r * r * px
    ay = trace.ay + rd * px - r * r * py
    f = np.column_stack([ax, ay, np.full_like(ax, body.gravity)])
    w = np.column_stack([np.zeros_like(r), np.zeros_like(r), r])
    return w, f


def _vibration(rng: np.random.Generator, n: int, freq: float) -> NDArray[np.float64]:
    """(n, 3) band-limited noise of unit RMS around ``freq`` Hz at the physics rate."""
    lo, hi = 0.7 * freq, min(1.3 * freq, 0.45 * PHYSICS_RATE)
    sos = signal.butter(2, [lo, hi], btype="bandpass", fs=PHYSICS_RATE, output="sos")
    v = signal.sosfilt(sos, rng.standard_normal((n + 2000, 3)), axis=0)[2000:]
    return v / np.sqrt(np.mean(v * v, axis=0))


def _stamps(rng: np.random.Generator, t: NDArray[np.float64], latency: float,
            jitter: float) -> NDArray[np.float64]:
    s = t + latency + (np.abs(rng.standard_normal(t.size)) * jitter if jitter > 0 else 0.0)
    for i in range(1, s.size):  # strictly increasing (rarely needed)
        if s[i] <= s[i - 1]:
            s[i] = s[i - 1] + 1e-6
    return s


def _interp(t: NDArray[np.float64], tp: NDArray[np.float64], v: NDArray[np.float64]):
    return np.column_stack([np.interp(t, tp, v[:, j]) for j in range(v.shape[1])])


def sample_imu(trace: BodyTrace, body: BodyParams, sensors: SensorModel,
               rng: np.random.Generator) -> dict[str, NDArray[np.float64]]:
    """IMU readings from the trace.

    Returns:
        ``t`` (host stamps, s), ``gyro`` (rad/s) and ``accel`` (m/s^2), (N, 3) in the IMU
        frame, and ``t_true`` (the true sample times, s).
    """
    w, f = body_rates_and_forces(trace, body)
    n = trace.t.size
    speed = np.abs(trace.u)[:, None]
    if sensors.vibration_accel > 0:
        f = f + sensors.vibration_accel * speed * _vibration(rng, n, sensors.vibration_frequency)
    if sensors.vibration_gyro > 0:
        w = w + sensors.vibration_gyro * speed * _vibration(rng, n, sensors.vibration_frequency)
    if sensors.imu_lowpass > 0:
        a = 1.0 - math.exp(-2.0 * math.pi * sensors.imu_lowpass / PHYSICS_RATE)
        zi_w = (1.0 - a) * w[0]
        zi_f = (1.0 - a) * f[0]
        w = signal.lfilter([a], [1.0, a - 1.0], w, axis=0, zi=zi_w[None, :])[0]
        f = signal.lfilter([a], [1.0, a - 1.0], f, axis=0, zi=zi_f[None, :])[0]
    R = mount_matrix(sensors.mount_rpy)
    w = base_to_imu(R, w)
    f = base_to_imu(R, f)
    period = (1.0 + sensors.imu_clock_error) / sensors.imu_rate
    t0 = rng.uniform(0.0, period)
    ts = np.arange(t0, trace.t[-1], period)
    w = _interp(ts, trace.t, w)
    f = _interp(ts, trace.t, f)
    sx, sy, sz = sensors.gyro_scale
    cxy, cxz, cyx, cyz, czx, czy = sensors.gyro_cross_axis
    M = np.array([[1 + sx, cxy, cxz], [cyx, 1 + sy, cyz], [czx, czy, 1 + sz]])
    G = np.asarray(sensors.gyro_g_sensitivity, dtype=float).reshape(3, 3)
    gyro = w @ M.T + f @ G.T + sensors.gyro_bias_at(ts)
    accel = f + np.asarray(sensors.accel_bias)
    if sensors.gyro_noise_std > 0:
        gyro = gyro + sensors.gyro_noise_std * rng.standard_normal(gyro.shape)
    if sensors.accel_noise_std > 0:
        accel = accel + sensors.accel_noise_std * rng.standard_normal(accel.shape)
    keep = rng.random(ts.size) >= sensors.imu_sample_loss
    ts, gyro, accel = ts[keep], gyro[keep], accel[keep]
    return {"t": _stamps(rng, ts, sensors.imu_latency, sensors.imu_jitter), "gyro": gyro,
            "accel": accel, "t_true": ts}


def sample_encoders(trace: BodyTrace, sensors: SensorModel, rng: np.random.Generator
                    ) -> dict[str, NDArray]:
    """Wheel frames from the trace.

    Returns:
        ``t`` (host stamps, s), ``ticks`` ((M, 2) int64, left and right counts of each
        period), ``t_end`` (true end of each period, s) and ``dead`` (bool, the frame fell in a
        dead-encoder window).
    """
    period = sensors.wheel_period * (1.0 + sensors.firmware_clock_error)
    t0 = rng.uniform(0.0, period)
    ends = np.arange(t0, trace.t[-1], period)
    per_rad = sensors.encoder_ticks_per_rev / (2.0 * math.pi)
    counts = np.column_stack([np.floor(np.interp(ends, trace.t, a) * per_rad)
                              for a in (trace.angle_l, trace.angle_r)]).astype(np.int64)
    ticks = np.diff(counts, axis=0)
    ends = ends[1:]
    dead = np.zeros(ends.size, dtype=bool)
    for start, duration in sensors.encoder_dead_windows:
        dead |= (ends >= start) & (ends < start + duration)
    ticks[dead] = 0
    keep = rng.random(ends.size) >= sensors.wheel_frame_loss
    ends, ticks, dead = ends[keep], ticks[keep], dead[keep]
    return {"t": _stamps(rng, ends, sensors.wheel_latency, sensors.wheel_jitter),
            "ticks": ticks, "t_end": ends, "dead": dead}
