"""What a replay fuses (:class:`Streams`: IMU samples, wheel frames, odometry twists) and the
checks on it that need the whole log rather than the pipeline's counters: the IMU and the
odometry on one clock, a gyro that reads nothing, an accelerometer that does not read gravity
(fused level), the mount estimated for a ``mount`` warning, gyro axes that are not the
accelerometer's (``gyro_axes``), and what the output cannot cover (spans and gaps).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fusion.calibration.gyro_axes import axis_angle, components, gyro_yaw_axis
from fusion.calibration.mount import estimate_imu_mount, imu_handedness
from fusion.evaluation.trust import ACCEL_SCALE_TOLERANCE, TrustWarning
from fusion.geometry.mount import imu_to_base, mount_matrix
from fusion.io.errors import LogFormatError
from fusion.planar.imu_motion import imu_window_stds
from fusion.planar.robot import RobotConfig
from fusion.types.constants import STANDARD_GRAVITY

__all__ = [
    "DEAD_GYRO_TURN",
    "GYRO_AXES_LIMIT",
    "HANDED_CORRELATION",
    "HANDED_SIGMAS",
    "JOINT_GAP",
    "MIN_STILL_ODOMETRY",
    "SPEED_SCALE_LIMIT",
    "Streams",
    "coverage_warnings",
    "gyro_axes_warnings",
    "gyro_plateau",
    "handedness_warnings",
    "joint_gap_warnings",
    "rest_vibration",
    "speed_scale_warnings",
    "stillness_warnings",
    "two_digits_up",
    "with_gyro_limit",
    "with_mount_estimate",
]

#: rad: the odometry's turns about a gyro axis this far from the accelerometer's up (and as
#: far from down) are the ``gyro_axes`` warning's (:func:`gyro_axes_warnings`): a tilted
#: mount moves both together; hills tilt the turning axis by a few degrees on average.
GYRO_AXES_LIMIT = math.radians(30.0)

#: A turn's sideways specific force against the odometry's v * w at or below this
#: correlation (:func:`fusion.calibration.mount.imu_handedness`), and :data:`HANDED_SIGMAS`
#: standard errors below zero, is the ``handedness`` warning's: the mirror of what clean
#: runs read where their turns show (+0.14 to +0.89: the black-box simulator's seeds
#: 445-446, the terrain bags, the Jackal bag; an independent probe's bag with one IMU axis
#: negated -0.33, 6 standard errors; a simulator whose vibration hides the turns reads
#: about 0, at most 3 standard errors either way, and says nothing).
HANDED_CORRELATION = -0.2
HANDED_SIGMAS = 4.0

#: The odometry's accelerations this many times the accelerometer's (or as many times less)
#: are the ``speed_scale`` warning's (:func:`speed_scale_warnings`): units (cm/s: 100, mm/s:
#: 1000, km/h: 3.6), not a wheel radius a few percent off, which this fit cannot resolve (a
#: 10 % larger radius read 1.07; the bundled Jackal bag's Gazebo odometry reads 2.4).
SPEED_SCALE_LIMIT = 3.0

#: A gyro axis reading exactly its largest magnitude on this many consecutive samples has
#: saturated (noise makes a free gyro's largest reading a lone sample).
PLATEAU_RUN = 5
#: The EKF's gyro_limit set for a saturated gyro: this share of the plateau (the vertical
#: rate of a tilted IMU is the axis's times the cosine of the tilt: 0.98 up to 11 deg).
PLATEAU_LIMIT_SHARE = 0.98

#: s: the odometry reading zero for at least this long in all (stretches of 1 s or more)
#: with hardly any zero-velocity update is the ``stillness`` warning's
#: (:func:`stillness_warnings`).
MIN_STILL_ODOMETRY = 5.0
#: Zero-velocity updates per zero odometry frame below which the stops went unused.
_FEW_ZUPTS = 0.2
#: The stillness thresholds suggested: this margin over this quantile of the windows at rest.
_REST_QUANTILE = 0.95
_REST_MARGIN = 1.25

#: Share of the IMU's span within which the odometry's start and end offsets from the IMU's
#: are one shift (:func:`coverage_warnings`: two clocks).
SAME_SHIFT = 0.01
#: rad: odometry turns through which a gyro reading exactly 0 is refused
#: (:meth:`Streams.check_gyro`).
DEAD_GYRO_TURN = 1.0


@dataclass
class Streams:
    """What a replay fuses: IMU samples in the IMU frame (s, rad/s, m/s^2), wheel frames (s,
    int ticks per period) and external odometry twists (s, m/s, rad/s); any may be None."""

    imu_t: NDArray[np.float64] | None = None
    gyro: NDArray[np.float64] | None = None
    accel: NDArray[np.float64] | None = None
    wheel_t: NDArray[np.float64] | None = None
    ticks: NDArray[np.int64] | None = None
    twist_t: NDArray[np.float64] | None = None
    twist_v: NDArray[np.float64] | None = None
    twist_w: NDArray[np.float64] | None = None

    @staticmethod
    def _has(a) -> bool:
        return a is not None and a.size > 0

    @property
    def has_imu(self) -> bool:
        return self._has(self.imu_t)

    def level_note(self) -> str:
        """Why the IMU's tilt cannot be compensated ("" when it can): an accelerometer whose
        mean over the log is not gravity (zero rows: not provided; more than
        :data:`fusion.evaluation.trust.ACCEL_SCALE_TOLERANCE` off 9.81 m/s^2: gravity removed,
        g units, another full-scale range; the ``accel_scale`` warning says which)."""
        if not self.has_imu:
            return ""
        norm = float(np.linalg.norm(np.mean(self.accel, axis=0)))
        if abs(norm / STANDARD_GRAVITY - 1.0) <= ACCEL_SCALE_TOLERANCE:
            return ""
        what = ("reads zero throughout" if not np.any(self.accel) else
                f"does not read gravity (its mean is {norm:.3g} m/s^2)")
        return f"the accelerometer {what}: fused without tilt compensation (as --level)"

    @property
    def has_wheels(self) -> bool:
        return self._has(self.wheel_t)

    @property
    def has_twist(self) -> bool:
        return self._has(self.twist_t)

    def odometry_rates(self, chassis: Any
                       ) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                  NDArray[np.float64]] | None:
        """``(t s, v m/s, w rad/s)`` of the odometry: the wheel frames' (with ``chassis``,
        a :class:`fusion.geometry.kinematics.DiffDriveParams`) or else the twists; None
        without either."""
        if self.has_wheels:
            from fusion.geometry.kinematics import ticks_to_twist

            v, w = ticks_to_twist(self.ticks[:, 0], self.ticks[:, 1], chassis)
            return self.wheel_t, np.asarray(v, dtype=float), np.asarray(w, dtype=float)
        if self.has_twist:
            return self.twist_t, self.twist_v, self.twist_w
        return None

    def span(self) -> tuple[float, float]:
        """First and last stamp over the streams, s."""
        ts = [a for a in (self.imu_t, self.wheel_t, self.twist_t) if self._has(a)]
        if not ts:
            raise ValueError("nothing to replay: no IMU sample, wheel frame or twist")
        return min(float(a[0]) for a in ts), max(float(a[-1]) for a in ts)

    def check_overlap(self, where: str, hint: str) -> None:
        """Refuse IMU samples and odometry (wheel frames or twists) whose stamps do not
        overlap at all: the two were stamped on different clocks, and fused they would give
        a track that never moves. LogFormatError naming ``where``, both spans and ``hint``."""
        odometry = self.wheel_t if self.has_wheels else self.twist_t
        if not (self.has_imu and self._has(odometry)):
            return
        imu = (float(self.imu_t[0]), float(self.imu_t[-1]))
        odo = (float(odometry[0]), float(odometry[-1]))
        if imu[1] < odo[0] or odo[1] < imu[0]:
            kind = "wheel frames'" if self.has_wheels else "odometry's"
            raise LogFormatError(
                f"{where}: the IMU's stamps span {imu[0]:.3f}-{imu[1]:.3f} s and the {kind} "
                f"{odo[0]:.3f}-{odo[1]:.3f} s: they do not overlap, so they are on different "
                f"clocks ({hint})")

    def check_gyro(self, where: str, chassis: Any) -> None:
        """Refuse a gyro that reads exactly 0 on every axis in every sample while the
        odometry turned more than :data:`DEAD_GYRO_TURN` (a real gyro's noise never reads
        exactly 0 throughout; a deadband driver at rest may, but not through turns): fused,
        it held the heading straight through every turn (the terrain outdoor bag: 67.7 m of
        GPS RMSE, only heading_divergence said anything). LogFormatError naming ``where``."""
        odometry = self.odometry_rates(chassis) if self.has_imu else None
        if odometry is None or np.any(self.gyro):
            return
        t, _, w = odometry
        dt = np.diff(t)
        turn = float(np.sum(np.abs(w[1:]) * np.where(dt > 1.0, 0.0, dt)))  # gaps: no turn
        if turn > DEAD_GYRO_TURN:
            raise LogFormatError(
                f"{where}: every angular velocity of its {self.imu_t.size} IMU samples is "
                f"exactly 0 while the odometry turned {math.degrees(turn):.0f} deg: no gyro "
                "rates (an orientation-only driver that does not say so, REP-145's "
                "angular_velocity_covariance[0] = -1, or a dead sensor); the fusion needs "
                "the gyro's rates")

    def nominal_imu_rate(self) -> float:
        """The IMU's nominal rate, Hz (the median interval, rounded: 100.0, not 99.99999 from
        jittered stamps); 100 Hz without two samples (the attitude filter's first step, as
        live)."""
        if self.has_imu and self.imu_t.size >= 2:
            dt = float(np.median(np.diff(self.imu_t)))
            if math.isfinite(dt) and dt > 0:
                return round(1.0 / dt, 3)
        return 100.0


def with_mount_estimate(warnings: list[TrustWarning], robot: RobotConfig, streams: Streams
                         ) -> list[TrustWarning]:
    """``warnings`` with a ``mount`` warning (:mod:`fusion.evaluation.trust`) completed by the
    mount estimated from the log (:func:`fusion.calibration.mount.estimate_imu_mount`: roll
    and pitch from gravity, yaw from the driving accelerations against the odometry's
    speed): what to set, not only that something is wrong."""
    out = []
    for w in warnings:
        if w.name == "mount" and streams.has_imu:
            odometry = streams.odometry_rates(robot.chassis)
            speed_t, speed = (None, None) if odometry is None else odometry[:2]
            try:
                est = estimate_imu_mount(streams.imu_t, streams.gyro, streams.accel, speed_t,
                                         speed)
            except ValueError:
                out.append(w)
                continue
            figures = {**w.figures, "estimated_roll": est.rpy[0],
                       "estimated_pitch": est.rpy[1], "estimated_yaw": est.rpy[2],
                       "estimated_yaw_known": float(est.yaw_known)}
            if est.yaw_known:  # else NaN, which JSON does not have
                figures["estimated_yaw_std"] = est.yaw_std
            w = TrustWarning(w.name, f"{w.message}; {est.describe()}", figures)
        out.append(w)
    return out


def gyro_axes_warnings(streams: Streams, robot: RobotConfig) -> list[TrustWarning]:
    """A ``gyro_axes`` warning when the odometry turns about a gyro axis more than
    :data:`GYRO_AXES_LIMIT` from the vertical the accelerometer reads
    (:mod:`fusion.calibration.gyro_axes`; both in the IMU frame, so the mount does not enter):
    the gyro's axes are not the accelerometer's. Not within that of straight down: a gyro
    turning the other way is ``gyro_axis``'s."""
    odometry = streams.odometry_rates(robot.chassis) if streams.has_imu else None
    if odometry is None or streams.level_note():
        return []
    fit = gyro_yaw_axis(streams.imu_t, streams.gyro, odometry[0], odometry[2])
    if fit is None:
        return []
    up = np.mean(streams.accel, axis=0)
    angle = axis_angle(fit.axis, up)
    if not GYRO_AXES_LIMIT < angle < math.pi - GYRO_AXES_LIMIT:
        return []
    up_text = components(up / np.linalg.norm(up))
    return [TrustWarning(
        "gyro_axes",
        f"the odometry's turns show on the gyro about its axis {fit.describe()} (IMU frame; "
        f"{fit.scale:.2f} odometry rad/s per gyro rad/s, correlation {fit.correlation:.3f} "
        f"over {math.degrees(fit.turn):.0f} deg of turns), {math.degrees(angle):.0f} deg from "
        f"the up the accelerometer reads, {up_text}: the gyro's axes are not the "
        "accelerometer's (two gyro axes swapped in the driver, or rates and accelerations "
        "from different sensors or frames), so the heading rate was taken about the wrong "
        "axis",
        {"gyro_axes_angle": angle, "gyro_yaw_axis_x": fit.axis[0],
         "gyro_yaw_axis_y": fit.axis[1], "gyro_yaw_axis_z": fit.axis[2],
         "gyro_yaw_axis_correlation": fit.correlation})]


