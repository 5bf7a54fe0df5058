"""Trust signals: do a run's inputs agree within what the fusion model explains?

The EKF always returns an answer; these checks say when that answer should not be trusted
because its inputs disagree beyond the model (wheel/twist odometry and the gyro describe
different motions, or the gyro's bias estimate left the sensor's physical range). They look
only at a run's counters (:meth:`fusion.pipeline.core.PipelineStats.as_dict`: ``wheel_frames``,
``twist_messages``, ``slips``, ``encoder_faults``, ``gyro_turn``, ``gyro_time``,
``wheel_turn``, ``twist_turn``, ``wheel_travel``, ``twist_travel``, ``fault_turn``,
``odometry_rate_slope``,
``odometry_rate_correlation``, ``imu_samples``, ``accel_sum``)
and the EKF's final gyro bias and wheel calibration estimates, so ``fusion replay`` and
``fusion run`` use the same checks, and a script can run them on a finished pipeline.

Checks (each a :class:`TrustWarning` with its figures):

``slip``
    More than :data:`SLIP_FRACTION_LIMIT` of the odometry frames (wheel frames or twists)
    were flagged as slip (their yaw rate disagreed with the gyro's) or, once most turns
    disagreed, were turning frames whose yaw rate the EKF no longer fused
    (``wheel_rate_distrusted``): slip is an exception the model down-weights, not the normal
    state; most frames disagreeing means the two sources describe different motions (a
    skid-steer base, a wrong wheel_distance, an IMU on another body, a wrong mount).
``encoder_fault``
    More than :data:`ENCODER_FAULT_LIMIT` of the odometry frames read zero speed while the
    IMU showed motion (``encoder_faults``: not fused, the pose coasted on the motion model
    with a growing covariance). A few seconds of a dead encoder feed are what the EKF is
    built to ride through; a tenth of the run is no longer a fault but the input: a wheel
    encoder unplugged, or a driver whose twist stays zero (a bag whose twists are all zero
    has its motion taken from its poses, :mod:`fusion.io.odometry_motion`; one whose twists
    are zero only at times does not).
``gyro_bias``
    The EKF's gyro bias estimate beyond :data:`GYRO_BIAS_LIMIT`: the MPU-6050's initial
    zero-rate output tolerance, +-20 deg/s at 25 C (InvenSense MPU-6000/MPU-6050 Product
    Specification rev. 3.4, section 6.1, "Initial ZRO Tolerance"). A larger "bias" is a
    disagreement the filter folded into its bias state.
``wheel_scale``
    The EKF's wheel yaw-rate scale ``k`` (the wheels' yaw rate over the gyro's, less one) at
    the end of a run with wheel frames is beyond :data:`WHEEL_SCALE_LIMIT`: robot.toml's
    wheel_distance is that far from what the gyro sees, three times the EKF's prior for it
    (``EkfNoise.calib_k_std``, 5 %). A skid-steer base with its geometric track (its wheels
    turn more than a differential drive's) or a mistyped distance; until it is corrected the
    turns' disagreement went partly into the gyro bias (benchmarks/terrain: a base whose
    wheels turn 1.5 times too fast, driving from the first sample, ended with k = +0.49 and
    28 deg of yaw RMSE, without any other warning; 19.8 deg with the filter of 2026-11-27;
    4.7 deg opted in to the EKF's restart of ``k`` at the ticks' fitted scale once 2 s of
    turns show it, ``EkfNoise.wheel_scale_refit``: the turns before that still bend the
    bias).
``odometry_scale``
    A run with odometry twists whose yaw rate, fitted against the gyro's over every moving
    twist (``odometry_rate_slope``), is more than :data:`WHEEL_SCALE_LIMIT` off it, while
    the two still correlate (``odometry_rate_correlation`` >= 0.9: the odometry measures
    the rotation, at another scale). That is a skid-steer base's odometry computed with
    its geometric track, or a wrong track or wheel radius in its driver. The EKF never
    fuses such yaw rates (they are never proven in turns), so the fused heading rests on
    the gyro; the warning says so instead of leaving it to the count of distrusted turning
    twists (the terrain benchmark's skid-steer bags, slope 1.49-1.50: 0 of 12 runs warned
    before, heading_divergence only where the turns happen not to cancel).
``mount``
    The accelerometer's mean over the run (``accel_sum / imu_samples``, in the base frame
    after the configured mount) points more than :data:`MOUNT_TILT_LIMIT` from the base's z
    axis: the IMU does not sit as robot.toml's ``imu_mount_rpy`` (or ``--imu-mount-rpy``)
    says. The heading rate is then taken about the wrong axis and the accelerometer's slip
    and stillness checks look along the wrong ones; ``fusion replay`` adds a mount estimated
    from the log (:mod:`fusion.calibration.mount`). Only with at least
    :data:`MOUNT_MIN_SAMPLES` samples whose mean is at least half of gravity (an
    accelerometer that reads in m/s^2).
``gyro_axis``
    The odometry's yaw rate, fitted against the gyro's over the moving frames
    (``odometry_rate_slope``, wheel frames or twists), is a close copy of it
    (``|odometry_rate_correlation|`` >= :data:`ODOMETRY_CORRELATION`) at a slope within
    :data:`ACCEL_SCALE_TOLERANCE` of -1 (the gyro's vertical axis points down: an IMU
    upside down against imu_mount_rpy, or an axis sign flipped in the driver) or of pi/180
    (gyro rates in deg/s where rad/s are taken), or beyond 1 as far as a skid-steer base's
    odometry overstates turns (:data:`SKID_FACTOR_MAX`: -1.49 or 1.49 x pi/180 on the
    terrain benchmark's bags; an independent probe's skid-steer bag with its gyro in deg/s
    had been told "a skid-steer base's odometry", 25 m of GPS RMSE, and its stops blamed on
    vibration and a dead encoder feed). No model state explains either; the
    warning names the cause that ``slip`` and ``heading_divergence`` only show. Takes the
    place of ``odometry_scale``.
``accel_scale``
    The accelerometer's mean over the run has a magnitude more than
    :data:`ACCEL_SCALE_TOLERANCE` off standard gravity: not m/s^2 as the inputs take (ROS
    sensor_msgs/Imu, imu.csv). About 1/9.8 of it is a log in g; a power of two a driver that
    scales by another full-scale range than the chip's AFS_SEL (2, 4, 8 or 16 g). The
    stillness, slip and attitude checks read their accelerations at the wrong scale. Same
    samples as ``mount``; either check, not both (a mean too small to be gravity says
    nothing of the mount); neither for an accelerometer that reads exactly zero (a
    gyro-only source).
``implausible``
    More than :data:`IMPLAUSIBLE_LIMIT` of the inputs (IMU samples, wheel frames, twists) were
    refused by the EKF as implausible or non-finite (``invalid``: a rate above ``max_rate``,
    a speed above ``max_speed``): not a corrupt value now and then but a stream in other
    units (a twist in cm/s on the terrain outdoor bag: 2451 of 2999 refused, the rest fused
    100 times too fast, only a counter said so).
``heading_divergence``
    The odometry's heading change (wheel frames and twists) differs from what the gyro's
    (its bias estimate taken out) predicts for it through the EKF's wheel calibration
    (``(1 + k) * gyro turn + c * distance``, the yaw-rate scale ``k`` and the radius mismatch
    ``c`` each credited anywhere between 0 and its estimate, which is clipped at
    :data:`WHEEL_SCALE_LIMIT` and :data:`RADIUS_MISMATCH_LIMIT`: estimates learnt without a
    stop are confounded with the gyro bias, and may only explain a difference, never make one)
    by more than
    ``HEADING_FLOOR + HEADING_FRACTION * |larger turn| + HEADING_RATE * gyro_time``: a few
    degrees of noise, what the calibration states have not yet learnt (up to
    :data:`HEADING_FRACTION` of the turns), and on average :data:`HEADING_RATE` for what
    the model explains over time (bias wander, the short slip events the EKF gates out). On
    ``degraded_mission`` runs (:mod:`fusion.evaluation.synthetic`: 3 % wheel_distance error,
    0.5 deg/s bias, three one-second 30 % slip patches) the divergence is at most 0.52 of
    this allowance (seeds 0-9, 60 s and 300 s; 0.62 without crediting k and c; the
    constants were set by reasoning, then checked on these runs); on the bundled Jackal bag
    (odometry +2044 deg, gyro +271 deg raw in 61 s) it is 7.1 times the allowance. On the
    black-box simulator's dead seed 403 (the odometry turned -131 deg where the gyro turned
    -340 over 79 m; the EKF's k -0.027 and c +0.023 rad/m, a 0.5 % radius mismatch, predict
    -229 deg) the 98 deg left are within the 199 deg allowed; without k and c credited the
    209 deg apart called a track of 0.9 deg yaw RMSE untrustworthy. The gyro's turn while
    the odometry read zero as an encoder fault (``fault_turn``) is left out: the odometry
    could not see it, and ``encoder_fault`` speaks for that (an independent probe's dead feed
    during a spin in place had the odometry 295 deg behind, named as a calibration
    disagreement on a track of 5.9 deg yaw RMSE). Where ``odometry_scale`` has spoken (the
    twists' yaw rate a steady multiple of the gyro's), the twists' turn is taken over that
    multiple: that warning already names the disagreement, and repeating it here depended
    on chance (a skid-steer bag's 1.49 times: 302 deg apart against 298 allowed in one
    replay, under the limit in others of the same data).

Angles in rad and rates in rad/s inside; messages print degrees.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from fusion.geometry.mount import angle_from_vertical
from fusion.planar._ekf_core import LINEAR_SOURCE_CORRELATION
from fusion.types.constants import STANDARD_GRAVITY

__all__ = [
    "ACCEL_SCALE_TOLERANCE",
    "ENCODER_FAULT_LIMIT",
    "GYRO_BIAS_LIMIT",
    "HEADING_FLOOR",
    "HEADING_FRACTION",
    "HEADING_RATE",
    "IMPLAUSIBLE_LIMIT",
    "MOUNT_MIN_SAMPLES",
    "MOUNT_TILT_LIMIT",
    "ODOMETRY_CORRELATION",
    "RADIUS_MISMATCH_LIMIT",
    "SKID_FACTOR_MAX",
    "SLIP_FRACTION_LIMIT",
    "WHEEL_SCALE_LIMIT",
    "TrustWarning",
    "imu_units_wrong",
    "trust_warnings",
    "units_caveat",
    "units_first",
]

#: Share of the inputs refused as implausible above which the ``implausible`` check fires.
IMPLAUSIBLE_LIMIT = 0.01

#: Fraction of odometry frames flagged as slip above which the inputs disagree ("most").
SLIP_FRACTION_LIMIT = 0.5
#: Fraction of odometry frames read as encoder faults above which the odometry is missing
#: rather than faulty (the black-box simulator's dead feed, 8 s of 300 s, is 2.7 %).
ENCODER_FAULT_LIMIT = 0.1
#: rad/s: the MPU-6050's initial ZRO tolerance, +-20 deg/s (datasheet rev. 3.4, 6.1).
GYRO_BIAS_LIMIT = math.radians(20.0)
#: Largest wheel yaw-rate scale error ``|k|`` (1) taken as a calibration error the EKF follows:
#: three times its prior's standard deviation (EkfNoise.calib_k_std).
WHEEL_SCALE_LIMIT = 0.15
#: rad/m: the largest wheel radius mismatch ``|c|`` credited to the odometry's turns by
#: ``heading_divergence``: three times its prior's standard deviation (EkfNoise.calib_c_std).
RADIUS_MISMATCH_LIMIT = 0.15
#: The least correlation of the odometry's yaw rate with the gyro's for ``odometry_scale``
#: (below it the rates are no scaled copy of each other and ``slip`` or
#: ``heading_divergence`` speak): the EKF's own test for straight driving from such rates.
ODOMETRY_CORRELATION = LINEAR_SOURCE_CORRELATION
#: rad: the mean specific force further than this from the base's z axis means the configured
#: mount is wrong. Before the first stop the fusion takes the gyro's z axis as the vertical
#: one: at 15 deg that costs 1 - cos(15 deg) = 3.4 % of every turn, more than the MPU-6050's
#: own scale tolerance (3 %); and no route's mean slope comes near it.
MOUNT_TILT_LIMIT = math.radians(15.0)
#: Largest relative difference of the accelerometer's mean magnitude from standard gravity
#: taken as a sensor's error, not a unit's: the MPU-6050's zero-g offsets (+-50 mg on x, y,
#: +-80 mg on z; datasheet rev. 3.4, 6.2) and sensitivity tolerance (+-3 %), a mean slope's
#: cos (15 deg: 3.4 %); a range mix-up is a factor of 2 or more, a log in g one of 9.8.
ACCEL_SCALE_TOLERANCE = 0.2
#: IMU samples the ``mount`` check needs (a second at 100 Hz: a live run's first batches say
#: nothing about the mean).
MOUNT_MIN_SAMPLES = 100
#: rad: heading disagreement always allowed (noise, start-up).
HEADING_FLOOR = math.radians(15.0)
#: Heading disagreement allowed per radian turned (a wheel_distance error up to 10 %).
HEADING_FRACTION = 0.10
#: rad/s: average heading disagreement allowed over the run (bias wander on top of the final
#: estimate, slip events the EKF gates out).
HEADING_RATE = math.radians(0.5)


@dataclass(frozen=True)
class TrustWarning:
    """One failed check: ``name`` (``slip``, ``encoder_fault``, ``gyro_bias``, ``wheel_scale``,
    ``odometry_scale``, ``mount``, ``gyro_axis``, ``accel_scale``, ``implausible``,
    ``heading_divergence``;
    ``twist_pose`` from :mod:`fusion.jobs.odometry_signs`; ``gyro_axes``, ``handedness`` and
    others from :mod:`fusion.jobs.streams`), a
    sentence for the user with the figures, and the figures (SI: rad, rad/s, s, fractions)."""

    name: str
    message: str
    figures: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: ``{"name", "message", **figures}``."""
        return {"name": self.name, "message": self.message, **self.figures}


