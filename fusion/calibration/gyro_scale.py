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
from scipy.stats import chi2

from fusion.calibration.gyro_limits import check_gyro_units, saturated_samples

__all__ = ["GyroScaleCalibration", "calibrate_gyro_scale", "combine_gyro_scales"]

_DEG = math.pi / 180.0

#: rad/s: an MPU6050's rate noise at rest, per sample (standard deviation)
MPU6050_REST_NOISE = 0.001
#: rad/s: above this spread over the first second (standard deviation) the gyro cannot be at
#: rest in rad/s
REST_SPREAD_MAX = 20.0 * MPU6050_REST_NOISE
#: Above this |g| a result is reported with a caution: the datasheet allows 3 %, but a robot
#: a quarter turn off its mark after 10 turns gives 2.5 % too.
LARGE_SCALE_ERROR = 0.02
#: The combined runs must agree with each other at this chi-square probability; where they do
#: not, but no run is further than RUN_SPREAD_MAX from their mean, the combined standard
#: deviation is widened by the Birge ratio sqrt(chi-square / dof) instead (a scale that
#: differs a little with the turning direction is a property of the gyro, not a mistake).
AGREEMENT_PROBABILITY = 0.999
RUN_SPREAD_MAX = 0.005
#: s of each rest next to the turns left out of the wheels' check (their stamps and the IMU's
#: may be that far apart, and a gearbox settles there)
WHEEL_CHECK_MARGIN = 1.0


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
        note: what the reader should know about a combination (its standard deviation
            widened because the runs differ), or "".
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
    note: str = ""

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
            + (f"\ncaution: a scale error of {100 * self.scale_error:+.2f} % is large (the "
               f"datasheet allows 3 %); it is also what a robot "
               f"{abs(self.scale_error * self.declared_turns) * 360.0:.0f} deg off its mark "
               "would give: check that it ended on the mark"
               if abs(self.scale_error) > LARGE_SCALE_ERROR else "")
            + (f"\nnote: {self.note}" if self.note else "")
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
    max_scale_error: float = 0.05,
    max_gap: float = 0.1,
    wheel_t: ArrayLike | None = None,
    ticks: ArrayLike | None = None,
    wheel_geometry: tuple[float, float] | None = None,
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
        max_scale_error: a larger ``|g|`` is refused as a miscount (the datasheet allows 3 %;
            on an accurate gyro a miscount by one of up to 19 turns gives more than 5 %, on
            one 3 % off, of up to 12).
        max_gap: the longest interval without an IMU sample between the rests, s (or five
            sample periods, if longer): the angle turned across a gap is unknown.
        wheel_t, ticks, wheel_geometry: optional wheel frames of the same run ((M,) stamps on
            the IMU's clock, s; (M, 2) left and right ticks per frame) and the chassis'
            ``(speed_ratio, wheel_distance)`` (m/tick, m): a rest in which the wheels turned
            the robot by more than the mark's uncertainty, counted over the turning time
            (the rate taken for bias), is refused; :data:`WHEEL_CHECK_MARGIN` s of each rest
            next to the turns are left out of this check.

    Raises:
        ValueError: inputs of the wrong shape, non-finite (naming the first such sample) or
            not increasing; ``turns`` zero or not finite; a gyro beyond the MPU6050's full
            scale (other units), or held at its limit during the turns; a rest shorter than
            ``min_rest`` at either end, or one the wheels turned in; a gap in the samples
            during the turns; a measured turn count whose scale error exceeds
            ``max_scale_error`` (the message gives both counts).
    """
    t = np.asarray(imu_t, dtype=float).reshape(-1)
    g = np.asarray(gyro, dtype=float)
    a = np.asarray(accel, dtype=float)
    if g.shape != (t.size, 3) or a.shape != (t.size, 3):
        raise ValueError(f"gyro and accel must be ({t.size}, 3) like the stamps, got "
                         f"{g.shape} and {a.shape}")
    if t.size < 3:
        raise ValueError(f"need at least 3 IMU samples, got {t.size}")
    finite = np.isfinite(t) & np.isfinite(g).all(axis=1) & np.isfinite(a).all(axis=1)
    if not finite.all():
        i = int(np.flatnonzero(~finite)[0])
        raise ValueError(f"IMU sample {i} (t = {float(t[i])!r} s) is not finite "
                         f"({int(np.sum(~finite))} such samples): the angle turned across "
                         "them is unknown")
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
    check_gyro_units(g)
    n_before = _rest_length(rate, t, turn_threshold)
    n_after = _rest_length(rate[::-1], -t[::-1], turn_threshold)
    if n_before == t.size:
        raise ValueError(
            "the rate about the vertical never departs from its first second's by "
            f"{math.degrees(turn_threshold):g} deg/s: no turn in this run")
    before = (t < t[n_before - 1] - margin) if n_before else np.zeros(t.size, bool)
    after = (t > t[t.size - n_after] + margin) if n_after else np.zeros(t.size, bool)
    rest_b = float(np.ptp(t[before])) if before.sum() > 1 else 0.0
    rest_a = float(np.ptp(t[after])) if after.sum() > 1 else 0.0
    if rest_b < min_rest or rest_a < min_rest:
        spread = float(np.std(rate[t <= t[0] + 1.0]))
        hint = ""
        if spread > REST_SPREAD_MAX:
            hint = (f"; over the first second the rate spreads by {spread:.3g} rad/s, "
                    f"{spread / MPU6050_REST_NOISE:.0f} times an MPU6050's at rest: the robot "
                    "moved, or the "
                    "gyro is not in rad/s (deg/s?)")
        raise ValueError(
            f"the robot must stand still for at least {min_rest:g} s before and after the "
            f"turns: found {rest_b:.1f} s at the start and {rest_a:.1f} s at the end (a rest "
            f"ends where the rate about the vertical departs by {math.degrees(turn_threshold):g} "
            f"deg/s){hint}")
    b0, b1 = float(rate[before].mean()), float(rate[after].mean())
    tb0, tb1 = float(t[before].mean()), float(t[after].mean())
    bias = b0 + (b1 - b0) * (t - tb0) / (tb1 - tb0)  # linear drift between the rests
    span = slice(int(np.flatnonzero(before)[-1]), int(np.flatnonzero(after)[0]) + 1)
    ts, rs = t[span], rate[span] - bias[span]
    period = float(np.median(np.diff(t)))
    gaps = np.diff(ts)
    worst = int(np.argmax(gaps))
    if gaps[worst] > max(max_gap, 5.0 * period):
        raise ValueError(
            f"no IMU sample for {gaps[worst]:.3g} s after t = {float(ts[worst])!r} s, during the "
            "turns: the angle turned across the gap is unknown; record the run again")
    clipped = saturated_samples(g[span])
    if clipped.any():
        first = int(np.flatnonzero(clipped)[0])
        limit = math.degrees(float(np.abs(g[span][first]).max()))
        raise ValueError(
            f"the gyro is held at its limit ({limit:.0f} deg/s) on {int(clipped.sum())} "
            "samples during the turns, from t = "
            f"{float(ts[first]):.2f} s: a saturated gyro reads its limit, not the rate; turn "
            "slower, or set a larger full scale ([imu] gyro_range_dps)")
    if wheel_t is not None and ticks is not None and wheel_geometry is not None:
        _refuse_turning_wheels(np.asarray(wheel_t, dtype=float).reshape(-1),
                               np.asarray(ticks), wheel_geometry, t[before], t[after],
                               float(ts[-1] - ts[0]), mark_std)
    angle = float(trapezoid(rs, ts))
    declared = 2.0 * math.pi * turns
    measured_turns = angle / (2.0 * math.pi)
    scale = angle / declared - 1.0
    if abs(scale) > max_scale_error:
        ratio = angle / declared
        units = (" The ratio is 180/pi's: the gyro is in deg/s, not rad/s."
                 if abs(ratio / (180.0 / math.pi) - 1.0) < 0.1 else "")
        raise ValueError(
            f"the gyro measured {measured_turns:+.3f} turns ({math.degrees(angle):+.1f} deg) "
            f"but {turns:+g} were declared, a scale error of {100 * scale:+.1f} % where an "
            f"MPU6050's is within 3 %: count the turns again (CCW positive), check that "
            f"the robot turned in place back to the mark and that the gyro did not "
            f"saturate.{units}")
    duration = float(ts[-1] - ts[0])
    # uncertainty of the angle: the mark, the bias over the turning time, the white noise
    noise = np.concatenate([rate[before] - b0, rate[after] - b1])
    bias_std = math.sqrt(np.var(noise) / noise.size + ((b1 - b0) / (2.0 * math.sqrt(3.0))) ** 2)
    var_angle = mark_std ** 2 + (bias_std * duration) ** 2 + np.var(noise) * period * duration
    return GyroScaleCalibration(
        scale_error=scale, scale_error_std=math.sqrt(var_angle) / abs(declared),
        measured_turns=measured_turns, declared_turns=float(turns), turning_time=duration,
        bias_before=b0, bias_after=b1, rest_before=rest_b, rest_after=rest_a,
        vertical=(float(up[0]), float(up[1]), float(up[2])))


def _refuse_turning_wheels(wheel_t: NDArray[np.float64], ticks: ArrayLike,
                           wheel_geometry: tuple[float, float],
                           rest_before: NDArray[np.float64], rest_after: NDArray[np.float64],
                           turning_time: float, mark_std: float) -> None:
    """Raise if the wheels turned the robot during a rest (stamps ``rest_*``, s; the
    :data:`WHEEL_CHECK_MARGIN` next to the turns left out) at a rate that, taken for the
    gyro's bias over ``turning_time`` s, would cost more angle than ``mark_std`` (rad)."""
    ticks = np.asarray(ticks, dtype=float).reshape(-1, 2)
    speed_ratio, wheel_distance = wheel_geometry
    for name, rest in (("before", rest_before), ("after", rest_after)):
        lo, hi = float(rest[0]), float(rest[-1])
        if name == "before":
            hi -= WHEEL_CHECK_MARGIN
        else:
            lo += WHEEL_CHECK_MARGIN
        inside = (wheel_t >= lo) & (wheel_t <= hi)
        if hi - lo <= 0.0 or not inside.any():
            continue
        turned = float(np.sum(ticks[inside, 1] - ticks[inside, 0])) * speed_ratio / wheel_distance
        cost = abs(turned) / (hi - lo) * turning_time
        if cost > mark_std:
            raise ValueError(
                f"the wheels turned the robot by {math.degrees(turned):+.2f} deg during the rest "
                f"{name} the turns (t = {lo:.2f} to {hi:.2f} s): taken for the gyro's bias, that "
                f"rate costs {math.degrees(cost):.1f} deg over the {turning_time:.0f} s of "
                f"turning, more than the mark's {math.degrees(mark_std):g} deg; the robot must "
                "stand still there")


def combine_gyro_scales(runs: Sequence[GyroScaleCalibration]) -> GyroScaleCalibration:
    """Inverse-variance mean of several runs (e.g. one clockwise, one counter-clockwise:
    a bias error then cancels). The turn counts (unsigned) and times add up; the rests are the
    shortest.

    Runs that differ by more than their uncertainties (chi-square above its
    :data:`AGREEMENT_PROBABILITY` quantile) but each within :data:`RUN_SPREAD_MAX` of the mean
    give the mean with its standard deviation widened by the Birge ratio, and a note.

    Raises:
        ValueError: no runs; runs that disagree beyond their uncertainties with one further
            than :data:`RUN_SPREAD_MAX` from the mean (a miscount, a robot off its mark, a
            rest that was no rest), naming each run's value.
    """
    if not runs:
        raise ValueError("combine_gyro_scales needs at least one run")
    w = np.array([1.0 / r.scale_error_std ** 2 for r in runs])
    g = np.array([r.scale_error for r in runs])
    mean = float(np.sum(w * g) / np.sum(w))
    spread = float(np.sum(w * (g - mean) ** 2))
    std = float(1.0 / math.sqrt(np.sum(w)))
    note = ""
    dof = len(runs) - 1
    if dof and spread > chi2.ppf(AGREEMENT_PROBABILITY, dof) and (
            np.max(np.abs(g - mean)) <= RUN_SPREAD_MAX):
        birge = math.sqrt(spread / dof)
        std *= birge
        note = (f"the runs differ by more than their uncertainties (chi-square {spread:.1f} "
                f"on {dof} degree{'s' if dof > 1 else ''} of freedom), each within "
                f"{100 * RUN_SPREAD_MAX:g} % of the mean: its standard deviation is widened "
                f"{birge:.1f} times (a scale that differs with the turning direction, or a "
                "mark missed by a little)")
    elif dof and spread > chi2.ppf(AGREEMENT_PROBABILITY, dof):
        values = ", ".join(f"{100 * r.scale_error:+.3f} % +- {100 * r.scale_error_std:.3f} %"
                           for r in runs)
        raise ValueError(
            f"the runs disagree beyond their uncertainties ({values}; chi-square "
            f"{spread:.1f} on {len(runs) - 1} degree{'s' if len(runs) > 2 else ''} of "
            "freedom): one was miscounted, did "
            "not end on its mark or did not stand still in a rest; check each, or give a "
            "larger --mark-std if the marks were rough")
    return GyroScaleCalibration(
        scale_error=mean, scale_error_std=std,
        measured_turns=float(sum(abs(r.measured_turns) for r in runs)),
        declared_turns=float(sum(abs(r.declared_turns) for r in runs)),
        turning_time=float(sum(r.turning_time for r in runs)),
        bias_before=runs[0].bias_before, bias_after=runs[-1].bias_after,
        rest_before=min(r.rest_before for r in runs), rest_after=min(r.rest_after for r in runs),
        vertical=runs[0].vertical, note=note)