def handedness_warnings(streams: Streams, robot: RobotConfig) -> list[TrustWarning]:
    """A ``handedness`` warning when the accelerometer's sideways readings in the turns run
    against the gyro's (:data:`HANDED_CORRELATION`, :data:`HANDED_SIGMAS`): one IMU axis
    negated in its driver leaves axes no mount can rotate onto the base's (an independent
    probe: x or z negated cost 28-37 % of GPS RMSE with only a heading_divergence said; y,
    the mount it suggested left 35 %)."""
    odometry = streams.odometry_rates(robot.chassis) if streams.has_imu else None
    if odometry is None or streams.level_note():
        return []
    fit = imu_handedness(streams.imu_t, streams.gyro, streams.accel, odometry[0], odometry[1])
    if fit is None or not (fit.correlation <= HANDED_CORRELATION
                           and fit.correlation <= -HANDED_SIGMAS * fit.std):
        return []
    return [TrustWarning(
        "handedness",
        f"in the turns the accelerometer's sideways reading runs against the odometry's "
        f"speed times the gyro's yaw rate (correlation {fit.correlation:+.2f} +- "
        f"{fit.std:.2f}, where a right-handed IMU reads it positive: a turn's centripetal "
        "acceleration points into it): the IMU's axes are left-handed, one of them negated "
        "in its driver or its configuration; no --imu-mount-rpy can undo that (a mount is a "
        "rotation): fix the axis's sign, then replay",
        {"handedness_correlation": fit.correlation, "handedness_std": fit.std})]