def trust_warnings(stats: Mapping[str, Any], gyro_bias: float | None,
                   wheel_rate_scale: float | None = None,
                   radius_mismatch: float | None = None) -> list[TrustWarning]:
    """The checks of the module docstring over a run's counters ``stats`` (the keys of
    :meth:`fusion.pipeline.core.PipelineStats.as_dict`; missing keys count as 0), the EKF's
    final gyro bias estimate (rad/s; None without an IMU), its final wheel yaw-rate scale
    ``k`` (1; None: not checked, and 0 for ``heading_divergence``) and radius mismatch ``c``
    (rad/m; None: 0). Empty when nothing disagrees."""
    out: list[TrustWarning] = []
    frames = int(stats.get("wheel_frames", 0)) + int(stats.get("twist_messages", 0))
    slips = int(stats.get("slips", 0))
    distrusted = int(stats.get("wheel_rate_distrusted", 0))
    disagree = slips + distrusted
    if frames and disagree / frames > SLIP_FRACTION_LIMIT:
        out.append(TrustWarning(
            "slip",
            f"{100 * disagree / frames:.0f} % of the {frames} odometry frames disagree with "
            f"the gyro on the yaw rate or with the accelerometer on the speed ({slips} "
            f"flagged as slip, {distrusted} turning frames "
            "whose yaw rate was not fused because the odometry was not yet proven in turns "
            "or most turns disagreed; more than "
            f"{100 * SLIP_FRACTION_LIMIT:.0f} % means the two inputs describe different "
            "motions: a skid-steer base, or check wheel_distance, the IMU mount and the "
            "topics)" + ("; the fused heading followed the gyro alone" if distrusted > slips
                         else ""),
            {"slip_fraction": disagree / frames, "slips": float(slips),
             "wheel_rate_distrusted": float(distrusted), "frames": float(frames)}))
    faults = int(stats.get("encoder_faults", 0))
    if frames and faults / frames > ENCODER_FAULT_LIMIT:
        out.append(TrustWarning(
            "encoder_fault",
            f"{100 * faults / frames:.1f} % of the {frames} odometry frames read zero speed "
            + ("while the IMU showed motion or could not rule it out"
               if int(stats.get("imu_samples", 0)) else
               "from a speed no braking within stop_decel could have ended (there is no IMU)")
            + " (not fused: the pose coasted on the motion model); "
            f"more than {100 * ENCODER_FAULT_LIMIT:.0f} % means the odometry is missing, not "
            "faulty: check the wheel encoders and their wiring, or the odometry topic (a "
            "driver whose twist stays zero)",
            {"encoder_fault_fraction": faults / frames, "encoder_faults": float(faults),
             "frames": float(frames)}))
    mount = _mount_warning(stats)
    if mount is not None:
        out.append(mount)
    inputs = frames + int(stats.get("imu_samples", 0))
    invalid = int(stats.get("invalid", 0))
    if inputs and invalid / inputs > IMPLAUSIBLE_LIMIT:
        out.append(TrustWarning(
            "implausible",
            f"{invalid} of the {inputs} inputs (IMU samples and odometry frames) were refused "
            "as implausible or not finite (a rate above max_rate, a speed above max_speed; "
            f"more than {100 * IMPLAUSIBLE_LIMIT:.0f} % is a stream in other units, e.g. "
            "speeds in cm/s, or a corrupt one, not a corrupt value now and then): the rest "
            "of that stream was fused as it reads, values short of those limits included",
            {"invalid": float(invalid), "inputs": float(inputs)}))
    gyro_time = float(stats.get("gyro_time", 0.0))
    if gyro_bias is None or not gyro_time > 0:
        return out
    if not abs(gyro_bias) <= GYRO_BIAS_LIMIT:
        out.append(TrustWarning(
            "gyro_bias",
            f"the gyro bias estimate {math.degrees(gyro_bias):+.2f} deg/s is beyond the "
            f"MPU-6050's zero-rate tolerance (+-{math.degrees(GYRO_BIAS_LIMIT):.0f} deg/s): "
            "the filter absorbed a disagreement into its bias",
            {"gyro_bias": gyro_bias, "limit": GYRO_BIAS_LIMIT}))
    wheel_frames = int(stats.get("wheel_frames", 0))
    if wheel_frames and wheel_rate_scale is not None and not (
            abs(wheel_rate_scale) <= WHEEL_SCALE_LIMIT):
        k = wheel_rate_scale
        refits = int(stats.get("wheel_scale_refits", 0))
        if refits:
            cost = ("the EKF restarted that scale at the wheels' fitted one, but the turns "
                    "before went into the gyro bias")
        else:
            cost = "part of that went into the gyro bias"
        out.append(TrustWarning(
            "wheel_scale",
            f"the wheels' yaw rate is {100 * k:+.0f} % off the gyro's (the EKF's wheel "
            f"yaw-rate scale; more than {100 * WHEEL_SCALE_LIMIT:.0f} % means robot.toml's "
            "wheel_distance does not fit this base, e.g. a skid-steer base's geometric track): "
            f"{cost}; correct wheel_distance (`fusion calibrate odometry`), or speed_ratio "
            "if the distances are off by as much too (it scales the speeds and the turns "
            "alike: a gear ratio left out), and replay"
            + ("" if refits else ", or let the EKF restart its scale at the fitted one "
               "(robot.toml [ekf] wheel_scale_refit = 3)"),
            {"wheel_rate_scale": k, "limit": WHEEL_SCALE_LIMIT,
             "wheel_frames": float(wheel_frames), "wheel_scale_refits": float(refits)}))
    slope = stats.get("odometry_rate_slope")
    corr = stats.get("odometry_rate_correlation")
    twists = int(stats.get("twist_messages", 0))
    axis = _gyro_axis_warning(slope, corr, stats)
    twist_scale = 1.0  # the twists' yaw rate over the gyro's, where odometry_scale says it
    if axis is not None:
        out.append(axis)
    elif (twists and slope is not None and corr is not None and corr >= ODOMETRY_CORRELATION
            and not abs(slope - 1.0) <= WHEEL_SCALE_LIMIT):
        twist_scale = float(slope)
        out.append(TrustWarning(
            "odometry_scale",
            f"the odometry's yaw rate is {slope:.2f} times the gyro's (fitted over the "
            f"moving twists, correlation {corr:.3f}; more than {100 * WHEEL_SCALE_LIMIT:.0f} "
            "% off means it turns unlike the robot: a skid-steer base's odometry, or a wrong "
            "track or wheel radius in its driver): its yaw rate was not fused, only its speed "
            "and, when near zero, its straight driving",
            {"odometry_rate_slope": float(slope), "odometry_rate_correlation": float(corr),
             "limit": WHEEL_SCALE_LIMIT, "twist_messages": float(twists)}))
    if not frames:
        return out
    odometry = (float(stats.get("wheel_turn", 0.0))
                + float(stats.get("twist_turn", 0.0)) / twist_scale)
    gyro = (float(stats.get("gyro_turn", 0.0)) - gyro_bias * gyro_time
            - float(stats.get("fault_turn", 0.0)))
    # the odometry's turn the EKF's wheel calibration predicts from the gyro's, w_m = (1 + k)
    # w + c v_m, each state within its limit (beyond, wheel_scale speaks or it explains
    # nothing): a radius mismatch turns the odometry with the distance, not the turns
    k = _within(wheel_rate_scale, WHEEL_SCALE_LIMIT)
    c = _within(radius_mismatch, RADIUS_MISMATCH_LIMIT)
    distance = (float(stats.get("wheel_travel", 0.0))
                + float(stats.get("twist_travel", 0.0)))
    # credited UP TO the estimates, not at them: k and c learnt without a stop are confounded
    # with the bias (c * v is a constant rate at a steady speed), and taken at face value they
    # predicted a turn further from the odometry's than the gyro's own (a moving start of 60 s
    # with a 3 deg/s bias: k -0.05, c +0.014 rad/m made +142 deg of +86 against +83)
    # (bilinear in the two credits: over the box their turns fill the corners' range)
    corners = [(1.0 + kk) * gyro + cc * distance for kk in (0.0, k) for cc in (0.0, c)]
    predicted = min(max(odometry, min(corners)), max(corners))
    divergence = abs(odometry - predicted)
    allowed = (HEADING_FLOOR + HEADING_FRACTION * max(abs(odometry), abs(gyro))
               + HEADING_RATE * gyro_time)
    if divergence > allowed:
        out.append(TrustWarning(
            "heading_divergence",
            f"odometry and gyro headings diverge: the odometry turned "
            f"{math.degrees(odometry):+.0f} deg"
            + (f" (its twists' turn over {twist_scale:.2f}, odometry_scale's)"
               if twist_scale != 1.0 else "")
            + f", the gyro {math.degrees(gyro):+.0f} deg "
            f"(bias estimate removed) over {gyro_time:.1f} s; the EKF's wheel calibration "
            f"(yaw-rate scale {k:+.3f}, radius mismatch {c:+.4f} rad/m over "
            f"{distance:.0f} m), credited up to its estimates, brings the gyro's turn no "
            f"nearer the odometry's than {math.degrees(predicted):+.0f} deg; "
            f"{math.degrees(divergence):.0f} deg apart, more than the "
            f"{math.degrees(allowed):.0f} deg the model explains",
            {"odometry_turn": odometry, "gyro_turn": gyro, "predicted_turn": predicted,
             "divergence": divergence, "allowed": allowed, "gyro_time": gyro_time,
             "wheel_rate_scale": k, "radius_mismatch": c, "odometry_distance": distance}))
    return out


