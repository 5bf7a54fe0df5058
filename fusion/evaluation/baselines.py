"""Baselines the fused odometry has to beat.

- :func:`wheel_only`: seed 000's dead reckoning from the ticks alone
  (:class:`fusion.planar.odometry.WheelOdometry`, midpoint rule).
- :func:`gyro_at_stops`: heading from the gyro, its bias re-learnt at every stop, distance from
  the wheels. A stop is a run of wheel frames with zero ticks on BOTH wheels lasting at least
  ``min_duration`` during which the IMU is quiet too (every gyro and accelerometer axis varies
  little and the gyro reads near zero): zero ticks while the IMU shows motion is a dead encoder,
  not a stop. The bias is the mean gyro z over the stop (its edges trimmed); it applies from the
  end of that stop on (0, or ``initial_bias``, before the first stop), and the heading is held
  during a stop. Each wheel frame moves the position by its distance ``(left + right)/2 *
  speed_ratio`` along the heading at the middle of its period.

Frames and units: gyro and accelerometer samples in the base frame (rad/s, m/s^2; rotate a
mounted IMU first), stamps s on one clock, poses ``(x m, y m, yaw rad continuous)`` of
base_footprint in odom at the wheel frames' stamps.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import cumulative_trapezoid

from fusion.geometry.kinematics import DiffDriveParams
from fusion.planar.odometry import WheelOdometry

__all__ = [
    "GyroAtStops",
    "StopDetector",
    "detect_stops",
    "gyro_at_stops",
    "gyro_at_stops_twist",
    "wheel_only",
]


def wheel_only(params: DiffDriveParams, ticks: ArrayLike) -> NDArray[np.float64]:
    """(M, 3) poses after each wheel frame from its ticks alone (seed 000's midpoint rule)."""
    tk = np.asarray(ticks).reshape(-1, 2)
    return WheelOdometry(params).update_batch(tk[:, 0], tk[:, 1])


@dataclass(frozen=True)
class StopDetector:
    """When a robot counts as standing still.

    Attributes:
        min_duration: shortest run of all-zero wheel frames, s (from the start of its first
            period to the end of its last).
        max_gap: longest gap between consecutive zero frames of one run (lost frames), in
            firmware periods.
        edge: trimmed from both ends of the run before the IMU is looked at, s.
        gyro_quiet: largest standard deviation of any gyro axis, rad/s.
        accel_quiet: largest standard deviation of any accelerometer axis, m/s^2.
        gyro_max: largest |mean| of any gyro axis, rad/s (a larger one is a rotation, not a
            bias).
        min_samples: fewest IMU samples in the trimmed window.
    """

    min_duration: float = 1.0
    max_gap: float = 2.5
    edge: float = 0.2
    gyro_quiet: float = 0.01
    accel_quiet: float = 0.15
    gyro_max: float = 0.05
    min_samples: int = 20


@dataclass
class GyroAtStops:
    """Result of :func:`gyro_at_stops`.

    Attributes:
        t: (M,) the wheel frames' stamps, s.
        poses: (M, 3) ``x, y, yaw`` after each frame (m, m, rad continuous).
        stops: ``(start s, end s, bias rad/s)`` of each stop used.
        rejected: ``(start s, end s)`` runs of zero ticks the IMU did not confirm (motion seen).
    """

    t: NDArray[np.float64]
    poses: NDArray[np.float64]
    stops: list[tuple[float, float, float]] = field(default_factory=list)
    rejected: list[tuple[float, float]] = field(default_factory=list)


def _zero_runs(frame_t: NDArray[np.float64], zero: NDArray[np.bool_], period: float,
               max_gap: float) -> list[tuple[float, float]]:
    runs: list[tuple[float, float]] = []
    start = last = None
    for t, z in zip(frame_t.tolist(), zero.tolist()):
        if z and last is not None and t - last <= max_gap * period:
            last = t
            continue
        if start is not None:
            runs.append((start, last))
            start = last = None
        if z:
            start, last = t - period, t
    if start is not None:
        runs.append((start, last))
    return runs


def _imu_arrays(imu_t: ArrayLike, gyro: ArrayLike, accel: ArrayLike):
    imu_t = np.asarray(imu_t, dtype=float)
    gyro = np.asarray(gyro, dtype=float).reshape(-1, 3)
    accel = np.asarray(accel, dtype=float).reshape(-1, 3)
    if not imu_t.size == gyro.shape[0] == accel.shape[0] or imu_t.size < 2:
        raise ValueError(f"need at least 2 IMU samples with one gyro and accelerometer row "
                         f"each, got {imu_t.size}, {gyro.shape}, {accel.shape}")
    return imu_t, gyro, accel


def _confirm(imu_t, gyro, accel, runs, det: StopDetector):
    stops: list[tuple[float, float, float]] = []
    rejected: list[tuple[float, float]] = []
    for start, end in runs:
        if end - start < det.min_duration:
            continue
        i0, i1 = np.searchsorted(imu_t, [start + det.edge, end - det.edge])
        if i1 - i0 < det.min_samples:
            continue
        g, a = gyro[i0:i1], accel[i0:i1]
        quiet = (g.std(axis=0).max() <= det.gyro_quiet and a.std(axis=0).max() <= det.accel_quiet
                 and np.abs(g.mean(axis=0)).max() <= det.gyro_max)
        if quiet:
            stops.append((start, end, float(g[:, 2].mean())))
        else:
            rejected.append((start, end))
    return stops, rejected


def detect_stops(params: DiffDriveParams, imu_t: ArrayLike, gyro: ArrayLike, accel: ArrayLike,
                 wheel_t: ArrayLike, ticks: ArrayLike, detector: StopDetector | None = None
                 ) -> tuple[list[tuple[float, float, float]], list[tuple[float, float]]]:
    """Stops confirmed by wheels AND IMU: ``([(start s, end s, mean gyro z rad/s)], rejected)``
    where ``rejected`` lists the zero-tick runs the IMU contradicted (see the module docstring).
    """
    det = detector or StopDetector()
    imu_t, gyro, accel = _imu_arrays(imu_t, gyro, accel)
    zero = np.all(np.asarray(ticks).reshape(-1, 2) == 0, axis=1)
    runs = _zero_runs(np.asarray(wheel_t, dtype=float), zero, params.encode_sampling_time,
                      det.max_gap)
    return _confirm(imu_t, gyro, accel, runs, det)


def _track(imu_t, gyro_z, stops, rejected, frame_t, frame_dt, distance,
           initial_bias) -> GyroAtStops:
    bias = np.full(imu_t.size, float(initial_bias))
    still = np.zeros(imu_t.size, dtype=bool)
    for start, end, b in stops:
        bias[imu_t >= end] = b
        still[(imu_t >= start) & (imu_t <= end)] = True
    rate = np.where(still, 0.0, gyro_z - bias)
    heading = cumulative_trapezoid(rate, imu_t, initial=0.0)
    mid = np.interp(frame_t - 0.5 * frame_dt, imu_t, heading)
    poses = np.column_stack([np.cumsum(distance * np.cos(mid)),
                             np.cumsum(distance * np.sin(mid)),
                             np.interp(frame_t, imu_t, heading)])
    return GyroAtStops(frame_t, poses, stops, rejected)


def gyro_at_stops(params: DiffDriveParams, imu_t: ArrayLike, gyro: ArrayLike, accel: ArrayLike,
                  wheel_t: ArrayLike, ticks: ArrayLike, detector: StopDetector | None = None,
                  initial_bias: float = 0.0) -> GyroAtStops:
    """Gyro heading with the bias re-learnt at every stop, distance from the wheels (module
    docstring).

    Args:
        params: chassis (``speed_ratio`` m/tick, ``encode_sampling_time`` s).
        imu_t, gyro, accel: IMU stamps (s) and (N, 3) base-frame readings (rad/s, m/s^2).
        wheel_t, ticks: wheel frame stamps (s, end of each period) and (M, 2) ticks.
        detector: stop criteria.
        initial_bias: gyro z bias used before the first stop, rad/s.
    """
    imu_t, gyro, accel = _imu_arrays(imu_t, gyro, accel)
    wheel_t = np.asarray(wheel_t, dtype=float)
    ticks = np.asarray(ticks).reshape(-1, 2)
    stops, rejected = detect_stops(params, imu_t, gyro, accel, wheel_t, ticks, detector)
    T = params.encode_sampling_time
    d = 0.5 * (ticks[:, 0] + ticks[:, 1]) * params.speed_ratio
    return _track(imu_t, gyro[:, 2], stops, rejected, wheel_t, T, d, initial_bias)


def gyro_at_stops_twist(imu_t: ArrayLike, gyro: ArrayLike, accel: ArrayLike,
                        twist_t: ArrayLike, v: ArrayLike, w: ArrayLike,
                        detector: StopDetector | None = None, initial_bias: float = 0.0,
                        still_v: float = 1e-3, still_w: float = 1e-3) -> GyroAtStops:
    """:func:`gyro_at_stops` for odometry twists instead of ticks (e.g. a ROS bag's
    nav_msgs/Odometry): a message with ``|v| < still_v`` (m/s) and ``|w| < still_w`` (rad/s)
    counts as a zero frame, and message k moves ``v_k * (t_k - t_{k-1})`` (m; the first one
    the median interval) along the heading at the middle of that interval.

    Args:
        imu_t, gyro, accel: IMU stamps (s) and (N, 3) base-frame readings (rad/s, m/s^2).
        twist_t, v, w: message stamps (s), forward speed (m/s), yaw rate (rad/s).
    """
    imu_t, gyro, accel = _imu_arrays(imu_t, gyro, accel)
    det = detector or StopDetector()
    twist_t = np.asarray(twist_t, dtype=float)
    v = np.asarray(v, dtype=float)
    w = np.asarray(w, dtype=float)
    if not twist_t.size == v.size == w.size or twist_t.size < 2:
        raise ValueError(f"need at least 2 twists with one v and w each, got {twist_t.size}, "
                         f"{v.size}, {w.size}")
    period = float(np.median(np.diff(twist_t)))
    dt = np.concatenate(([period], np.diff(twist_t)))
    zero = (np.abs(v) < still_v) & (np.abs(w) < still_w)
    stops, rejected = _confirm(imu_t, gyro, accel,
                               _zero_runs(twist_t, zero, period, det.max_gap), det)
    return _track(imu_t, gyro[:, 2], stops, rejected, twist_t, dt, v * dt, initial_bias)