def coverage_warnings(imu_t: NDArray[np.float64], odom_t: NDArray[np.float64],
                      longest: float, odometry: str = "odometry",
                      fused: NDArray[np.float64] | None = None) -> list[str]:
    """What the fused output cannot cover, one sentence each (empty when nothing is missing),
    with ``longest`` s the EKF's ``max_extrapolation``: odometry stamps more than that
    beyond the IMU's span (rows are written at IMU samples: a CSV ends at the IMU's last),
    IMU samples more than that beyond the odometry's (the pose stands still there: speeds
    forgotten), and gaps longer than that in either (an odometry gap stops the pose once
    its speed has run on for ``longest`` s; over an IMU gap the odometry's yaw rate carries
    the heading unchecked: :data:`fusion.planar._ekf_core.GYRO_SILENT`). With the ``fused``
    table (:data:`fusion.io.fused_csv.FUSED_CSV_COLUMNS`), also the motion the filter made up
    where both were silent (:func:`joint_gap_warnings`)."""
    out = []
    before, after = imu_t[0] - odom_t[0], odom_t[-1] - imu_t[-1]
    shift = -before
    if abs(shift) > longest and abs(after - shift) <= SAME_SHIFT * (imu_t[-1] - imu_t[0]):
        # both ends moved by one offset: one recording on two clocks, not two recordings (an
        # independent probe's wheels.csv 100 s off was fused into a -19 deg/s gyro bias and a
        # wheel_scale warning, and nothing said the clocks)
        out.append(f"the {odometry} and the IMU span the same {imu_t[-1] - imu_t[0]:.1f} s "
                   f"shifted by {shift:+.3f} s: their stamps are on two clocks (a log's "
                   "stamps must all be one host clock's); the fused result pairs samples "
                   "that are that far apart")
    if before > longest or after > longest:
        out.append(f"the {odometry} spans {odom_t[0]:.3f}-{odom_t[-1]:.3f} s, the IMU "
                   f"{imu_t[0]:.3f}-{imu_t[-1]:.3f} s: {max(0.0, before):.1f} s before and "
                   f"{max(0.0, after):.1f} s after the IMU's samples are not in a CSV output "
                   "(rows at IMU samples; .jsonl and .mcap records go on)")
    if -before > longest or -after > longest:
        out.append(f"the IMU spans {imu_t[0]:.3f}-{imu_t[-1]:.3f} s, the {odometry} "
                   f"{odom_t[0]:.3f}-{odom_t[-1]:.3f} s: over the {max(0.0, -before):.1f} s "
                   f"before and {max(0.0, -after):.1f} s after the {odometry} the pose stands "
                   "still (no speed)")
    for name, t in (("IMU", imu_t), (odometry, odom_t)):
        dt = np.diff(t)
        gaps = np.flatnonzero(dt > longest)
        if gaps.size:
            i = int(gaps[np.argmax(dt[gaps])])
            if name == odometry:
                over = (f"the speed ran on at its last value for {longest:g} s, then the "
                        "pose stopped (speeds forgotten)")
            else:
                silent = sum(_longest_silence(odom_t, t[g], t[g + 1]) >= JOINT_GAP
                             for g in gaps)
                alone = (f"rested on the yaw rate of the {odometry} alone, with no gyro to "
                         "check it for slip")
                unmeasured = f"ran on unmeasured where the {odometry} had no sample either"
                over = ("a CSV output has no rows (rows at IMU samples), and the heading "
                        + (alone if silent == 0 else unmeasured if silent == gaps.size
                           else f"{alone}, and {unmeasured} (in {silent} of them)"))
            out.append(f"{name} gaps longer than {longest:g} s: {gaps.size}, "
                       f"{float(np.sum(dt[gaps])):.1f} s in all (the longest {dt[i]:.1f} s "
                       f"after {t[i]:.3f} s); over them {over}")
    if fused is not None:
        out.extend(joint_gap_warnings(imu_t, odom_t, fused, longest, odometry))
    return out