def _within(value: float | None, limit: float) -> float:
    """``value`` clipped to +-``limit`` (0 for None or NaN)."""
    if value is None or not math.isfinite(value):
        return 0.0
    return max(-limit, min(limit, float(value)))


#: The most a skid-steer or tracked base's odometry overstates its turns (the twist's yaw
#: rate over the true one; the terrain benchmark's bags: 1.49-1.50).
SKID_FACTOR_MAX = 3.0


def _near(ratio: float) -> bool:
    """Whether ``ratio`` (the odometry's yaw rate over a gyro's read at face value) is 1, give
    or take :data:`ACCEL_SCALE_TOLERANCE` below and up to :data:`SKID_FACTOR_MAX` above."""
    return 1.0 - ACCEL_SCALE_TOLERANCE <= ratio <= SKID_FACTOR_MAX


def _in_degrees(slope: float) -> bool:
    """Whether the odometry-over-gyro yaw-rate ``slope`` says a gyro in deg/s."""
    return _near(slope * math.degrees(1.0))


def _gyro_axis_warning(slope: float | None, corr: float | None,
                       stats: Mapping[str, Any] | None = None) -> TrustWarning | None:
    """The ``gyro_axis`` check of the module docstring (None: passed or not applicable)."""
    if slope is None or corr is None or not abs(corr) >= ODOMETRY_CORRELATION:
        return None
    if _near(-slope):
        n = int((stats or {}).get("imu_samples", 0))
        total = (stats or {}).get("accel_sum")
        upright = (n >= MOUNT_MIN_SAMPLES and total is not None
                   and angle_from_vertical([float(v) / n for v in total]) < MOUNT_TILT_LIMIT)
        # rates alone cannot tell which of the two is flipped: an independent probe's swapped
        # or negated wheel columns had been blamed on the gyro alone
        cause = ("one of the two turns the wrong way: the gyro (its vertical axis pointing "
                 "down, or an axis sign flipped in its driver"
                 + ("; the accelerometer reads the IMU upright as configured, so not the "
                    "mount" if upright else "") +
                 ") or the odometry (its left and right wheels swapped, both wheels' signs "
                 "flipped, its speed then running backwards too, or its driver's yaw rate "
                 "sign)")
    elif _in_degrees(slope):
        cause = ("the gyro turns 57.3 times as fast: its rates look like deg/s, the inputs "
                 "take rad/s" + ("" if abs(slope * math.degrees(1.0) - 1.0)
                                 <= ACCEL_SCALE_TOLERANCE else
                                 f" (and the odometry turns {slope * math.degrees(1.0):.2f} "
                                 "times the rest: a skid-steer base's)"))
    else:
        return None
    return TrustWarning(
        "gyro_axis",
        f"the odometry's yaw rate is {slope:.3g} times the gyro's (fitted over the moving "
        f"frames, correlation {corr:.3f}): {cause}",
        {"odometry_rate_slope": float(slope), "odometry_rate_correlation": float(corr)})


