"""Gyro scale calibration: turn in place a counted number of times, back to a mark.

Why: a gyro's scale error (MPU6050 datasheet: sensitivity tolerance +-3 %) turns every angle
the robot turns into a heading error of that fraction: 1 % over a net 600 deg of turning is
6 deg. Neither the wheels (their yaw rate carries the wheel distance's own error) nor the
gyro's bias learnt at rest can reveal it; only a known angle can. The procedure every robot
owner can do with a piece of tape on the floor:

1. put the robot on a mark (tape along one side, or a line on the floor), keep it still for
   at least ``min_rest`` s (3 s by default);
2. turn it in place, N full turns in one direction (teleoperation or a constant command; 5 to
   10 turns at 0.5-1.5 rad/s: more turns, smaller error), and stop it back on the mark;
3. keep it still again for at least ``min_rest`` s; log the IMU throughout.

Then the angle the gyro integrated about the vertical, with its bias taken from the two rests,
is compared with ``N * 360 deg``: the scale error is ``g = measured / declared - 1`` (the gyro
reads ``(1 + g)`` times the true rate, the convention of the planar EKF's ``g`` state). The
uncertainty adds how well the robot was put back on the mark (``mark_std``, 1 deg by default:
a robot aligned by eye with a tape line), the bias's uncertainty over the turning time, and the
integrated white noise. Ten turns and a 1 deg mark give about 0.03 %.

The result goes into robot.toml's ``[ekf]`` as ``gyro_scale`` and ``gyro_scale_std``
(:class:`fusion.planar.ekf.EkfNoise`; ``fusion calibrate gyro-scale`` writes it): the EKF then
integrates the heading with the calibrated scale and its covariance reflects what is left.

Units: s, rad, rad/s, m/s^2. The vertical is the direction of the specific force at rest (so a
tilted IMU mount needs no configuration); the rate about it is ``gyro . up``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import trapezoid

__all__ = ["GyroScaleCalibration", "calibrate_gyro_scale", "combine_gyro_scales"]

_DEG = math.pi / 180.0


@dataclass(frozen=True)
class GyroScaleCalibration:
    """The result of one calibration run (or several combined).

    Attributes:
        scale_error: ``g``, the gyro reads ``(1 + g)`` times the true rate about the vertical, 1.
        scale_error_std: standard deviation of ``g``, 1.
        measured_turns: turns the gyro integrated (bias removed), signed (CCW positive).
        declared_turns: turns the robot really made (the mark), signed.
        turning_time: time between the two rests, s.
        bias_before, bias_after: the rate about the vertical at the two rests, rad/s.
        rest_before, rest_after: length of the two rests used, s.
        vertical: (3,) unit vector of the vertical (up) in the IMU frame, from the first
            rest; the rate calibrated is ``gyro . vertical``, so feed the EKF that rate (the
            pipeline's tilt-compensated rate is the same on a level floor).
    """

    scale_error: float
    scale_error_std: float
    measured_turns: float
    declared_turns: float
    turning_time: float
    bias_before: float
    bias_after: float
    rest_before: float
    rest_after: float
    vertical: tuple[float, float, float] = (0.0, 0.0, 1.0)

    @property
    def mount_tilt(self) -> float:
        """Angle between the IMU's z axis and the vertical, rad."""
        return math.acos(max(-1.0, min(1.0, self.vertical[2])))

    def ekf_fields(self) -> dict[str, float]:
        """The ``[ekf]`` keys of robot.toml (:class:`fusion.planar.ekf.EkfNoise` fields)
        that carry this calibration."""
        return {"gyro_scale": self.scale_error, "gyro_scale_std": self.scale_error_std}

    def report(self) -> str:
        """A few human-readable lines."""
        return (
            f"gyro turned {self.measured_turns:+.4f} turns for {self.declared_turns:+g} declared "
            f"in {self.turning_time:.1f} s\n"
            f"gyro scale error g = {100 * self.scale_error:+.3f} % +- "
            f"{100 * self.scale_error_std:.3f} % (reads (1 + g) x the true rate)\n"
            f"bias about the vertical: {math.degrees(self.bias_before):+.4f} deg/s before "
            f"({self.rest_before:.1f} s at rest), {math.degrees(self.bias_after):+.4f} deg/s "
            f"after ({self.rest_after:.1f} s)\n"
            f"IMU z axis {math.degrees(self.mount_tilt):.2f} deg from the vertical"
        )


def _rest_length(rate: NDArray[np.float64], t: NDArray[np.float64], threshold: float) -> int:
    """Number of leading samples before ``rate`` first departs from its first second's median
    by more than ``threshold`` (rad/s)."""
    head = rate[t <= t[0] + 1.0]
    moved = np.flatnonzero(np.abs(rate - np.median(head)) > threshold)
    return int(moved[0]) if moved.size else rate.size


def calibrate_gyro_scale(
    imu_t: ArrayLike,
    gyro: ArrayLike,
    accel: ArrayLike,
    turns: float,
    *,
    mark_std: float = 1.0 * _DEG,
    min_rest: float = 3.0,
    turn_threshold: float = 0.05,
    margin: float = 0.5,
    max_scale_error: float = 0.1,
) -> GyroScaleCalibration:
    """Gyro scale error from one run of turns in place (see the module docstring).

    Args:
        imu_t: (N,) stamps, s, increasing.
        gyro, accel: (N, 3) rad/s and m/s^2 in the IMU frame (any mount).
        turns: the full turns the robot made from the mark back to it, signed (CCW
            positive; ``-5`` is five clockwise turns).
        mark_std: how well the robot was put back on the mark, rad (1 sigma).
        min_rest: least time at rest before and after the turns, s.
        turn_threshold: a rate this far (rad/s) from the rest's median ends a rest.
        margin: time trimmed off each rest next to the turning, s.
        max_scale_error: a larger ``|g|`` is refused as a miscount (the datasheet allows 3 %).

    Raises:
        ValueError: inputs of the wrong shape, non-finite or not increasing; ``turns`` zero or
            not finite; a rest shorter than ``min_rest`` at either end; a measured turn count
            that does not match ``turns`` (the message gives both).
    """
    t = np.asarray(imu_t, dtype=float).reshape(-1)
    g = np.asarray(gyro, dtype=float)
    a = np.asarray(accel, dtype=float)
    if g.shape != (t.size, 3) or a.shape != (t.size, 3):
        raise ValueError(f"gyro and accel must be ({t.size}, 3) like the stamps, got "
                         f"{g.shape} and {a.shape}")
    if t.size < 3 or not (np.isfinite(t).all() and np.isfinite(g).all() and
                          np.isfinite(a).all()):
        raise ValueError("need at least 3 finite IMU samples")
    if np.any(np.diff(t) <= 0):
        i = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise ValueError(f"IMU stamps must increase: sample {i} at {t[i]!r} s")
    if not (math.isfinite(turns) and turns != 0):
        raise ValueError(f"turns must be a non-zero number of full turns, got {turns!r}")
    # the vertical from the first rest: the rate about it needs no mount configuration
    first = t <= t[0] + 1.0
    up = a[first].mean(axis=0)
    up /= np.linalg.norm(up)
    rate = g @ up
    n_before = _rest_length(rate, t, turn_threshold)
    n_after = _rest_length(rate[::-1], -t[::-1], turn_threshold)
    before = t < t[max(n_before - 1, 0)] - margin
    after = t > t[t.size - n_after] + margin
    rest_b = float(np.ptp(t[before])) if before.sum() > 1 else 0.0
    rest_a = float(np.ptp(t[after])) if after.sum() > 1 else 0.0
    if rest_b < min_rest or rest_a < min_rest:
        raise ValueError(
            f"the robot must stand still for at least {min_rest:g} s before and after the "
            f"turns: found {rest_b:.1f} s at the start and {rest_a:.1f} s at the end (a rest "
            f"ends where the rate about the vertical departs by {math.degrees(turn_threshold):g} "
            "deg/s)")
    b0, b1 = float(rate[before].mean()), float(rate[after].mean())
    tb0, tb1 = float(t[before].mean()), float(t[after].mean())
    bias = b0 + (b1 - b0) * (t - tb0) / (tb1 - tb0)  # linear drift between the rests
    span = slice(int(np.flatnonzero(before)[-1]), int(np.flatnonzero(after)[0]) + 1)
    ts, rs = t[span], rate[span] - bias[span]
    angle = float(trapezoid(rs, ts))
    declared = 2.0 * math.pi * turns
    measured_turns = angle / (2.0 * math.pi)
    scale = angle / declared - 1.0
    if abs(measured_turns - turns) > 0.25 or abs(scale) > max_scale_error:
        raise ValueError(
            f"the gyro measured {measured_turns:+.3f} turns ({math.degrees(angle):+.1f} deg) "
            f"but {turns:+g} were declared: count the turns again (CCW positive), check that "
            "the robot turned in place back to the mark and that the gyro did not saturate")
    duration = float(ts[-1] - ts[0])
    # uncertainty of the angle: the mark, the bias over the turning time, the white noise
    noise = np.concatenate([rate[before] - b0, rate[after] - b1])
    period = float(np.median(np.diff(t)))
    bias_std = math.sqrt(np.var(noise) / noise.size + ((b1 - b0) / (2.0 * math.sqrt(3.0))) ** 2)
    var_angle = mark_std ** 2 + (bias_std * duration) ** 2 + np.var(noise) * period * duration
    return GyroScaleCalibration(
        scale_error=scale, scale_error_std=math.sqrt(var_angle) / abs(declared),
        measured_turns=measured_turns, declared_turns=float(turns), turning_time=duration,
        bias_before=b0, bias_after=b1, rest_before=rest_b, rest_after=rest_a,
        vertical=(float(up[0]), float(up[1]), float(up[2])))


def combine_gyro_scales(runs: Sequence[GyroScaleCalibration]) -> GyroScaleCalibration:
    """Inverse-variance mean of several runs (e.g. one clockwise, one counter-clockwise:
    a bias error then cancels). The turn counts (unsigned) and times add up; the rests are the
    shortest.

    Raises:
        ValueError: no runs.
    """
    if not runs:
        raise ValueError("combine_gyro_scales needs at least one run")
    w = np.array([1.0 / r.scale_error_std ** 2 for r in runs])
    g = np.array([r.scale_error for r in runs])
    return GyroScaleCalibration(
        scale_error=float(np.sum(w * g) / np.sum(w)), scale_error_std=float(1.0 / math.sqrt(
            np.sum(w))),
        measured_turns=float(sum(abs(r.measured_turns) for r in runs)),
        declared_turns=float(sum(abs(r.declared_turns) for r in runs)),
        turning_time=float(sum(r.turning_time for r in runs)),
        bias_before=runs[0].bias_before, bias_after=runs[-1].bias_after,
        rest_before=min(r.rest_before for r in runs), rest_after=min(r.rest_after for r in runs),
        vertical=runs[0].vertical)