def _longest_silence(t: NDArray[np.float64], lo: float, hi: float) -> float:
    """s: the longest stretch of ``[lo, hi]`` without one of the sorted stamps ``t``."""
    inside = t[np.searchsorted(t, lo, side="right"):np.searchsorted(t, hi, side="left")]
    return float(np.max(np.diff(np.concatenate([[lo], inside, [hi]]))))


#: s: silences of both the IMU and the odometry from this long are looked at by
#: :func:`joint_gap_warnings` (a serial read or a recorder's flush takes well under that).
JOINT_GAP = 1.0
#: What the filter may make up over the silences of a run before it is said: deg of heading,
#: m of travel (one degree is the issue's yaw budget's scale; 5 cm a wheel frame's worth).
MADE_UP_TURN_DEG = 1.0
MADE_UP_TRAVEL = 0.05


def joint_gap_warnings(imu_t: NDArray[np.float64], odom_t: NDArray[np.float64],
                       fused: NDArray[np.float64], longest: float,
                       odometry: str = "odometry") -> list[str]:
    """The motion the filter made up where neither the IMU nor the ``odometry`` has a sample
    for :data:`JOINT_GAP` s or more, one sentence (empty below :data:`MADE_UP_TURN_DEG` and
    :data:`MADE_UP_TRAVEL`). Over such a silence the pose runs on at the last speeds for up
    to ``longest`` s (``max_extrapolation``) and then stands: that turn and travel are the
    filter's guess, not a measurement, and a clock step makes the same silence while the
    robot did not move at all (an independent probe's +5 s step in a turn at -0.91 rad/s:
    -156 deg of heading, said only as two gaps). ``fused``: the output table
    (:data:`fusion.io.fused_csv.FUSED_CSV_COLUMNS`: t, ..., v at 4, w at 5), rows in time
    order; the speeds are the last row's at or before each silence's start."""
    stamps = np.union1d(imu_t, odom_t)
    if stamps.size < 2 or fused.shape[0] == 0:
        return []
    dt = np.diff(stamps)
    starts = np.flatnonzero(dt >= JOINT_GAP)
    if not starts.size:
        return []
    rows = np.searchsorted(fused[:, 0], stamps[starts], side="right") - 1
    known = rows >= 0
    run = np.minimum(dt[starts], longest)[known]
    turn = np.degrees(fused[rows[known], 5]) * run
    travel = np.abs(fused[rows[known], 4]) * run
    total_turn = float(np.sum(np.abs(turn)))
    total_travel = float(np.sum(travel))
    if total_turn < MADE_UP_TURN_DEG and total_travel < MADE_UP_TRAVEL:
        return []
    k = int(np.argmax(np.abs(turn) + travel))
    i = int(starts[known][k])
    return [f"no IMU sample and nothing from the {odometry} over {starts.size} gap"
            f"{'s' if starts.size > 1 else ''} of {JOINT_GAP:g} s or more "
            f"({float(np.sum(dt[starts])):.1f} s in all; the largest {dt[i]:.1f} s after "
            f"{stamps[i]:.3f} s): the pose ran on at the last speeds for up to {longest:g} s "
            f"of each (max_extrapolation), {total_turn:.1f} deg of turn and "
            f"{total_travel:.2f} m of travel that nothing measured (the largest "
            f"{turn[k]:+.1f} deg, {travel[k]:.2f} m); a clock step makes such a gap while "
            "the robot does not move"]