def _mount_warning(stats: Mapping[str, Any]) -> TrustWarning | None:
    """The ``accel_scale`` or the ``mount`` check of the module docstring (None: passed or
    not applicable)."""
    n = int(stats.get("imu_samples", 0))
    total = stats.get("accel_sum")
    if n < MOUNT_MIN_SAMPLES or total is None:
        return None
    mean = [float(v) / n for v in total]
    norm = math.sqrt(sum(v * v for v in mean))
    ratio = norm / STANDARD_GRAVITY
    if norm == 0.0:
        return None  # no accelerometer (a gyro-only source's zero rows): nothing to check
    if not abs(ratio - 1.0) <= ACCEL_SCALE_TOLERANCE:
        return TrustWarning(
            "accel_scale",
            f"the accelerometer's mean over {n} samples has a magnitude of {norm:.3g}, "
            f"{ratio:.3g} times standard gravity (more than "
            f"{100 * ACCEL_SCALE_TOLERANCE:.0f} % off): the accelerations are not in m/s^2 "
            f"({_accel_scale_cause(ratio)}); the stillness, slip and tilt checks read them at "
            "the wrong scale",
            {"accel_mean_norm": norm, "gravity_ratio": ratio})
    tilt = angle_from_vertical(mean)
    if not tilt > MOUNT_TILT_LIMIT:
        return None
    side = ("upside down, " if tilt > math.radians(120.0) else
            "on its side, " if tilt > math.radians(60.0) else "")
    return TrustWarning(
        "mount",
        f"the accelerometer's mean over {n} samples, in the base frame after the configured "
        f"IMU mount, is ({mean[0]:+.2f}, {mean[1]:+.2f}, {mean[2]:+.2f}) m/s^2: "
        f"{side}{math.degrees(tilt):.0f} deg from the base's z axis (more than "
        f"{math.degrees(MOUNT_TILT_LIMIT):.0f} deg): the IMU does not sit as imu_mount_rpy "
        "(robot.toml, or --imu-mount-rpy) says, so the heading rate is taken about the wrong "
        "axis; set the IMU's mount",
        {"mount_tilt": tilt, "accel_mean_x": mean[0], "accel_mean_y": mean[1],
         "accel_mean_z": mean[2]})


