"""Wheel odometry, measured on the surface the robot drives on, turned into what the planar EKF
integrates: speed over the horizontal plane and the heading's rate.

On a slope the wheels count the distance along the surface and turn with the body about the
surface normal (the base frame's z axis). The EKF's pose is planar: its position moves at the
HORIZONTAL speed, and its yaw (the heading, the ZYX yaw) changes at the rate the pipeline
feeds it, which on hills is not the rate about the body z axis
(:meth:`fusion.pipeline.core.FusionPipeline._roll_term` says why). Fed as measured, the wheels
made every distance on a slope long by ``1/cos(pitch)`` (0.3-0.5 % over 10-15 deg hills,
benchmarks/terrain) and disagreed with the gyro on ramps and bumps, where the two rates part:
150-600 rows per 300 s run were flagged as slips though nothing slipped.

So each wheel frame (or twist) is converted with the IMU samples of its own period: its speed
``v`` times the mean ``cos(pitch)`` of the attitude, its yaw rate ``w`` plus the mean
difference ``d`` between the rate fed to the EKF and the gyro's base-frame z rate. The wheels
then say what the gyro says where both are right; a disagreement left over is the wheels' own
(slip, wrong geometry). On a level floor ``cos(pitch)`` is 1 and ``d`` is 0 up to the tilt
estimate's noise: nothing changes. An IMU mounted with a pitch that robot.toml does not state
looks like a slope: its distances come out short by ``1 - cos(pitch)`` (0.06 % at 2 deg,
0.4 % at 5 deg).

Frames and twists that say "standing still" (both wheels' ticks zero, or a twist below the
EKF's zero thresholds) are left exactly as they are: stillness, stops and encoder faults are
decided on them.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = ["HeadingFrame"]

#: s: the longest period a twist's conversion averages over (the time since the previous
#: twist; an odometry topic at 10 Hz gives 0.1 s)
MAX_TWIST_SPAN = 0.5


class HeadingFrame:
    """The IMU's recent ``cos(pitch)`` and rate difference, and the conversion of wheel frames
    and twists that arrive after them (see the module docstring).

    Args:
        period: s, the wheel frames' period (robot.toml's ``encode_sampling_time``): a frame
            stamped ``t`` is converted with the IMU samples stamped in ``(t - period, t]``.
        metres_per_tick: m of wheel travel per encoder tick (``speed_ratio``).
        wheel_distance: m, robot.toml's ``wheel_distance``.
    """

    def __init__(self, period: float, metres_per_tick: float, wheel_distance: float) -> None:
        self.period = float(period)
        self._ticks_per_speed = self.period / float(metres_per_tick)  # ticks per (m/s)
        self.wheel_distance = float(wheel_distance)
        # long enough for a wheel period and a twist's span, short enough to stay small
        self._keep = max(1.0, 2.0 * self.period, 2.0 * MAX_TWIST_SPAN)
        self._t = np.zeros(0)
        self._cos_pitch = np.zeros(0)
        self._rate_diff = np.zeros(0)
        self._last_twist_t = math.nan

    def add_imu(self, t: NDArray[np.float64], q: NDArray[np.float64],
                rate_diff: NDArray[np.float64]) -> None:
        """IMU samples at stamps ``t`` (s, increasing, after every sample added so far):
        attitudes ``q`` (N, 4) ``w, x, y, z``, base frame to world, and ``rate_diff`` (N,)
        rad/s, the rate fed to the EKF minus the gyro's base-frame z rate."""
        qw, qx, qy, qz = np.asarray(q, dtype=np.float64).T
        sin_pitch = -2.0 * (qx * qz - qw * qy) / (qw * qw + qx * qx + qy * qy + qz * qz)
        cos_pitch = np.sqrt(np.maximum(1.0 - sin_pitch * sin_pitch, 0.0))
        ok = np.isfinite(cos_pitch) & np.isfinite(rate_diff)  # no attitude yet: no sample
        self._t = np.concatenate([self._t, t[ok]])
        self._cos_pitch = np.concatenate([self._cos_pitch, cos_pitch[ok]])
        self._rate_diff = np.concatenate([self._rate_diff, rate_diff[ok]])

    def forget_old(self) -> None:
        """Drop the samples no later frame can need (after a call's frames are converted)."""
        if self._t.size:
            keep = self._t > self._t[-1] - self._keep
            if not keep.all():
                self._t = self._t[keep]
                self._cos_pitch = self._cos_pitch[keep]
                self._rate_diff = self._rate_diff[keep]

    def _means(self, t: float, span: float) -> tuple[float, float] | None:
        """Mean ``cos(pitch)`` and rate difference over the samples in ``(t - span, t]``, or
        None without one. A slice's own mean: the same bits however the samples were
        pushed."""
        i1 = int(np.searchsorted(self._t, t, side="right"))
        i0 = int(np.searchsorted(self._t, t - span, side="right"))
        if i1 <= i0:
            return None
        return float(self._cos_pitch[i0:i1].mean()), float(self._rate_diff[i0:i1].mean())

    def ticks(self, wheel_t: NDArray[np.float64], ticks: NDArray[np.int64]
              ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Left and right ticks (float, as the EKF reads them) of frames stamped ``wheel_t``
        (s, end of period) with measured ``ticks`` (M, 2), converted: the speed they give is
        the horizontal one, their yaw rate the heading's."""
        left = ticks[:, 0].astype(np.float64)
        right = ticks[:, 1].astype(np.float64)
        k = self._ticks_per_speed
        for i, t in enumerate(wheel_t.tolist()):
            if left[i] == 0.0 and right[i] == 0.0:
                continue
            means = self._means(t, self.period)
            if means is None:
                continue
            cos_pitch, rate_diff = means
            v = 0.5 * (left[i] + right[i]) / k * cos_pitch
            w = (right[i] - left[i]) / (k * self.wheel_distance) + rate_diff
            half = 0.5 * w * self.wheel_distance
            left[i], right[i] = (v - half) * k, (v + half) * k
        return left, right

    def twists(self, twist_t: NDArray[np.float64], v: NDArray[np.float64],
               w: NDArray[np.float64], zero_v: float, zero_w: float
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Speeds (m/s) and yaw rates (rad/s) of twists stamped ``twist_t`` (s), converted
        over the time since the previous twist (at most :data:`MAX_TWIST_SPAN`); a twist
        below ``zero_v`` and ``zero_w`` (the EKF's stillness thresholds) is left as it is."""
        v = np.array(v, dtype=np.float64)
        w = np.array(w, dtype=np.float64)
        last = self._last_twist_t
        for i, t in enumerate(twist_t.tolist()):
            span = MAX_TWIST_SPAN if math.isnan(last) else min(t - last, MAX_TWIST_SPAN)
            last = t
            if abs(v[i]) <= zero_v and abs(w[i]) <= zero_w:
                continue
            means = self._means(t, span)
            if means is None:
                continue
            v[i] *= means[0]
            w[i] += means[1]
        self._last_twist_t = last
        return v, w