def _zero_stretches(t: NDArray[np.float64], v: NDArray[np.float64], w: NDArray[np.float64],
                    zero_v: float, zero_w: float) -> tuple[list[tuple[float, float]], int]:
    """(start, end) s of the runs of odometry frames reading zero (within ``zero_v`` m/s and
    ``zero_w`` rad/s) that last 1 s or more, and how many zero frames there are in all."""
    zero = (np.abs(v) <= zero_v) & (np.abs(w) <= zero_w)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], zero.astype(np.int8), [0]])))
    spans = [(float(t[a]), float(t[b - 1])) for a, b in zip(edges[::2], edges[1::2],
                                                              strict=True)]
    return [(a, b) for a, b in spans if b - a >= 1.0], int(np.count_nonzero(zero))


def rest_vibration(stds: NDArray[np.float64], imu_t: NDArray[np.float64],
                   spans: list[tuple[float, float]], quantile: float = 0.5
                   ) -> tuple[float, float]:
    """(gyro rad/s, accel m/s^2): the IMU's vibration at rest, the ``quantile`` (default the
    median) over the samples inside ``spans`` of the detector's window statistics ``stds``
    ((N, 2) at ``imu_t``: :func:`fusion.planar.imu_motion.imu_window_stds`); NaN without a
    sample there."""
    inside = np.zeros(imu_t.size, dtype=bool)
    for start, end in spans:
        inside |= (imu_t >= start) & (imu_t <= end)
    if not np.any(inside):
        return math.nan, math.nan
    g, a = np.quantile(stds[inside], quantile, axis=0)
    return float(g), float(a)