#: The MPU-6050's accelerometer sensitivity, LSB per g, by full-scale range (g; AFS_SEL 0-3):
#: an accelerometer whose mean magnitude is near one of these is logged in raw counts.
RAW_ACCEL_LSB_PER_G = {2: 16384, 4: 8192, 8: 4096, 16: 2048}


#: An accelerometer mean below this share of standard gravity is one whose driver removed
#: gravity (its units may well be m/s^2), not one in other units.
NO_GRAVITY_RATIO = 0.2


def _accel_scale_cause(ratio: float) -> str:
    """The likely cause of an accelerometer mean ``ratio`` times standard gravity."""
    if abs(ratio * STANDARD_GRAVITY - 1.0) <= ACCEL_SCALE_TOLERANCE:
        return f"a log in g: multiply by {STANDARD_GRAVITY}"
    if ratio < NO_GRAVITY_RATIO:
        return ("nearly no gravity: a driver that removes it, where sensor_msgs/Imu and "
                "imu.csv take the specific force with gravity (+9.81 up at rest)")
    for g_range, lsb in RAW_ACCEL_LSB_PER_G.items():
        if abs(ratio * STANDARD_GRAVITY / lsb - 1.0) <= ACCEL_SCALE_TOLERANCE:
            # an independent probe's raw log had been put down to a full-scale range 1024
            # times off, and its gyro's raw counts (3753 times rad/s) named nowhere
            return (f"raw MPU-6050 counts at +-{g_range} g, {lsb} per g: divide by {lsb} and "
                    f"multiply by {STANDARD_GRAVITY}; its gyro is then likely raw counts too "
                    "(131, 65.5, 32.8 or 16.4 per deg/s at +-250, 500, 1000, 2000 deg/s: "
                    "most of its rates beyond max_rate, refused)")
    power = round(math.log2(ratio))
    # full-scale ranges of 2-16 g differ by at most 8 times
    if power and abs(power) <= 3 and abs(ratio / 2.0 ** power - 1.0) <= ACCEL_SCALE_TOLERANCE:
        return (f"{2.0 ** power:g} times: a driver scaling by another full-scale range than "
                "the chip's (MPU-6050 AFS_SEL: 2, 4, 8, 16 g)")
    return "check the driver's scale factor"