def stillness_warnings(streams: Streams, robot: RobotConfig, zupts: int) -> list[TrustWarning]:
    """A ``stillness`` warning when the odometry read zero for :data:`MIN_STILL_ODOMETRY` s
    or more (in stretches of 1 s or more) but fewer than a fifth of its zero frames became
    zero-velocity updates (``zupts``), while the IMU vibrated there beyond the stillness
    thresholds (``robot.imu_motion``): an IMU that shakes at rest (an engine, fans, a loose
    mount) is never still, so stops teach nothing and the gyro bias is not learnt at them
    (the terrain outdoor bag with 0.1-0.25 m/s^2 of vibration on every sample: 150 updates
    fell to 0-6 and the GPS RMSE rose from 1.5 to 3.4-5.3 m without a word; parked, the
    heading drifted by 104 deg). It gives the ``[imu_motion]`` thresholds that would take
    those stops: 1.25 times the 95th percentile of the vibration measured there."""
    if not streams.has_imu:
        return []
    odometry = streams.odometry_rates(robot.chassis)
    if odometry is None:
        return []
    t, v, w = odometry
    # zero ticks are exactly 0; a twist is as still as the EKF takes it
    limits = (0.0, 0.0) if streams.has_wheels else (robot.ekf.twist_zero_v,
                                                     robot.ekf.twist_zero_w)
    spans, frames = _zero_stretches(t, v, w, *limits)
    still_time = sum(b - a for a, b in spans)
    if still_time < MIN_STILL_ODOMETRY or zupts >= _FEW_ZUPTS * frames:
        return []
    mount = mount_matrix(robot.imu_mount_rpy)  # the pipeline's detector sees the base frame
    stds = imu_window_stds(streams.imu_t, imu_to_base(mount, streams.gyro),
                           imu_to_base(mount, streams.accel), robot.imu_motion)
    gyro_rest, accel_rest = rest_vibration(stds, streams.imu_t, spans)
    th = robot.imu_motion
    if not (gyro_rest > th.gyro_still or accel_rest > th.accel_still):
        return []
    # thresholds above nearly every window at rest: the detector needs still_time s of them
    # in a row (1.5 times the median took half of the parked runs' frames, 1.25 times the
    # 95th percentile nearly all)
    gyro_top, accel_top = rest_vibration(stds, streams.imu_t, spans, _REST_QUANTILE)
    gyro_set = max(th.gyro_still, two_digits_up(_REST_MARGIN * gyro_top))
    accel_set = max(th.accel_still, two_digits_up(_REST_MARGIN * accel_top))
    settings = f"[imu_motion] gyro_still = {gyro_set:g}, accel_still = {accel_set:g}"
    if gyro_set > th.gyro_move or accel_set > th.accel_move:
        # the motion thresholds well above the stillness ones, or a stop's vibration peaks
        # read as motion
        gyro_move = max(th.gyro_move, two_digits_up(1.5 * gyro_set))
        accel_move = max(th.accel_move, two_digits_up(1.5 * accel_set))
        settings += (f", gyro_move = {gyro_move:g}, accel_move = {accel_move:g} (which also "
                     "makes a dead encoder feed while driving harder to tell from a stop)")
    if gyro_set > th.gyro_still:
        # measured: a gyro shaking by 0.01 rad/s of white noise at 100 Hz (14 times the
        # MPU-6050's) on a degraded mission, yaw RMSE 5.5 deg without its stops, 9.0 with
        settings += ("; check the result with the gyro's threshold raised: the EKF's gyro "
                     "noise model is a still MPU-6050's, which understates a gyro shaking this "
                     "much, and its stops can then make the heading worse (better: damp the "
                     "IMU's mount)")
    return [TrustWarning(
        "stillness",
        f"the odometry read zero for {still_time:.0f} s ({frames} frames) but only {zupts} "
        f"were zero-velocity updates: where the robot stood still, its IMU vibrated (median "
        f"of its window standard deviations: gyro {gyro_rest:.3g} rad/s, accelerometer "
        f"{accel_rest:.3g} m/s^2, "
        f"against the stillness thresholds {th.gyro_still:g} and {th.accel_still:g}), so it "
        "never looked still, the stops taught nothing and the gyro bias was not learnt at "
        f"them (an engine, fans, a loose mount); in robot.toml: {settings}. If the robot "
        "was driving there instead, its odometry feed was dead",
        {"still_odometry_time": still_time, "zero_frames": float(frames),
         "zupts": float(zupts), "rest_gyro_std": gyro_rest, "rest_accel_std": accel_rest,
         "suggested_gyro_still": gyro_set, "suggested_accel_still": accel_set})]