#: Checks read from the IMU's motion (still or moving, from its gyro's and accelerometer's
#: spread): an IMU in other units makes them say nothing of the wheels.
IMU_MOTION_CHECKS = ("encoder_fault", "stillness")


def imu_units_wrong(warning: TrustWarning) -> bool:
    """Whether ``warning`` says the IMU's readings are in other units: ``accel_scale`` (but
    for gravity removed by the driver, below :data:`NO_GRAVITY_RATIO`: the units may be
    right), or ``gyro_axis`` at the 57.3 times of deg/s (a skid-steer's factor on top)."""
    if warning.name == "accel_scale":
        return not warning.figures.get("gravity_ratio", 1.0) < NO_GRAVITY_RATIO
    slope = warning.figures.get("odometry_rate_slope")
    return warning.name == "gyro_axis" and slope is not None and _in_degrees(slope)


def units_first(warnings: list[TrustWarning]) -> list[TrustWarning]:
    """``warnings`` with the :data:`IMU_MOTION_CHECKS` marked as read through an IMU in other
    units where another warning says so (:func:`imu_units_wrong`). An independent probe's
    gyro in deg/s was named (``gyro_axis``), and beside it ``encoder_fault`` said to check
    the wheel encoders' wiring: a gyro 57 times too fast never looks still, so every stop
    read as a dead encoder. Marked, not dropped: a real fault may hide under it too."""
    caveat = units_caveat(warnings)
    if not caveat:
        return warnings
    return [TrustWarning(w.name, w.message + caveat, w.figures)
            if w.name in IMU_MOTION_CHECKS else w for w in warnings]


def units_caveat(warnings: list[TrustWarning]) -> str:
    """What to add to a finding read from the IMU's motion (a check, or the replay's dead
    feed note) when ``warnings`` say the IMU is in other units (:func:`imu_units_wrong`);
    "" when none does."""
    units = [w.name for w in warnings if imu_units_wrong(w)]
    if not units:
        return ""
    named = list(dict.fromkeys(units))
    said = " and ".join(named) + (" say" if len(named) > 1 else " says")
    return (f" (but this reads the IMU's motion, and {said} the IMU is in other units: fix "
            "that first, then look again)")