def two_digits_up(x: float) -> float:
    """``x`` > 0 rounded up to two significant digits."""
    scale = 10.0 ** (math.floor(math.log10(x)) - 1)
    return math.ceil(x / scale - 1e-9) * scale


def speed_scale_warnings(streams: Streams, robot: RobotConfig) -> list[TrustWarning]:
    """A ``speed_scale`` warning when the odometry's driving accelerations (dv/dt and v w)
    are :data:`SPEED_SCALE_LIMIT` times the accelerometer's or more (or as many times less):
    its speeds are not in m/s, or robot.toml's speed_ratio is off by that factor (a twist in
    cm/s on the terrain outdoor bag: 328 m of GPS RMSE, most twists refused as implausible and
    the rest fused 100 times too fast, with no warning). The fit is
    :func:`fusion.calibration.mount.estimate_imu_mount`'s on the base-frame IMU (needs
    driving accelerations; an accelerometer that does not read gravity is not asked)."""
    odometry = streams.odometry_rates(robot.chassis) if streams.has_imu else None
    if odometry is None or streams.level_note():
        return []
    mount = mount_matrix(robot.imu_mount_rpy)
    try:
        est = estimate_imu_mount(streams.imu_t, imu_to_base(mount, streams.gyro),
                                 imu_to_base(mount, streams.accel), odometry[0], odometry[1])
    except ValueError:
        return []
    scale = est.odometry_scale
    if not (est.yaw_known and (scale >= SPEED_SCALE_LIMIT or scale <= 1.0 / SPEED_SCALE_LIMIT)):
        return []
    units = {100.0: "cm/s", 1000.0: "mm/s", 3.6: "km/h", 0.01: "m/s read as cm/s",
             0.001: "m/s read as mm/s"}
    guess = next((f"; {name}?" for factor, name in units.items()
                  if abs(math.log(scale / factor)) < math.log(1.25)), "")
    source = "robot.toml's speed_ratio" if streams.has_wheels else "the twists' units"
    return [TrustWarning(
        "speed_scale",
        f"the odometry's driving accelerations are {scale:.3g} times what the accelerometer "
        f"felt (fitted over the run, {est.excitation:.3g} m/s^2 RMS of them): its speeds "
        f"are not in m/s or are off by that factor ({source}{guess}); the fused track's "
        "distances are off by as much",
        {"odometry_accel_scale": scale, "excitation": est.excitation})]


def gyro_plateau(gyro: NDArray[np.float64]) -> tuple[float, int, int] | None:
    """``(rad/s, samples, axis)``: where a gyro axis reads exactly its largest magnitude on
    :data:`PLATEAU_RUN` or more consecutive samples, that magnitude (the smallest over such
    axes), how many samples sit on it and the axis (0-2, IMU frame); None when no axis
    saturates."""
    found = None
    for axis in range(3):
        rates = np.abs(gyro[:, axis])
        top = float(np.max(rates, initial=0.0))
        if not top > 0.0:
            continue
        on = rates >= top
        edges = np.flatnonzero(np.diff(np.concatenate([[0], on.astype(np.int8), [0]])))
        if np.max(edges[1::2] - edges[::2], initial=0) >= PLATEAU_RUN and (
                found is None or top < found[0]):
            found = (top, int(np.count_nonzero(on)), axis)
    return found


def with_gyro_limit(robot: RobotConfig, streams: Streams) -> tuple[RobotConfig, str]:
    """``robot`` with the EKF's ``gyro_limit`` set below a saturated gyro's plateau
    (:func:`gyro_plateau`) where robot.toml leaves it unset, and a note saying so ("" when
    nothing changed): a clipped rate fused as the rate loses every turn beyond it (the terrain
    outdoor bag's gyro clipped at 0.5 rad/s: 8.4 m of GPS RMSE, the heading 245 deg off, and
    a warning that blamed the odometry). Samples at or above the limit are skipped and the
    odometry carries the heading there (:class:`fusion.planar.ekf.EkfNoise` ``gyro_limit``)."""
    if not streams.has_imu or math.isfinite(robot.ekf.gyro_limit):
        return robot, ""
    plateau = gyro_plateau(streams.gyro)
    if plateau is None:
        return robot, ""
    top, samples, axis = plateau
    limit = PLATEAU_LIMIT_SHARE * top
    note = (f"the gyro's {'xyz'[axis]} axis reads exactly +-{top:.4g} rad/s "
            f"({math.degrees(top):.4g} deg/s) on {samples} samples, in runs: it saturates "
            f"there, so the EKF's gyro_limit is set to {limit:.4g} rad/s for this replay (the "
            "samples beyond it skipped, the odometry carrying the heading; set [ekf] "
            "gyro_limit in robot.toml, or a larger full-scale range on the IMU)")
    return dataclasses.replace(robot, ekf=dataclasses.replace(robot.ekf, gyro_limit=limit)), \
        note
